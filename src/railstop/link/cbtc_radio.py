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

import hashlib
import heapq
from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np

from railstop.errors import TelegramError
from railstop.link.channel import ChannelParams, SimChannel
from railstop.link.codec import CbtcCommand, CbtcReport, decode, encode
from railstop.link.safety import Delivered, SafeReceiver, SafeSender, link_key
from railstop.messages import Message, MovementCommand, Output, PositionReport

__all__ = ["CbtcRadio", "RadioCounts"]

ZC_ADDRESS = 0x0300
_TRAIN_BASE = 0x2000
# Demonstration master key. A deployment loads its link keys from its key management.
_DEMO_MASTER = hashlib.sha256(b"railstop demonstration CBTC radio master key").digest()


@dataclass(slots=True)
class RadioCounts:
    reports_sent: int = 0
    reports_delivered: int = 0
    commands_sent: int = 0
    commands_delivered: int = 0
    lost: int = 0  # by the medium or an outage
    rejected: dict[str, int] = field(default_factory=dict)  # by the safety layer / codec, by reason


@dataclass(slots=True)
class _End:
    sender: SafeSender
    channel: SimChannel
    receiver: SafeReceiver


@dataclass(slots=True)
class CbtcRadio:
    """The radio of every train. ``outages``: per train index, (start_s, end_s) windows."""

    params: ChannelParams
    seed: int
    max_age_s: float = 1.0
    outages: dict[int, list[tuple[float, float]]] = field(default_factory=dict)
    zc_name: str = "zc"
    name: str = "radio"
    accepts: tuple[type, ...] = (PositionReport, MovementCommand)
    counts: RadioCounts = field(default_factory=RadioCounts)
    _links: dict[tuple[int, str], _End] = field(default_factory=dict)
    _arrivals: list[tuple[float, int, str]] = field(default_factory=list)
    _scheduled: dict[tuple[int, str], float] = field(default_factory=dict)  # the live heap entry

    def _end(self, train_id: int, direction: str) -> _End:
        key = (train_id, direction)
        end = self._links.get(key)
        if end is None:
            train_addr = _TRAIN_BASE + train_id
            src, dst = (train_addr, ZC_ADDRESS) if direction == "up" else (ZC_ADDRESS, train_addr)
            k = link_key(_DEMO_MASTER, src, dst)
            entropy = [
                int(self.seed) & 0xFFFF_FFFF_FFFF_FFFF,
                16,
                int(train_id),
                0 if direction == "up" else 1,
            ]
            end = _End(
                sender=SafeSender(src, dst, key=k, category=3),
                channel=SimChannel(self.params, np.random.default_rng(np.random.SeedSequence(entropy))),
                receiver=SafeReceiver(dst, src, key=k, category=3, max_age_s=self.max_age_s, timeout_s=1e9),
            )
            self._links[key] = end
        return end

    def _dead(self, train_id: int, now_s: float) -> bool:
        return any(a <= now_s < b for a, b in self.outages.get(train_id, ()))

    def handle(self, message: Message, now_s: float) -> list[Output]:
        try:
            if isinstance(message, PositionReport):
                self.counts.reports_sent += 1
                direction, payload = "up", encode(CbtcReport(**_fields(message)))
            elif isinstance(message, MovementCommand):
                self.counts.commands_sent += 1
                direction, payload = "down", encode(CbtcCommand(**_fields(message)))
            else:
                return []
        except TelegramError as exc:
            # A value the telegram cannot carry: nothing is sent (the receiver sees a missed
            # report or command, which its supervision handles); counted by reason.
            self._reject(f"encode-{exc.reason}")
            return []
        end = self._end(message.train_id, direction)
        frame = end.sender.wrap(payload, now_s)
        if self._dead(message.train_id, now_s):
            self.counts.lost += 1
            return []
        lost_before = end.channel.stats.lost
        end.channel.send(frame, now_s)
        self.counts.lost += end.channel.stats.lost - lost_before
        self._schedule(message.train_id, direction, end)
        return []

    def _schedule(self, train_id: int, direction: str, end: _End) -> None:
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
            for frame in end.channel.receive(now_s):
                verdict = end.receiver.accept(frame, now_s)
                if not isinstance(verdict, Delivered):
                    self._reject(verdict.reason)
                    continue
                try:
                    tele = decode(verdict.payload)
                except TelegramError as exc:
                    self._reject(f"codec-{exc.reason}")
                    continue
                if isinstance(tele, CbtcReport) and direction == "up":
                    self.counts.reports_delivered += 1
                    out.append(Output(to=self.zc_name, message=PositionReport(**_fields(tele))))
                elif isinstance(tele, CbtcCommand) and direction == "down":
                    self.counts.commands_delivered += 1
                    out.append(Output(to=f"cbtc-{tele.train_id}", message=MovementCommand(**_fields(tele))))
                else:
                    self._reject("unexpected-type")
            self._schedule(train_id, direction, end)
        return out

    def _reject(self, reason: str) -> None:
        self.counts.rejected[reason] = self.counts.rejected.get(reason, 0) + 1


def _fields(obj: object) -> dict[str, Any]:
    return {f.name: getattr(obj, f.name) for f in fields(obj)}  # type: ignore[arg-type]
