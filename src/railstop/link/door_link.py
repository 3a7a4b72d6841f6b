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
generator given, nothing is read from a clock. ``outage`` is fault injection:
every frame sent inside ``[start_s, end_s)`` is lost, both ways (a dead
transponder, a cut loop cable).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from railstop.config.media import ChannelParams
from railstop.control.doors import LOCKED_STATES, DoorSignals, DoorState, door_mask
from railstop.link.channel import LinkError, SimChannel
from railstop.link.codec import DoorCommand, PsdStatus, Telegram
from railstop.link.safe_channel import SafeChannel
from railstop.link.safety import SafeReceiver, SafeSender, demo_master_key, link_key, sum_counts

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
    """Both directions of one train's door link at one platform.

    ``max_age_s``: the receivers refuse frames older than this (EN 50159
    delay); ``start_s``: the link comes up then (the receivers' time-outs count
    from it).
    """

    params: ChannelParams
    rng: np.random.Generator
    train_id: int
    category: int = 1
    max_age_s: float = 0.3
    timeout_s: float = 0.5
    start_s: float = 0.0
    outage: tuple[float, float] | None = None
    up: SafeChannel = field(init=False)  # train -> platform
    down: SafeChannel = field(init=False)  # platform -> train

    def __post_init__(self) -> None:
        start, end = self.outage if self.outage is not None else (0.0, 0.0)
        if not (math.isfinite(start) and not math.isnan(end) and start <= end):
            raise LinkError(f"outage: needs a finite start_s <= end_s (inf: for good) (got {self.outage!r})")
        if not 0 <= int(self.train_id) <= 0xEFFF:
            raise LinkError(f"train_id: must be in 0..{0xEFFF} (got {self.train_id!r})")
        train_addr = 0x1000 + int(self.train_id)
        self.up = self._direction(train_addr, PLATFORM_ID)
        self.down = self._direction(PLATFORM_ID, train_addr)

    def _direction(self, src: int, dst: int) -> SafeChannel:
        key = link_key(_DEMO_MASTER, src, dst) if self.category == 3 else None
        return SafeChannel(
            sender=SafeSender(src, dst, key=key, category=self.category),
            channel=SimChannel(self.params, self.rng),
            receiver=SafeReceiver(
                dst,
                src,
                key=key,
                category=self.category,
                max_age_s=self.max_age_s,
                timeout_s=self.timeout_s,
                start_s=self.start_s,
            ),
            outages=() if self.outage is None else (self.outage,),
        )

    def send_command(self, msg: DoorCommand, now_s: float) -> None:
        """Train -> platform."""
        self.up.send(msg, now_s)

    def send_status(self, msg: PsdStatus, now_s: float) -> None:
        """Platform -> train."""
        self.down.send(msg, now_s)

    def next_arrival_s(self) -> float | None:
        """When the next frame in flight (either way) arrives, or None."""
        times = [t for t in (self.up.next_arrival_s(), self.down.next_arrival_s()) if t is not None]
        return min(times) if times else None

    def deliver(self, now_s: float) -> list[Received]:
        """The telegrams that have arrived by ``now_s`` and passed the safety layer and the codec."""
        return [
            Received(to=to, telegram=msg, at_s=now_s)
            for to, d in (("platform", self.up), ("train", self.down))
            for msg in d.receive(now_s)
        ]

    def train_timed_out(self, now_s: float) -> bool:
        """No valid status frame has reached the train for longer than ``timeout_s``."""
        return self.down.receiver.timed_out(now_s)

    @property
    def counts(self) -> DoorLinkCounts:
        rejected = sum_counts(d.rejected for d in (self.up, self.down))
        return DoorLinkCounts(
            commands_sent=self.up.sent,
            commands_delivered=self.up.delivered,
            status_sent=self.down.sent,
            status_delivered=self.down.delivered,
            lost=self.up.lost + self.down.lost,
            rejected=rejected,
        )
