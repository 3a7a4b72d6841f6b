"""The train <-> platform door link of SPEC §5 as frames: codec + EN 50159 layer + medium, both ways.

The train's CPCS / ATC sends :class:`~railstop.link.codec.DoorCommand`
telegrams (the door signals and the PSC request) to the platform's WPCS; the
WPCS sends :class:`~railstop.link.codec.PsdStatus` telegrams back (the PSC
reply, PSD closed and locked, start enable). Each telegram is encoded by the
codec (type, fixed-point payload, CRC-16), wrapped in a safety frame
(:mod:`railstop.link.safety`: ids, sequence number, timestamp, CRC-32 or
MAC) and carried by one direction of a simulated medium
(:class:`~railstop.link.channel.SimChannel`: poll cycle, latency, loss,
bursts, bit errors). The receiving end checks the safety frame, then decodes;
a frame refused by either is dropped and counted by its reason, never
delivered.

Pure (DESIGN rule 2): time is an argument, randomness comes from the
counter-based streams of (seed, train, dwell, direction)
(:meth:`~railstop.link.channel.LinkStreams.for_link`), nothing is read from a
clock. ``outage`` is fault injection: every frame sent inside ``[start_s,
end_s)`` is lost, both ways (a dead transponder, a cut loop cable).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

from railstop.config.media import ChannelParams
from railstop.control.doors import LOCKED_STATES, DoorSignals, DoorState, door_mask
from railstop.link.channel import LinkError, LinkStreams, SimChannel
from railstop.link.codec import DoorCommand, PsdStatus, Telegram
from railstop.link.endpoint import Endpoint
from railstop.link.safety import demo_master_key, sum_counts
from railstop.streams import Stream

__all__ = ["DoorLink", "DoorLinkCounts", "Received", "command_signals", "door_command", "psd_status"]

PLATFORM_ID = 0x0200  # the station's WPCS
# The simulated door link's built-in demonstration master key (category 3 only; no attacker in a
# simulation). Public: the live links (SafePeers) refuse it; a deployment loads its own keys.
_DEMO_MASTER = demo_master_key("door link")


_OPEN = frozenset({DoorState.OPEN})


def door_command(
    train_id: int,
    signals: DoorSignals,
    *,
    psc: bool,
    automatic: bool,
    doors: Sequence[DoorState],
    locked: frozenset[DoorState] = LOCKED_STATES,
) -> DoorCommand:
    """The train's ``door-command``: its door signals, the PSC request, the driving mode and which of
    its ``doors`` facing the platform are closed and locked."""
    s = signals
    return DoorCommand(
        train_id=train_id,
        doa_l=s.doa_l,
        doa_r=s.doa_r,
        dmc_l=s.dmc_l,
        dmc_r=s.dmc_r,
        doc=s.doc,
        dcc=s.dcc,
        psc=psc,
        automatic=automatic,
        doors_locked=door_mask(doors, locked),
    )


def command_signals(cmd: DoorCommand) -> DoorSignals:
    """The door signals a ``door-command`` carries (what the WPCS reads them as)."""
    return DoorSignals(
        doa_l=cmd.doa_l, doa_r=cmd.doa_r, dmc_l=cmd.dmc_l, dmc_r=cmd.dmc_r, doc=cmd.doc, dcc=cmd.dcc
    )


def psd_status(
    train_id: int,
    units: Sequence[DoorState],
    *,
    fault: bool,
    psc: bool,
    manual: bool,
    locked: frozenset[DoorState] = LOCKED_STATES,
) -> PsdStatus:
    """The WPCS's ``psd-status`` for its PSD ``units``: start enable only with every unit closed and
    locked and no fault (SPEC §5 fig. 7), and which units are fully open."""
    all_locked = all(u in locked for u in units)
    return PsdStatus(
        train_id=train_id,
        psc=psc,
        psd_closed_locked=all_locked,
        start_enable=all_locked and not fault,
        manual=manual,
        fault=fault,
        psd_open=door_mask(units, _OPEN),
    )


@dataclass(frozen=True, slots=True, kw_only=True)
class Received:
    """A telegram delivered to one end: ``to`` is "platform" or "train"."""

    to: str
    telegram: Telegram
    at_s: float


@dataclass(frozen=True, slots=True, kw_only=True)
class DoorLinkCounts:
    """What the link did: frames sent and delivered per direction, refusals by reason."""

    commands_sent: int
    commands_delivered: int
    status_sent: int
    status_delivered: int
    lost: int  # by the medium (loss, bursts, an outage)
    rejected: dict[str, int]  # by the safety layer or the codec, by reason

    def summary(self) -> dict[str, object]:
        return {
            "commands_sent": self.commands_sent,
            "commands_delivered": self.commands_delivered,
            "status_sent": self.status_sent,
            "status_delivered": self.status_delivered,
            "lost": self.lost,
            "rejected": dict(self.rejected),
        }


@dataclass(slots=True)
class DoorLink:
    """Both directions of one train's door link at one platform: the train's and the platform's
    :class:`~railstop.link.endpoint.Endpoint` (the ends the live door link runs too) and one
    :class:`~railstop.link.channel.SimChannel` per direction between them.

    ``seed``, ``dwell``: the link's random streams are those of (seed, ``Stream.DOOR_LINK``, train,
    dwell, direction) (DESIGN rule 7; ``dwell`` numbers one train's dwells).
    ``max_age_s``: the receivers refuse frames older than this (EN 50159 delay); ``start_s``:
    the link comes up then (no frame is sent before it); ``outage``: every frame sent inside
    ``[start_s, end_s)`` is lost, both ways (fault injection). ``timeout_s`` is the door data's
    supervision time-out, kept for the record: the units supervise their peer's silence.
    """

    params: ChannelParams
    train_id: int
    seed: int = 0
    dwell: int = 0
    category: int = 1
    max_age_s: float = 0.3
    timeout_s: float = 0.5
    start_s: float = 0.0
    outage: tuple[float, float] | None = None
    train_addr: int = field(init=False)  # the train's safety-layer id
    train_end: Endpoint = field(init=False)
    platform_end: Endpoint = field(init=False)
    up: SimChannel = field(init=False)  # train -> platform
    down: SimChannel = field(init=False)  # platform -> train
    sent: dict[str, int] = field(init=False)  # telegrams handed to the link, per direction

    def __post_init__(self) -> None:
        if not 0 <= int(self.train_id) <= 0xEFFF:
            raise LinkError(f"train_id: must be in 0..{0xEFFF} (got {self.train_id!r})")
        self.train_addr = 0x1000 + int(self.train_id)
        key = _DEMO_MASTER if self.category == 3 else None
        self.train_end = self._end(self.train_addr, PLATFORM_ID, key, PsdStatus)
        self.platform_end = self._end(PLATFORM_ID, self.train_addr, key, DoorCommand)
        spans = () if self.outage is None else (self.outage,)  # checked by the media
        self.up, self.down = (
            SimChannel(
                self.params,
                LinkStreams.for_link(self.seed, Stream.DOOR_LINK, self.train_id, self.dwell, way),
                outages=spans,
            )
            for way in (0, 1)
        )
        self.sent = {"up": 0, "down": 0}

    def _end(self, own: int, peer: int, key: bytes | None, takes: type[Telegram]) -> Endpoint:
        return Endpoint(
            own,
            peers=lambda p: p == peer,
            max_age_s=self.max_age_s,
            category=self.category,
            master_key=key,
            expects=(takes,),
            simulated=True,
        )

    def _send(
        self, end: Endpoint, peer: int, medium: SimChannel, way: str, msg: Telegram, now_s: float
    ) -> None:
        self.sent[way] += 1
        frame = end.frame(msg, peer, now_s)
        if frame is None:
            return  # a value the telegram cannot carry: nothing sent (counted by the end)
        medium.send(frame, now_s)  # in an outage (fault injection) the medium loses it

    def send_command(self, msg: DoorCommand, now_s: float) -> None:
        """Train -> platform."""
        self._send(self.train_end, PLATFORM_ID, self.up, "up", msg, now_s)

    def send_status(self, msg: PsdStatus, now_s: float) -> None:
        """Platform -> train."""
        self._send(self.platform_end, self.train_addr, self.down, "down", msg, now_s)

    def next_arrival_s(self) -> float | None:
        """When the next frame in flight (either way) arrives, or None."""
        times = [t for t in (self.up.next_arrival_s(), self.down.next_arrival_s()) if t is not None]
        return min(times) if times else None

    def deliver(self, now_s: float) -> list[Received]:
        """The telegrams that have arrived by ``now_s`` and passed the safety layer and the codec."""
        out: list[Received] = []
        for to, medium, end in (
            ("platform", self.up, self.platform_end),
            ("train", self.down, self.train_end),
        ):
            arrival = medium.next_arrival_s()
            if arrival is None or arrival > now_s:
                continue  # nothing has arrived this way
            for frame in medium.receive(now_s):
                got = end.receive(frame, now_s)
                if got is not None:
                    out.append(Received(to=to, telegram=got[1], at_s=now_s))
        return out

    @property
    def counts(self) -> DoorLinkCounts:
        rejected = sum_counts(end.rejected for end in (self.train_end, self.platform_end))
        return DoorLinkCounts(
            commands_sent=self.sent["up"],
            commands_delivered=self.platform_end.delivered,
            status_sent=self.sent["down"],
            status_delivered=self.train_end.delivered,
            lost=self.up.stats.lost + self.down.stats.lost,
            rejected=rejected,
        )
