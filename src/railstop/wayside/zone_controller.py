"""The CBTC zone controller of SPEC §4, a pure unit on the ground.

It takes the trains' position reports (a) and answers each with a command (b)
after its processing delay Δt, computed from the **compensated position**::

    Pc = Pp ± Δt · Vp        (+ travelling in direction R, - in L; SPEC §4)

The command carries the movement authority as the distance from Pc to the
authority's end, and the gradient and speed limit at Pc: every element that
depends on the position is recomputed from Pc (SPEC §4); it carries Δt too,
and the onboard unit rebuilds Pc from its copy of the report, so that the end
it takes is the end meant here. The distance is sent rounded down to the
telegram's millimetre (the wire's rounding never lengthens it).

The authority ends ``safety_margin_m`` behind the nearest obstacle ahead, with
the location uncertainty of both trains and the rollback allowance (after
IEEE 1474.1's safe braking model): the last reported rear of the train ahead
*less* its uncertainty and ``rollback_m``, or the start of a protection zone;
and it is placed for the train's own front *plus* its uncertainty. A train's
occupancy (for zones, re-detection and as an obstacle) is its reported extent
widened by its uncertainty at both ends and by the rollback at its rear.

**Lost trains** (SPEC §4): a train whose reports stop for ``missed_reports_lost``
cycles (a :class:`~railstop.control.supervision.Watchdog` per train) is lost;
its position is unknown. The controller remembers it and sets a **protection
zone** from its occupancy end (the last reported rear) to its forward stop point
(the end of the furthest authority it was given): in
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
import hashlib
import heapq
import json
import math
import types
import typing
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field, fields, is_dataclass
from enum import Enum, StrEnum
from typing import Any

from railstop.config.layout import Cbtc
from railstop.control.supervision import Watchdog, WatchdogLimits
from railstop.errors import ConfigError, InterlockError
from railstop.messages import (
    ControllerRestart,
    ManualRelease,
    Message,
    MovementCommand,
    Output,
    PositionReport,
    TrainLeft,
    cbtc_grid,
    cbtc_grid_down,
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
    watchdog: Watchdog  # SPEC §4: its reports, fed at each receipt (missed_reports_lost: lost)
    status: TrainStatus = TrainStatus.UNKNOWN
    report: PositionReport | None = None
    # The furthest authority end sent, signed by the direction (R: chainage, L: -chainage), with
    # the uncertainty of the front it was placed for: any of the commands in flight may be the one
    # the train holds, so the furthest is where its true front may stop.
    furthest_end: float = -math.inf
    granted_end_m: float = math.nan  # the end of the last authority granted (chainage)
    zone: Zone | None = None


@dataclass(slots=True)
class ZoneCounts:
    reports: int = 0
    rejected_reports: int = 0  # invalid (direction, non-finite values, uncertainty): treated as missed
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
    _report_limits: WatchdogLimits = field(init=False)

    def __post_init__(self) -> None:
        for what, items in (("segments", self.segments), ("blocks", self.blocks)):
            if not items:
                raise InterlockError(f"zone controller: {what} must not be empty")
        self._seg_starts = [a for a, _ in self.segments]
        self._block_starts = [a for a, _ in self.blocks]
        self.mode = ZoneMode(self.mode)
        # A report after the last one received is missed half a cycle after it was due.
        p = self.params
        self._report_limits = WatchdogLimits(
            period_s=p.report_period_s, misses=p.missed_reports_lost, grace_cycles=_GRACE_CYCLES
        )

    def _watchdog(self, fed_s: float = -math.inf) -> Watchdog:
        """A train's report watchdog, last fed at ``fed_s``."""
        return Watchdog(self._report_limits, fed_s=fed_s)

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
        times += [
            due
            for t in self.trains.values()
            # (an expired watchdog has none: a re-zoned flagged train waits)
            if t.status in _SUPERVISED and (due := t.watchdog.next_deadline_s()) is not None
        ]
        return min(times) if times else None

    def on_timer(self, now_s: float) -> list[Output]:
        out: list[Output] = []
        # Supervision first: a train lost now gets its zone before any command is computed.
        for t in self.trains.values():
            if t.status in _SUPERVISED and not t.watchdog.lapsed and t.watchdog.expired(now_s):
                self._lose(t)
        while self._pending and self._pending[0][0] <= now_s + 1e-9:
            due_s, _, train_id, report = heapq.heappop(self._pending)
            known = self.trains.get(train_id)
            # SPEC §4: Δt runs from the report's receipt (due - the processing delay) to now.
            delay_s = max(now_s - (due_s - self.params.processing_delay_s), 0.0)
            cmd = self._command(known, report, delay_s) if known is not None else None  # None: it left
            if cmd is not None:
                self.counts.commands += 1
                out.append(Output(to=self.downlink or f"cbtc-{train_id}", message=cmd))
        return out

    # ------------------------------------------------------------------ reports

    def _on_report(self, r: PositionReport, now_s: float) -> list[Output]:
        ok = r.direction in ("R", "L") and math.isfinite(r.position_m) and math.isfinite(r.speed_mps)
        # IEEE 1474.1: the location uncertainty is part of the report; missing (NaN), negative or
        # infinite, the report says nothing about where the train is.
        ok = ok and math.isfinite(r.uncertainty_m) and r.uncertainty_m >= 0.0
        if not ok or r.speed_mps < 0.0:
            # An invalid report is no report (DESIGN rule 10): refused, counted, and the train
            # drifts towards lost as it would with the report missing.
            self.counts.rejected_reports += 1
            return []
        if r.train_id in self.left:
            self.counts.late_reports += 1
            return []
        self.counts.reports += 1
        t = self.trains.get(r.train_id)
        if t is None:
            t = self.trains[r.train_id] = _Train(train_id=r.train_id, watchdog=self._watchdog())
        if t.status in (TrainStatus.LOST, TrainStatus.FLAGGED):
            self._redetect(t, r)
        elif t.status == TrainStatus.UNKNOWN:
            t.status = TrainStatus.TRACKED
        t.report = r
        t.watchdog.feed(now_s)
        # SPEC §4: the command b0 is generated Δt after the report a0 is received.
        self._seq += 1
        heapq.heappush(self._pending, (now_s + self.params.processing_delay_s, self._seq, r.train_id, r))
        return []

    def _occupancy(self, r: PositionReport) -> tuple[float, float]:
        """(low, high) chainage the train of report ``r`` may occupy: its reported extent widened
        by its location uncertainty at both ends and by the rollback allowance at its rear (IEEE
        1474.1: the front within ± the uncertainty, and a train may roll back that far)."""
        u, back = r.uncertainty_m, self.params.rollback_m
        if r.direction == "R":
            return r.position_m - self.train_length_m - u - back, r.position_m + u
        return r.position_m - u, r.position_m + self.train_length_m + u + back

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
        t.watchdog.clear_misses()  # its cycles still timed from its last report
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
        # The train's ATO stops short of an authority's end and its braking curve keeps a reaction
        # distance there: the exit gives a safety margin more, so that the train runs out at a crawl.
        exit_m = self.train_length_m + 2.0 * self.params.safety_margin_m + 1.0
        if me.report is not None:  # ... and its own uncertainty, which the authority ends short by
            exit_m += me.report.uncertainty_m
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

    def _command(self, t: _Train, r: PositionReport, delay_s: float) -> MovementCommand | None:
        # SPEC §4: every report a gets its command b, computed from that report's Pp and Vp (a
        # newer report, with Δt longer than the cycle, gets its own command in turn).
        p = self.params
        sign = 1.0 if r.direction == "R" else -1.0
        # SPEC §4: Pc = Pp ± Δt·Vp (+ in R, - in L), Δt measured (``delay_s``) and sent on the
        # telegram's grid: the onboard unit computes the same Pc from the same numbers. Without
        # compensation (the comparison setting) the command says Δt = 0: Pc = Pp.
        dt = cbtc_grid(delay_s) if p.compensate else 0.0
        pc = r.position_m + sign * (dt * r.speed_mps)
        u = r.uncertainty_m
        if t.status == TrainStatus.FLAGGED:
            end = pc  # held where it is until the operator releases it (DESIGN rule 10)
        else:
            # The nearest obstacle ahead (a train's last reported occupancy with its uncertainty
            # and rollback, a zone, the line's end), less the margin, for a front up to the
            # train's own uncertainty ahead of its report (IEEE 1474.1); an obstacle already at
            # the train gives authority 0.
            obstacle = self._obstacle_ahead(t, r.position_m, r.direction)
            end = obstacle - sign * (p.safety_margin_m + u)
        # The distance from Pc, rounded down to the telegram's grid (never lengthened on the wire).
        authority = cbtc_grid_down(max(sign * (end - pc), 0.0))
        t.granted_end_m = pc + sign * authority  # the end meant: what the onboard unit computes
        t.furthest_end = max(t.furthest_end, sign * t.granted_end_m + u)
        grad = sign * self.gradient_at(pc)
        return MovementCommand(
            train_id=t.train_id,
            authority_m=authority,
            gradient_permille=grad,
            speed_limit_mps=self.limit_at(pc),
            report_time_s=r.time_s,
            delay_s=dt,
        )

    # ------------------------------------------------------------------ durable state (restarts)

    @staticmethod
    def state_layout() -> dict[str, Any]:
        """The layout of the controller's durable state: its name, its version and the fields of a
        train's record (a state of another layout is refused: :meth:`restore_state`)."""
        return {
            "format": "railstop-zone-controller-state",
            "version": 2,  # 2: a train's missed reports in its watchdog (was: receipt_s, missed)
            "train_fields": [f.name for f in fields(_Train)],
        }

    def state_bytes(self, saved_s: float) -> bytes:
        """The controller's durable state at ``saved_s``: every train's record (status, last report,
        furthest authority end, zone, ...: every field of ``_Train``, read with
        ``dataclasses.fields`` so that a field added later travels too) and the trains that have
        left, as JSON under a SHA-256 checksum line. What ``_restart`` assumes non-volatile memory
        keeps (SPEC §4: the lost trains, their zones and the authorities given); the commands
        being computed are not kept (a restart drops them)."""

        def plain(v: object) -> object:
            if is_dataclass(v) and not isinstance(v, type):
                return {f.name: plain(getattr(v, f.name)) for f in fields(v)}
            if isinstance(v, Enum):
                return v.value
            return v

        body = {
            **self.state_layout(),
            "saved_s": saved_s,
            "trains": [plain(t) for _, t in sorted(self.trains.items())],
            "left": sorted(self.left),
        }
        text = json.dumps(body, sort_keys=True, separators=(",", ":")).encode()
        digest = hashlib.sha256(text).hexdigest().encode()
        return b"railstop-zone-controller-state sha256 " + digest + b"\n" + text

    def restore_state(self, data: bytes) -> int:
        """A restart from the durable state ``data`` (:meth:`state_bytes`): the trains' records and
        the trains that left are restored, then the restart rule applies (``_restart``: every
        tracked train lost at once with its SPEC §4 zone, a flagged one still flagged with its zone
        kept, each re-detected by its next report). Returns the trains restored. ConfigError (and
        nothing changed) for a state that is damaged (checksum), of another format, version or
        train layout, or whose values are not of their fields' types (DESIGN rule 10: the caller
        then starts with every train unknown, :meth:`restore_unknown`)."""
        where = "zone controller state"
        head, sep, text = data.partition(b"\n")
        parts = head.split(b" ")
        if not sep or len(parts) != 3 or parts[:2] != [b"railstop-zone-controller-state", b"sha256"]:
            shown = head[:60].decode(errors="replace")
            raise ConfigError(where, "header", "not a zone controller state", shown)
        if hashlib.sha256(text).hexdigest().encode() != parts[2]:
            raise ConfigError(where, "sha256", "the checksum does not match the contents (damaged)")
        try:
            body = json.loads(text)
        except ValueError as exc:
            raise ConfigError(where, "body", f"not JSON ({exc})") from None
        if not isinstance(body, dict):
            raise ConfigError(where, "body", "not an object")
        layout = self.state_layout()
        for key, want in layout.items():
            if body.get(key) != want:
                raise ConfigError(where, key, f"this controller reads {want!r}", body.get(key))

        def typed(tp: Any, v: object, at: str) -> Any:
            # The value ``v`` as type ``tp`` (a field's annotation), strictly: a value of another
            # type is a damaged state, never a guess.
            if typing.get_origin(tp) in (typing.Union, types.UnionType):
                options = [a for a in typing.get_args(tp) if a is not type(None)]
                if v is None and len(options) < len(typing.get_args(tp)):
                    return None
                if len(options) == 1:
                    return typed(options[0], v, at)
            elif isinstance(tp, type) and is_dataclass(tp):
                names = {f.name for f in fields(tp) if f.init}
                if isinstance(v, dict) and set(v) == names:
                    hints = typing.get_type_hints(tp)
                    return tp(**{k: typed(hints[k], v[k], f"{at}.{k}") for k in names})
            elif isinstance(tp, type) and issubclass(tp, Enum):
                try:
                    return tp(v)
                except ValueError:
                    pass
            elif tp is float and isinstance(v, int | float) and not isinstance(v, bool):
                return float(v)
            elif tp in (int, str, bool) and type(v) is tp:
                return v
            raise ConfigError(where, at, f"not a value of {tp}", v)

        hints = typing.get_type_hints(_Train)
        rows = body.get("trains")
        left = body.get("left")
        if not isinstance(rows, list) or not isinstance(left, list):
            raise ConfigError(where, "trains", "a list of trains and a list of the trains that left expected")
        trains: dict[int, _Train] = {}
        for i, row in enumerate(rows):
            if not isinstance(row, dict) or set(row) != set(hints):
                raise ConfigError(where, f"trains[{i}]", "not a train record of this layout", row)
            t = _Train(**{k: typed(hints[k], row[k], f"trains[{i}].{k}") for k in hints})
            # The watchdog counts by this controller's parameters; the saved feed time and count stay.
            t.watchdog.limits = self._report_limits
            if t.train_id in trains:
                raise ConfigError(where, f"trains[{i}].train_id", "a train twice", t.train_id)
            trains[t.train_id] = t
        gone = {typed(int, k, f"left[{j}]") for j, k in enumerate(left)}
        self.trains, self.left = trains, gone
        self._restart()
        return len(trains)

    def restore_unknown(self, train_ids: Iterable[int], now_s: float) -> None:
        """A restart without a durable state (none, damaged, of another version): nothing is known
        of any train. [interpretation] SPEC §4 does not say; the fail-safe reading (DESIGN rule 10:
        unknown -> most restrictive) is that every train of the operation may be anywhere and may
        have moved while the controller was down, as a lost train re-detected outside its zone:
        each is flagged, with a zone over the whole area, held at authority 0 by every command
        (its reports are still taken) until an operator releases it after visual confirmation
        (SPEC §4 step 5)."""
        self.counts.restarts += 1
        self._pending.clear()
        area = (self.segments[0][0], self.segments[-1][1])
        for k in train_ids:
            if k in self.left:
                continue
            self.trains[k] = _Train(
                train_id=k,
                watchdog=self._watchdog(now_s),
                status=TrainStatus.FLAGGED,
                zone=Zone(train_id=k, start_m=area[0], end_m=area[1]),
            )
