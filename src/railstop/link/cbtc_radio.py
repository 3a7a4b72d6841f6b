"""The CBTC train radio of SPEC §4 as a unit: reports up, commands down, as frames on a medium.

Each train has its own link, one :class:`~railstop.link.channel.SimChannel`
per direction. A :class:`~railstop.messages.PositionReport` handed to the
radio becomes a ``cbtc-report`` codec frame in an EN 50159 safety frame
(category 3: radio is an open system, SPEC §5 "needs security"; a key per
train and direction) and reaches the zone controller when the medium
delivers it and the safety layer and the codec accept it; a
:class:`~railstop.messages.MovementCommand` goes down the same way as a
``cbtc-command``. What the medium loses never arrives; what the safety layer
refuses is counted by reason. An outage (a train's radio dead from
``start_s`` to ``end_s``, fault data) loses every frame sent in it, both
ways.

A unit of the scheduler (DESIGN rule 5: the link is a unit between two
others): ``handle`` takes a message, ``next_deadline_s`` is the next
arrival, ``on_timer`` delivers. Randomness: one generator per train and
direction from (seed, stream, train, direction) (DESIGN rule 7).
"""

from __future__ import annotations

import heapq
from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np

from railstop.config.media import ChannelParams
from railstop.link.channel import SimChannel
from railstop.link.codec import CbtcCommand, CbtcReport, Telegram
from railstop.link.safe_channel import SafeChannel
from railstop.link.safety import SafeReceiver, SafeSender, demo_master_key, link_key, sum_counts
from railstop.messages import Message, MovementCommand, Output, PositionReport
from railstop.streams import Stream, seed_u64

__all__ = ["MAX_AGE_S", "TRAIN_BASE", "ZC_ADDRESS", "CbtcRadio", "RadioCounts", "to_message", "to_telegram"]

ZC_ADDRESS = 0x0300  # the zone controller's safety-layer id
TRAIN_BASE = 0x2000  # train k's safety-layer id is TRAIN_BASE + k
MAX_AGE_S = 1.0  # a radio frame older than this is stale
# The simulated radio's built-in demonstration master key (no attacker in a simulation). Public:
# the live links (SafePeers) refuse it; a deployment loads its keys from its key management.
_DEMO_MASTER = demo_master_key("CBTC radio")


@dataclass(frozen=True, slots=True, kw_only=True)
class RadioCounts:
    reports_sent: int
    reports_delivered: int
    commands_sent: int
    commands_delivered: int
    lost: int  # by the medium or an outage
    rejected: dict[str, int]  # by the safety layer / codec, by reason


@dataclass(slots=True)
class CbtcRadio:
    """The radio of every train. ``outages``: per train index, (start_s, end_s) windows."""

    params: ChannelParams
    seed: int
    max_age_s: float = MAX_AGE_S
    outages: dict[int, list[tuple[float, float]]] = field(default_factory=dict)
    zc_name: str = "zc"
    name: str = "radio"
    accepts: tuple[type, ...] = (PositionReport, MovementCommand)
    reports_delivered: int = 0
    commands_delivered: int = 0
    unexpected: int = 0  # a telegram of the wrong type for its direction
    _links: dict[tuple[int, str], SafeChannel] = field(default_factory=dict)
    _arrivals: list[tuple[float, int, str]] = field(default_factory=list)
    _scheduled: dict[tuple[int, str], float] = field(default_factory=dict)  # the live heap entry

    def _end(self, train_id: int, direction: str) -> SafeChannel:
        key = (train_id, direction)
        end = self._links.get(key)
        if end is None:
            train_addr = TRAIN_BASE + train_id
            src, dst = (train_addr, ZC_ADDRESS) if direction == "up" else (ZC_ADDRESS, train_addr)
            k = link_key(_DEMO_MASTER, src, dst)
            entropy = [
                int(seed_u64(self.seed)),
                int(Stream.CBTC_RADIO),
                int(train_id),
                int(direction == "down"),
            ]
            end = SafeChannel(
                sender=SafeSender(src, dst, key=k, category=3),
                channel=SimChannel(self.params, np.random.default_rng(np.random.SeedSequence(entropy))),
                receiver=SafeReceiver(dst, src, key=k, category=3, max_age_s=self.max_age_s, timeout_s=1e9),
                outages=tuple(self.outages.get(train_id, ())),
            )
            self._links[key] = end
        return end

    @property
    def counts(self) -> RadioCounts:
        rejected = sum_counts(end.rejected for end in self._links.values())
        if self.unexpected:
            rejected["unexpected-type"] = self.unexpected
        ends = self._links.items()
        return RadioCounts(
            reports_sent=sum(e.sent for (_, d), e in ends if d == "up"),
            reports_delivered=self.reports_delivered,
            commands_sent=sum(e.sent for (_, d), e in ends if d == "down"),
            commands_delivered=self.commands_delivered,
            lost=sum(e.lost for e in self._links.values()),
            rejected=rejected,
        )

    def handle(self, message: Message, now_s: float) -> list[Output]:
        tele = to_telegram(message)
        if tele is None or not isinstance(message, PositionReport | MovementCommand):
            return []
        direction = "up" if isinstance(tele, CbtcReport) else "down"
        end = self._end(message.train_id, direction)
        if end.send(tele, now_s):
            self._schedule(message.train_id, direction, end)
        return []

    def _schedule(self, train_id: int, direction: str, end: SafeChannel) -> None:
        arrival = end.channel.next_arrival_s()
        key = (train_id, direction)
        if arrival is not None and arrival < self._scheduled.get(key, float("inf")):
            self._scheduled[key] = arrival
            heapq.heappush(self._arrivals, (arrival, train_id, direction))

    def next_deadline_s(self) -> float | None:
        return self._arrivals[0][0] if self._arrivals else None

    def on_timer(self, now_s: float) -> list[Output]:
        out: list[Output] = []
        while self._arrivals and self._arrivals[0][0] <= now_s + 1e-12:
            when, train_id, direction = heapq.heappop(self._arrivals)
            if self._scheduled.get((train_id, direction)) != when:
                continue  # superseded by an earlier arrival on the same link
            del self._scheduled[(train_id, direction)]
            end = self._links[(train_id, direction)]
            for tele in end.receive(now_s):
                msg = to_message(tele)
                if isinstance(msg, PositionReport) and direction == "up":
                    self.reports_delivered += 1
                    out.append(Output(to=self.zc_name, message=msg))
                elif isinstance(msg, MovementCommand) and direction == "down":
                    self.commands_delivered += 1
                    out.append(Output(to=f"cbtc-{msg.train_id}", message=msg))
                else:
                    self.unexpected += 1
            self._schedule(train_id, direction, end)
        return out


def to_telegram(message: Message) -> CbtcReport | CbtcCommand | None:
    """The codec telegram of a SPEC §4 report (up) or command (down); None for any other message."""
    if isinstance(message, PositionReport):
        return CbtcReport(**_fields(message))
    if isinstance(message, MovementCommand):
        return CbtcCommand(**_fields(message))
    return None


def to_message(tele: Telegram) -> PositionReport | MovementCommand | None:
    """The message a received ``cbtc-report`` / ``cbtc-command`` carries; None for another telegram."""
    if isinstance(tele, CbtcReport):
        return PositionReport(**_fields(tele))
    if isinstance(tele, CbtcCommand):
        return MovementCommand(**_fields(tele))
    return None


def _fields(obj: object) -> dict[str, Any]:
    return {f.name: getattr(obj, f.name) for f in fields(obj)}  # type: ignore[arg-type]
