"""The CBTC zone controller of SPEC §4, a pure unit on the ground.

It takes the trains' position reports (a) and answers each with a command (b)
after its processing delay Δt, computed from the **compensated position**::

    Pc = Pp ± Δt · Vp        (+ travelling in direction R, - in L; SPEC §4)

The command carries the movement authority as the distance from Pc to the
authority's end, and the gradient and speed limit at Pc: every element that
depends on the position is recomputed from Pc (SPEC §4). The authority ends
``safety_margin_m`` behind the nearest obstacle ahead: the last reported rear
of the train ahead, or the start of a protection zone.

**Lost trains** (SPEC §4): a train whose reports stop for ``missed_reports_lost``
cycles is lost; its position is unknown. The controller remembers it and sets
a **protection zone** from its occupancy end (the last reported rear) to its
forward stop point (the end of the furthest authority it was given): in
``minimal`` mode every *segment* touching that range (the paper's zone); in
``conventional`` mode every *fixed block* touching it and the overlap beyond
(what the paper says conventional systems protect; the baseline). No train
is given an authority that moves its end into a zone.

**Re-detection** (SPEC §4, the paper's five steps): when a lost train reports
again, its new occupancy is compared with its zone: inside, the zone is
released and the position confirmed automatically; outside, the train moved
while lost: the zone is kept, the train is flagged and held (authority 0)
until an operator releases it after visual confirmation (:class:`ManualRelease`,
which reaches this unit only through an authenticated link).

Nothing here reads a clock or draws a number; ``now_s`` is an argument
(DESIGN rule 2). Trains run in one direction per train; the line's chainage
is one-dimensional (DESIGN: no track graph).
"""

from __future__ import annotations

import bisect
import heapq
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from enum import StrEnum

from railstop.config.layout import Cbtc
from railstop.errors import InterlockError
from railstop.messages import (
    ControllerRestart,
    ManualRelease,
    Message,
    MovementCommand,
    Output,
    PositionReport,
    TrainLeft,
)

# The grace after a report's due time before it counts as missed: half a cycle, so that the
# radio's jitter does not make a report "missed" that is merely late. [interpretation]
_GRACE_CYCLES = 0.5


class ZoneMode(StrEnum):
    MINIMAL = "minimal"  # SPEC §4: segments from the occupancy end to the forward stop point
    CONVENTIONAL = "conventional"  # SPEC §4 baseline: whole blocks plus the route's overlap


class TrainStatus(StrEnum):
    UNKNOWN = "unknown"  # has not reported yet (not on the controlled line)
    TRACKED = "tracked"
    LOST = "lost"  # SPEC §4: reports missed, position unknown, zone set
    FLAGGED = "flagged"  # re-detected outside its zone: zone kept, held, manual release needed


#: The trains whose reports the controller supervises (a flagged train is re-zoned when silent).
_SUPERVISED = (TrainStatus.TRACKED, TrainStatus.FLAGGED)


@dataclass(frozen=True, slots=True, kw_only=True)
class Zone:
    train_id: int
    start_m: float
    end_m: float


@dataclass(slots=True)
class _Train:
    train_id: int
    status: TrainStatus = TrainStatus.UNKNOWN
    report: PositionReport | None = None
    receipt_s: float = -math.inf
    missed: int = 0
    # The furthest authority end sent, signed by the direction (R: chainage, L: -chainage): any
    # of the commands in flight may be the one the train holds, so the furthest is its stop point.
    furthest_end: float = -math.inf
    granted_end_m: float = math.nan  # the end of the last authority granted (chainage)
    zone: Zone | None = None


@dataclass(slots=True)
class ZoneCounts:
    reports: int = 0
    rejected_reports: int = 0  # invalid (direction, non-finite values): treated as missed
    late_reports: int = 0  # from a train that has left the area
    commands: int = 0
    lost: int = 0
    auto_releases: int = 0  # re-detected inside the zone (SPEC §4 step 4)
    flagged: int = 0  # re-detected outside (SPEC §4 step 5)
    manual_releases: int = 0
    ignored_releases: int = 0  # a manual release for a train with no zone
    restarts: int = 0
    rezoned: int = 0  # a flagged train silent again: its zone grown over its last report


@dataclass(slots=True)
class ZoneController:
    """The unit. ``segments`` / ``blocks``: (start_m, end_m) in running order, contiguous;
    ``limit_at`` / ``gradient_at``: the line's speed limit (m/s) and gradient (‰, + uphill in R)
    at a chainage; ``train_length_m``: every train's length; ``line_end_m``: no authority beyond."""

    params: Cbtc
    segments: Sequence[tuple[float, float]]
    blocks: Sequence[tuple[float, float]]
    overlap_m: float
    train_length_m: float
    line_end_m: float
    limit_at: Callable[[float], float]
    gradient_at: Callable[[float], float]
    mode: ZoneMode = ZoneMode.MINIMAL
    name: str = "zc"
    downlink: str | None = None  # where commands go (None: straight to "cbtc-<train>")
    accepts: tuple[type, ...] = (PositionReport, ManualRelease, TrainLeft, ControllerRestart)
    trains: dict[int, _Train] = field(default_factory=dict)
    counts: ZoneCounts = field(default_factory=ZoneCounts)
    left: set[int] = field(default_factory=set)  # trains that have left the area
    _pending: list[tuple[float, int, int, PositionReport]] = field(default_factory=list)
    _seq: int = 0
    _seg_starts: list[float] = field(default_factory=list)
    _block_starts: list[float] = field(default_factory=list)

    def __post_init__(self) -> None:
        for what, items in (("segments", self.segments), ("blocks", self.blocks)):
            if not items:
                raise InterlockError(f"zone controller: {what} must not be empty")
        self._seg_starts = [a for a, _ in self.segments]
        self._block_starts = [a for a, _ in self.blocks]
        self.mode = ZoneMode(self.mode)

    # ------------------------------------------------------------------ the contract

    def handle(self, message: Message, now_s: float) -> list[Output]:
        if isinstance(message, PositionReport):
            return self._on_report(message, now_s)
        if isinstance(message, ManualRelease):
            self._on_release(message.train_id)
            return []
        if isinstance(message, ControllerRestart):
            self._restart()
            return []
        if isinstance(message, TrainLeft):
            # Out of the area: forgotten (its zone too: nothing of it is left on this line); a
            # report of it still in flight is ignored when it arrives.
            self.trains.pop(message.train_id, None)
            self.left.add(message.train_id)
            return []
        raise InterlockError(f"zone controller: cannot take a {type(message).__name__}")

    def next_deadline_s(self) -> float | None:
        times = [self._pending[0][0]] if self._pending else []
        lost_after = self.params.missed_reports_lost
        times += [
            self._due_s(t)
            for t in self.trains.values()
            if t.status in _SUPERVISED and t.missed < lost_after  # (a re-zoned flagged train waits)
        ]
        return min(times) if times else None

    def on_timer(self, now_s: float) -> list[Output]:
        out: list[Output] = []
        # Supervision first: a train lost now gets its zone before any command is computed.
        for t in self.trains.values():
            while t.status in _SUPERVISED and t.missed < self.params.missed_reports_lost:
                if now_s < self._due_s(t) - 1e-9:
                    break
                t.missed += 1
                if t.missed >= self.params.missed_reports_lost:
                    self._lose(t)
        while self._pending and self._pending[0][0] <= now_s + 1e-9:
            _, _, train_id, report = heapq.heappop(self._pending)
            known = self.trains.get(train_id)
            cmd = self._command(known, report) if known is not None else None  # None: it left meanwhile
            if cmd is not None:
                self.counts.commands += 1
                out.append(Output(to=self.downlink or f"cbtc-{train_id}", message=cmd))
        return out

    # ------------------------------------------------------------------ reports

    def _due_s(self, t: _Train) -> float:
        # The (missed + 1)-th report after the last one received is missed half a cycle after it was due.
        return t.receipt_s + (t.missed + 1 + _GRACE_CYCLES) * self.params.report_period_s

    def _on_report(self, r: PositionReport, now_s: float) -> list[Output]:
        ok = r.direction in ("R", "L") and math.isfinite(r.position_m) and math.isfinite(r.speed_mps)
        if not ok or r.speed_mps < 0.0:
            # An invalid report is no report (DESIGN rule 10): refused, counted, and the train
            # drifts towards lost as it would with the report missing.
            self.counts.rejected_reports += 1
            return []
        if r.train_id in self.left:
            self.counts.late_reports += 1
            return []
        self.counts.reports += 1
        t = self.trains.setdefault(r.train_id, _Train(train_id=r.train_id))
        if t.status in (TrainStatus.LOST, TrainStatus.FLAGGED):
            self._redetect(t, r)
        elif t.status == TrainStatus.UNKNOWN:
            t.status = TrainStatus.TRACKED
        t.report = r
        t.receipt_s = now_s
        t.missed = 0
        # SPEC §4: the command b0 is generated Δt after the report a0 is received.
        self._seq += 1
        heapq.heappush(self._pending, (now_s + self.params.processing_delay_s, self._seq, r.train_id, r))
        return []

    def _occupancy(self, r: PositionReport) -> tuple[float, float]:
        """(low, high) chainage of the train of report ``r``."""
        if r.direction == "R":
            return r.position_m - self.train_length_m, r.position_m
        return r.position_m, r.position_m + self.train_length_m

    # ------------------------------------------------------------------ lost trains (SPEC §4)

    def _lose(self, t: _Train) -> None:
        if t.report is None:  # pragma: no cover - a tracked train has reported
            return
        lo, hi = self._occupancy(t.report)
        if t.status == TrainStatus.FLAGGED and t.zone is not None:
            # Flagged (held, waiting for the operator) and silent again: its zone grows to take in
            # where it last reported, so that it still covers every place the train can be.
            # [interpretation] SPEC §4 does not say; this keeps the zone rule of a lost train.
            self.counts.rezoned += 1
            t.zone = self._cover(t.train_id, min(lo, t.zone.start_m), max(hi, t.zone.end_m))
            return
        t.status = TrainStatus.LOST
        self.counts.lost += 1
        # From the occupancy end to the forward stop point: the furthest authority it was given.
        if t.report.direction == "R":
            hi = max(hi, t.furthest_end)
        else:
            lo = min(lo, -t.furthest_end)
        t.zone = self._cover(t.train_id, lo, hi)

    def _cover(self, train_id: int, lo: float, hi: float) -> Zone:
        """The zone over [lo, hi]: whole segments (minimal) or whole blocks and the overlap beyond
        both ends (conventional)."""
        if self.mode == ZoneMode.MINIMAL:
            stretches, starts, extra = self.segments, self._seg_starts, 0.0
        else:
            stretches, starts, extra = self.blocks, self._block_starts, self.overlap_m
        lo, hi = lo - extra, hi + extra
        last = len(stretches) - 1
        # The stretch holding lo (start <= lo < end) and the one holding hi (start < hi <= end).
        i = min(max(bisect.bisect_right(starts, lo) - 1, 0), last)
        j = min(max(bisect.bisect_left(starts, hi) - 1, i), last)
        return Zone(train_id=train_id, start_m=stretches[i][0], end_m=stretches[j][1])

    def _redetect(self, t: _Train, r: PositionReport) -> None:
        """SPEC §4 steps 4 and 5: inside the zone -> release and confirm; outside -> keep, flag."""
        zone = t.zone
        lo, hi = self._occupancy(r)
        # Only the part of the train inside the controlled area counts (a train at the area's
        # entry stands partly outside it, and so does its zone's cover).
        lo, hi = max(lo, self.segments[0][0]), min(hi, self.segments[-1][1])
        if t.status == TrainStatus.LOST and zone is not None and zone.start_m <= lo and hi <= zone.end_m:
            t.zone = None
            t.status = TrainStatus.TRACKED
            self.counts.auto_releases += 1
        elif t.status == TrainStatus.LOST:
            t.status = TrainStatus.FLAGGED
            self.counts.flagged += 1
        # FLAGGED stays FLAGGED: only the operator releases it.

    def _restart(self) -> None:
        """A restart. [interpretation] SPEC §4 says nothing of it; the fail-safe reading: the
        commands being computed are gone, and no train's position can be trusted any more, so
        every train it knew (the list, the last reports and the authorities given are kept in
        non-volatile memory) is lost at once, with the zone of SPEC §4; each is re-detected by
        its next report as after a radio loss (inside: released; outside: flagged)."""
        self.counts.restarts += 1
        self._pending.clear()
        for t in self.trains.values():
            if t.status == TrainStatus.TRACKED:
                self._lose(t)

    def _on_release(self, train_id: int) -> None:
        t = self.trains.get(train_id)
        if t is None or t.zone is None:
            self.counts.ignored_releases += 1
            return
        t.zone = None
        # The operator has seen the train: its next report is its confirmed position.
        t.status = TrainStatus.TRACKED if t.report is not None else TrainStatus.UNKNOWN
        t.missed = 0
        self.counts.manual_releases += 1

    # ------------------------------------------------------------------ commands

    def zones(self) -> list[Zone]:
        return [t.zone for t in self.trains.values() if t.zone is not None]

    def _obstacle_ahead(self, me: _Train, front_m: float, direction: str) -> float:
        """The near end of the nearest obstacle ahead of the train whose front is at ``front_m``:
        another train whose front is ahead of it (its last reported occupancy), or the zone of a
        lost train ahead of it that reaches ahead of it (possibly starting behind its front: then
        the authority is 0); the area's exit otherwise."""
        # [interpretation] The area ends at the line's ends, where trains leave it (to a depot or
        # the next controller): the authority reaches past the end by a train's length, so that
        # the whole train can leave.
        exit_m = self.train_length_m + self.params.safety_margin_m + 1.0
        best = self.line_end_m + exit_m if direction == "R" else -exit_m
        for o in self.trains.values():
            if o is me:
                continue
            # A zone is in the way only of the trains behind its owner: a train ahead of a lost
            # train runs away from it, even where the zone's rounding reaches past its front.
            behind_owner = o.report is None or (
                o.report.position_m > front_m if direction == "R" else o.report.position_m < front_m
            )
            if o.zone is not None and behind_owner:
                lo, hi = o.zone.start_m, o.zone.end_m
                if direction == "R" and hi > front_m:
                    best = min(best, lo)
                elif direction == "L" and lo < front_m:
                    best = max(best, hi)
            if o.report is not None and o.status != TrainStatus.UNKNOWN:
                lo, hi = self._occupancy(o.report)
                if direction == "R" and o.report.position_m > front_m:
                    best = min(best, lo)
                elif direction == "L" and o.report.position_m < front_m:
                    best = max(best, hi)
        return best

    def _command(self, t: _Train, r: PositionReport) -> MovementCommand | None:
        # SPEC §4: every report a gets its command b, computed from that report's Pp and Vp (a
        # newer report, with Δt longer than the cycle, gets its own command in turn).
        p = self.params
        sign = 1.0 if r.direction == "R" else -1.0
        # SPEC §4: Pc = Pp ± Δt·Vp (+ in R, - in L).
        pc = r.position_m + (sign * p.processing_delay_s * r.speed_mps if p.compensate else 0.0)
        if t.status == TrainStatus.FLAGGED:
            end = pc  # held where it is until the operator releases it (DESIGN rule 10)
        else:
            # The nearest obstacle ahead (a train's last reported occupancy, a zone, the line's
            # end), less the margin; an obstacle already at the train gives authority 0.
            obstacle = self._obstacle_ahead(t, r.position_m, r.direction)
            end = obstacle - sign * p.safety_margin_m
        authority = max(sign * (end - pc), 0.0)
        t.furthest_end = max(t.furthest_end, sign * pc + authority)
        t.granted_end_m = pc + sign * authority
        grad = sign * self.gradient_at(pc)
        return MovementCommand(
            train_id=t.train_id,
            authority_m=authority,
            gradient_permille=grad,
            speed_limit_mps=self.limit_at(pc),
            report_time_s=r.time_s,
        )
