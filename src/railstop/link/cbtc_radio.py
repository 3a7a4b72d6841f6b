"""The CBTC train radio of SPEC §4: its endpoint and the simulated radio of every train.

:class:`CbtcEndpoint` is one end (the zone controller's or a train's): a
:class:`~railstop.messages.PositionReport` handed to a train's end becomes a
``cbtc-report`` codec frame in an EN 50159 safety frame (category 3: radio is
an open system, SPEC §5 "needs security"; a key per train and direction), a
:class:`~railstop.messages.MovementCommand` handed to the controller's end a
``cbtc-command``; a frame received becomes the message again when the safety
layer and the codec accept it (what they refuse is counted by reason). Live
operation carries the frames over UDP (``live.cbtc``); :class:`CbtcRadio`
carries them over a simulated medium, one
:class:`~railstop.link.channel.SimChannel` per train and direction, between
the same ends. What the medium loses never arrives. An outage (a train's
radio dead from ``start_s`` to ``end_s``, fault data) loses every frame sent
in it, both ways.

A unit of the scheduler (DESIGN rule 5: the link is a unit between two
others): ``handle`` takes a message, ``next_deadline_s`` is the next
arrival, ``on_timer`` delivers. Randomness: the counter-based streams of
(seed, stream, train, direction) (DESIGN rule 7,
:meth:`~railstop.link.channel.LinkStreams.for_link`).
"""

from __future__ import annotations

import heapq
from collections.abc import Callable
from dataclasses import dataclass, field, fields
from typing import Any

from railstop.config.media import ChannelParams
from railstop.link.channel import LinkStreams, SimChannel
from railstop.link.codec import CbtcCommand, CbtcReport, Telegram
from railstop.link.endpoint import Endpoint
from railstop.link.safety import demo_master_key, sum_counts
from railstop.messages import Message, MovementCommand, Output, PositionReport
from railstop.streams import Stream

__all__ = [
    "MAX_AGE_S",
    "TRAIN_BASE",
    "ZC_ADDRESS",
    "CbtcEndpoint",
    "CbtcRadio",
    "RadioCounts",
    "to_message",
    "to_telegram",
]

ZC_ADDRESS = 0x0300  # the zone controller's safety-layer id
TRAIN_BASE = 0x2000  # train k's safety-layer id is TRAIN_BASE + k
MAX_AGE_S = 1.0  # a radio frame older than this is stale
# The simulated radio's built-in demonstration master key (no attacker in a simulation). Public:
# the live links (SafePeers) refuse it; a deployment loads its keys from its key management.
_DEMO_MASTER = demo_master_key("CBTC radio")
# The telegram that carries each message this radio takes.
_TELEGRAM_OF: dict[type[Message], type[Telegram]] = {PositionReport: CbtcReport, MovementCommand: CbtcCommand}


@dataclass(frozen=True, slots=True, kw_only=True)
class RadioCounts:
    reports_sent: int
    reports_delivered: int
    commands_sent: int
    commands_delivered: int
    lost: int  # by the medium or an outage
    rejected: dict[str, int]  # by the safety layer / codec, by reason


class CbtcEndpoint:
    """One end of the CBTC radio (SPEC §4): the zone controller's or a train's. Messages handed to
    it become category-3 frames to send (``outgoing``: (frame, peer id)); frames received become
    messages (:meth:`ingest`). Pure: whoever holds it carries the frames, a simulated medium
    (:class:`CbtcRadio`) or UDP sockets (``live.cbtc``). The one endpoint of this radio.

    ``started_s``: when this end (its process) started on the run's clock; frames sent before it
    are refused (``old_session``: a previous incarnation may have delivered them, EN 50159
    repetition across restarts). ``peers``: the safety-layer ids that may be heard (default: the
    zone controller and any train). ``expects``: the one message type this end takes (a zone
    controller takes reports, a train commands); any other is refused and counted
    (``unexpected-type``), never a crash (DESIGN rule 9). ``simulated``: a simulation's end, which
    may use the built-in demonstration key (``link.safety.SafePeers``)."""

    def __init__(
        self,
        *,
        own_id: int,
        master_key: bytes,
        name: str = "radio",
        started_s: float | None = None,
        peers: Callable[[int], bool] | None = None,
        expects: type[Message] | None = None,
        max_age_s: float = MAX_AGE_S,
        simulated: bool = False,
    ) -> None:
        self.name = name
        self.accepts: tuple[type, ...] = (PositionReport, MovementCommand)
        self.own_id = own_id
        self.expects = expects
        self.outgoing: list[tuple[bytes, int]] = []  # (frame, peer id)
        self.end = Endpoint(
            own_id,
            peers=peers or (lambda p: p == ZC_ADDRESS or TRAIN_BASE <= p < TRAIN_BASE + 0x1000),
            max_age_s=max_age_s,
            master_key=master_key,
            expects=() if expects is None else (_TELEGRAM_OF[expects],),
            started_s=started_s,
            simulated=simulated,
        )
        self.links = self.end.links

    @classmethod
    def zone_controller(
        cls,
        master_key: bytes,
        *,
        trains: int = 0x1000,
        name: str = "radio",
        started_s: float | None = None,
        max_age_s: float = MAX_AGE_S,
        simulated: bool = False,
    ) -> CbtcEndpoint:
        """The zone controller's end: it hears trains 0 .. ``trains`` - 1 and takes their reports."""
        return cls(
            own_id=ZC_ADDRESS, master_key=master_key, name=name, started_s=started_s,
            peers=lambda p: TRAIN_BASE <= p < TRAIN_BASE + trains, expects=PositionReport,
            max_age_s=max_age_s, simulated=simulated,
        )  # fmt: skip

    @classmethod
    def train(
        cls,
        train_id: int,
        master_key: bytes,
        *,
        name: str = "radio",
        started_s: float | None = None,
        max_age_s: float = MAX_AGE_S,
        simulated: bool = False,
    ) -> CbtcEndpoint:
        """Train ``train_id``'s end: it hears the zone controller and takes its commands."""
        return cls(
            own_id=TRAIN_BASE + train_id, master_key=master_key, name=name, started_s=started_s,
            peers=lambda p: p == ZC_ADDRESS, expects=MovementCommand, max_age_s=max_age_s,
            simulated=simulated,
        )  # fmt: skip

    def handle(self, message: Message, now_s: float) -> list[Output]:
        tele = to_telegram(message)
        if tele is None:
            return []
        peer = ZC_ADDRESS if isinstance(message, PositionReport) else TRAIN_BASE + tele.train_id
        frame = self.end.frame(tele, peer, now_s)
        if frame is not None:  # None: a value the telegram cannot carry (counted; the peer's
            self.outgoing.append((frame, peer))  # supervision sees a missed telegram)
        return []

    def next_deadline_s(self) -> float | None:
        return None

    def on_timer(self, now_s: float) -> list[Output]:
        return []

    def ingest(self, frame: bytes, now_s: float, *, to: Callable[[int], str]) -> list[Output]:
        """A received frame: the message it carries for the unit ``to(train_id)`` names, or nothing
        (refused frames are counted by reason)."""
        # SPEC §4: reports go up, commands come down; a command sent to the zone controller (or a
        # report to a train), even under a valid MAC, is refused and counted (the end's types).
        got = self.end.receive(frame, now_s)
        if got is None:
            return []
        msg = to_message(got[1])
        if msg is None:
            self.links.reject("unexpected-type")  # not a CBTC telegram (an end that takes any)
            return []
        if TRAIN_BASE + msg.train_id not in (got[0], self.own_id):
            # [interpretation] A telegram names the train whose link carries it: a report from
            # train k's radio is about train k, a command to train k's radio is for train k. A key
            # holder's frame naming another train is refused (EN 50159 masquerade, DESIGN rule 10).
            self.links.reject("train-mismatch")
            return []
        return [Output(to=to(msg.train_id), message=msg)]


@dataclass(slots=True)
class CbtcRadio:
    """The radio of every train on a simulated medium: the zone controller's
    :class:`CbtcEndpoint` and one per train (the same ends live operation runs over UDP), and
    between them one :class:`~railstop.link.channel.SimChannel` per train and direction.
    ``outages``: per train index, (start_s, end_s) windows in which every frame sent is lost."""

    params: ChannelParams
    seed: int
    max_age_s: float = MAX_AGE_S
    outages: dict[int, list[tuple[float, float]]] = field(default_factory=dict)
    zc_name: str = "zc"
    name: str = "radio"
    accepts: tuple[type, ...] = (PositionReport, MovementCommand)
    reports_delivered: int = 0
    commands_delivered: int = 0
    _zc: CbtcEndpoint | None = None
    _trains: dict[int, CbtcEndpoint] = field(default_factory=dict)
    _media: dict[tuple[int, str], SimChannel] = field(default_factory=dict)
    _sent: dict[str, int] = field(default_factory=lambda: {"up": 0, "down": 0})
    _arrivals: list[tuple[float, int, str]] = field(default_factory=list)
    _scheduled: dict[tuple[int, str], float] = field(default_factory=dict)  # the live heap entry

    def _zc_end(self) -> CbtcEndpoint:
        if self._zc is None:
            self._zc = CbtcEndpoint.zone_controller(
                _DEMO_MASTER, name=self.zc_name, max_age_s=self.max_age_s, simulated=True
            )
        return self._zc

    def _train_end(self, train_id: int) -> CbtcEndpoint:
        end = self._trains.get(train_id)
        if end is None:
            end = CbtcEndpoint.train(
                train_id, _DEMO_MASTER, name=f"cbtc-{train_id}", max_age_s=self.max_age_s, simulated=True
            )
            self._trains[train_id] = end
        return end

    def _medium(self, train_id: int, direction: str) -> SimChannel:
        key = (train_id, direction)
        medium = self._media.get(key)
        if medium is None:
            streams = LinkStreams.for_link(self.seed, Stream.CBTC_RADIO, train_id, int(direction == "down"))
            # An outage (a train's radio dead) loses every frame sent in it, both ways.
            medium = SimChannel(self.params, streams, outages=self.outages.get(train_id, ()))
            self._media[key] = medium
        return medium

    def _ends(self) -> list[CbtcEndpoint]:
        return ([self._zc] if self._zc is not None else []) + list(self._trains.values())

    @property
    def counts(self) -> RadioCounts:
        rejected = sum_counts(end.links.rejected for end in self._ends())
        return RadioCounts(
            reports_sent=self._sent["up"],
            reports_delivered=self.reports_delivered,
            commands_sent=self._sent["down"],
            commands_delivered=self.commands_delivered,
            lost=sum(m.stats.lost for m in self._media.values()),
            rejected=rejected,
        )

    def handle(self, message: Message, now_s: float) -> list[Output]:
        if isinstance(message, PositionReport):
            train_id, direction, end = message.train_id, "up", self._train_end(message.train_id)
        elif isinstance(message, MovementCommand):
            train_id, direction, end = message.train_id, "down", self._zc_end()
        else:
            return []
        self._sent[direction] += 1
        end.handle(message, now_s)
        frames, end.outgoing = end.outgoing, []
        for frame, _peer in frames:
            medium = self._medium(train_id, direction)
            medium.send(frame, now_s)
            self._schedule(train_id, direction, medium)
        return []

    def _schedule(self, train_id: int, direction: str, medium: SimChannel) -> None:
        arrival = medium.next_arrival_s()
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
            medium = self._media[(train_id, direction)]
            end = self._zc_end() if direction == "up" else self._train_end(train_id)
            to = self.zc_name if direction == "up" else f"cbtc-{train_id}"
            for frame in medium.receive(now_s):
                got = end.ingest(frame, now_s, to=lambda _k: to)  # noqa: B023 (used at once)
                if direction == "up":
                    self.reports_delivered += len(got)
                else:
                    self.commands_delivered += len(got)
                out.extend(got)
            self._schedule(train_id, direction, medium)
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
