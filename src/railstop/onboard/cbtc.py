"""The onboard CBTC unit of SPEC §4, pure, one per train.

Every ``report_period_s`` it sends a position report (a) with the train's
onboard position (SPEC §2 positioning), speed and location uncertainty; the
zone controller answers each with a command (b): the movement authority as a
distance from the compensated position Pc = Pp ± Δt·Vp, the gradient and the
speed limit there.

**The authority is anchored to the report it answers** (SPEC §4
[interpretation]): the unit keeps the reports it sent (time, Pp, Vp, uncertainty),
finds the one the command answers by its time, rebuilds Pc from it with the
command's Δt exactly as the zone controller computed it, and takes the end at
Pc plus the distance: the very point the controller meant, wherever the train
is when the command arrives. Reports and commands carry their values on the
telegrams' grid (``messages.cbtc_grid``), so both ends compute with the same
numbers. A command that answers a report the unit does not hold (never sent,
older than the last ``missed_commands_eb`` reports, or not newer than the
report of the authority it holds: out of order) or that carries an invalid
value is **not an authority**: ignored and counted, and the cycle stays a
missed one (DESIGN rule 10).

Supervision:

* **2 consecutive missed commands -> emergency brake** (SPEC §4): a cycle
  with no accepted command since the previous report counts as one missed
  (a :class:`~railstop.control.supervision.Watchdog` on the unit's report cycle);
* **overspeed** (IEEE 1474.1 safe braking model; the supervision SPEC §4
  implies but does not spell out): faster than the emergency brake
  intervention speed to the authority's end (detection and propulsion
  cut-off with runaway acceleration, brake build-up, the guaranteed emergency
  brake rate, the command's downhill gradient: :func:`safe_braking_distance_m`),
  or than the speed limit plus ``overspeed_tolerance_mps`` -> emergency brake.
  The distance to the end is less what the location uncertainty has grown
  since the report the authority answers (the controller took the front
  at the report's uncertainty);
* an invalid onboard position (non-finite, negative or missing uncertainty)
  -> emergency brake, and no report until a valid one (DESIGN rule 10);
* no command yet: no authority (end = where the train is).

``permitted_mps`` is the driving curve (full service ``curve_decel_mps2`` after
``response_s``, kept ``overspeed_tolerance_mps`` under the intervention curve)
a driver or an ATO holds to stay clear of the emergency brake.

The emergency brake is latched until the train stands still *and* a fresh
command has been accepted since ([interpretation]: the usual release rule).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from railstop.config.layout import Cbtc
from railstop.control.supervision import EbCause, Watchdog, WatchdogLimits
from railstop.errors import InterlockError
from railstop.messages import (
    Message,
    MovementCommand,
    OnboardPosition,
    Output,
    PositionReport,
    cbtc_grid,
    cbtc_grid_up,
)
from railstop.quantities import kmh_to_mps

G_MPS2 = 9.81


def permitted_speed_mps(distance_m: float, decel_mps2: float, response_s: float) -> float:
    """The highest speed from which the train stops within ``distance_m`` when its brake
    responds after ``response_s`` and then decelerates at ``decel_mps2``:
    v·t + v²/(2a) = d  ->  v = a·(-t + sqrt(t² + 2d/a))."""
    if distance_m <= 0.0:
        return 0.0
    a, t = decel_mps2, response_s
    return a * (-t + math.sqrt(t * t + 2.0 * distance_m / a))


def _phases(p: Cbtc, gradient_permille: float) -> tuple[float, float, float, float, float]:
    """(reaction time, acceleration during it, build-up time, acceleration during it, braking
    rate) of the safe braking model on ``gradient_permille`` (+ uphill in the direction of travel).
    [interpretation] Only a downhill gradient enters: the command carries the gradient at Pc
    alone, not the worst over the braking distance, so an uphill one is no credit."""
    down = G_MPS2 * max(-gradient_permille, 0.0) / 1000.0
    t_r = p.overspeed_detection_s + p.propulsion_cutoff_s
    return t_r, p.runaway_accel_mps2 + down, p.brake_build_up_s, down, p.gebr_mps2 - down


def safe_braking_distance_m(speed_mps: float, params: Cbtc, gradient_permille: float = 0.0) -> float:
    """IEEE 1474.1 safe braking distance from ``speed_mps``: the train runs away at the runaway
    acceleration (plus the downhill gradient) while the overspeed is detected and the propulsion
    cut, coasts (downhill: accelerates) while the emergency brake builds up, then stops at the
    guaranteed emergency brake rate less the downhill gradient (inf where that is not positive)."""
    t_r, a_r, t_b, a_b, b = _phases(params, gradient_permille)
    if b <= 0.0:
        return math.inf
    v1 = speed_mps + a_r * t_r
    v2 = v1 + a_b * t_b
    return speed_mps * t_r + 0.5 * a_r * t_r * t_r + v1 * t_b + 0.5 * a_b * t_b * t_b + v2 * v2 / (2.0 * b)


def approach_within_authority(
    *,
    front_m: float,
    speed_mps: float,
    hold_to_m: float,
    stop_m: float,
    authority_m: float,
    advance_mps: float,
    params: Cbtc,
    margin_m: float,
    samples: int = 64,
) -> bool:
    """Whether a station stop's approach stays within an authority that advances: the train from
    ``front_m`` at ``speed_mps`` holds its speed to ``hold_to_m`` (the first detector) and then
    brakes uniformly to a stand at ``stop_m``; the authority's end, ``authority_m`` now, advances
    at ``advance_mps``. True when at every sampled instant the end lies at least the safe braking
    distance (:func:`safe_braking_distance_m`) and ``margin_m`` ahead of the front, and at least
    ``margin_m`` beyond the stopping point once the train stands. [interpretation] A prediction
    for capacity (the line's ``handover = "predictive"``), not a safety function: the onboard
    unit supervises the authority it actually has throughout."""
    if not (math.isfinite(authority_m) and math.isfinite(advance_mps) and speed_mps > 0.0):
        return False
    hold = max(hold_to_m - front_m, 0.0)
    brake_m = stop_m - max(hold_to_m, front_m)
    if brake_m <= 0.0:
        return authority_m >= stop_m + margin_m
    t_hold = hold / speed_mps
    decel = speed_mps * speed_mps / (2.0 * brake_m)
    t_end = t_hold + speed_mps / decel
    for k in range(samples + 1):
        t = t_end * k / samples
        if t <= t_hold:
            x, v = front_m + speed_mps * t, speed_mps
        else:
            tb = t - t_hold
            x = front_m + hold + speed_mps * tb - 0.5 * decel * tb * tb
            v = max(speed_mps - decel * tb, 0.0)
        if authority_m + advance_mps * t - x < safe_braking_distance_m(v, params) + margin_m:
            return False
    return authority_m + advance_mps * t_end >= stop_m + margin_m


def intervention_speed_mps(distance_m: float, params: Cbtc, gradient_permille: float = 0.0) -> float:
    """The emergency brake intervention speed: the highest speed whose safe braking distance
    (:func:`safe_braking_distance_m`) is within ``distance_m`` (0 where none is)."""
    t_r, a_r, t_b, a_b, b = _phases(params, gradient_permille)
    if distance_m <= 0.0 or b <= 0.0:
        return 0.0
    # With w = v2 = v + c (c the speed gained before braking) and T = t_r + t_b the distance is
    # w²/(2b) + T·w + (k - T·c), k what the gains add: solve the quadratic for w.
    c = a_r * t_r + a_b * t_b
    total = t_r + t_b
    k = 0.5 * a_r * t_r * t_r + a_r * t_r * t_b + 0.5 * a_b * t_b * t_b
    q = k - total * c - distance_m
    disc = total * total - 2.0 * q / b
    w = b * (-total + math.sqrt(max(disc, 0.0)))
    return max(w - c, 0.0)


@dataclass(frozen=True, slots=True)
class _Sent:
    """A report the unit sent, as the telegram carries it."""

    time_s: float
    position_m: float
    speed_mps: float
    uncertainty_m: float


@dataclass(slots=True)
class OnboardCbtc:
    train_id: int
    direction: str
    params: Cbtc
    curve_decel_mps2: float  # the driving curve's rate (full service), not the supervision's
    response_s: float = 1.0
    overspeed_tolerance_mps: float = kmh_to_mps(5.0)
    start_s: float = 0.0
    active: bool = True  # reporting (False: starts with its first OnboardPosition)
    uplink: str = "zc"  # where the reports go: the zone controller, or the radio before it
    name: str = ""
    accepts: tuple[type, ...] = (MovementCommand, OnboardPosition)
    position_m: float = math.nan
    speed_mps: float = 0.0
    uncertainty_m: float = math.nan  # the positioning's present confidence bound
    authority_end_m: float = math.nan  # on the train's own chainage; NaN: none yet
    held_uncertainty_m: float = 0.0  # the uncertainty of the report the held authority answers
    speed_limit_mps: float = 0.0
    gradient_permille: float = 0.0
    emergency_brake: bool = False
    eb_cause: EbCause | None = None
    commands: int = 0
    eb_count: int = 0  # emergency brakes applied (each latch counts once)
    eb_causes: dict[EbCause, int] = field(default_factory=dict)  # the same, by cause
    foreign_commands: int = 0  # commands for another train: ignored, counted
    refused_commands: int = 0  # answering no report held, or invalid: no authority, counted
    _next_report_s: float = 0.0
    # SPEC §4: the commands, counted missed on the report cycle (nothing to miss before the first).
    watchdog: Watchdog = field(init=False)
    _sent: list[_Sent] = field(default_factory=list)  # the last reports sent, oldest first
    _answered_s: float = -math.inf  # the time of the report the held authority answers

    def __post_init__(self) -> None:
        if self.direction not in ("R", "L"):
            raise InterlockError(f"onboard CBTC: direction must be R or L (got {self.direction!r})")
        if not self.curve_decel_mps2 > 0.0:
            raise InterlockError(f"onboard CBTC: curve_decel_mps2 must be > 0 (got {self.curve_decel_mps2})")
        self.name = self.name or f"cbtc-{self.train_id}"
        self._next_report_s = self.start_s
        p = self.params
        self.watchdog = Watchdog(WatchdogLimits(period_s=p.report_period_s, misses=p.missed_commands_eb))

    @property
    def sign(self) -> float:
        return 1.0 if self.direction == "R" else -1.0

    def distance_to_end_m(self) -> float:
        """What is left of the authority ahead (0 without one), less the growth of the location
        uncertainty since the report the authority answers: the controller placed the end for a
        front up to that report's uncertainty ahead of its position."""
        if math.isnan(self.authority_end_m) or math.isnan(self.position_m):
            return 0.0
        growth = max(self.uncertainty_m - self.held_uncertainty_m, 0.0)
        return max(self.sign * (self.authority_end_m - self.position_m) - growth, 0.0)

    def intervention_mps(self) -> float:
        """The emergency brake intervention speed here: the safe braking model to the authority's
        end, and the speed limit plus the tolerance."""
        curve = intervention_speed_mps(self.distance_to_end_m(), self.params, self.gradient_permille)
        return min(curve, self.speed_limit_mps + self.overspeed_tolerance_mps)

    def permitted_mps(self) -> float:
        """The driving curve: full service after ``response_s`` to the end (the command's gradient
        in it, + uphill helps, - downhill works against; never below a tenth of the rate), the
        speed limit, and the tolerance under the intervention curve."""
        decel = max(
            self.curve_decel_mps2 + G_MPS2 * self.gradient_permille / 1000.0, 0.1 * self.curve_decel_mps2
        )
        curve = permitted_speed_mps(self.distance_to_end_m(), decel, self.response_s)
        below = self.intervention_mps() - self.overspeed_tolerance_mps
        return max(min(curve, self.speed_limit_mps, below), 0.0)

    # ------------------------------------------------------------------ the contract

    def handle(self, message: Message, now_s: float) -> list[Output]:
        if isinstance(message, OnboardPosition):
            return self._on_position(message, now_s)
        if isinstance(message, MovementCommand):
            self._on_command(message, now_s)
            return []
        raise InterlockError(f"onboard CBTC: cannot take a {type(message).__name__}")

    def _on_position(self, message: OnboardPosition, now_s: float) -> list[Output]:
        if not self.active:
            self.start(now_s)  # the first position starts the reports
        u = message.uncertainty_m
        finite = math.isfinite(message.position_m) and math.isfinite(message.speed_mps) and math.isfinite(u)
        if not finite or u < 0.0:
            # DESIGN rule 10: a position the unit cannot trust is no position: it stops reporting
            # (the controller loses the train, SPEC §4) and brakes.
            self.position_m = math.nan
            self.uncertainty_m = math.nan
            self._brake(EbCause.POSITION_INVALID)
            return []
        self.position_m = message.position_m
        self.speed_mps = message.speed_mps
        self.uncertainty_m = u
        if self.speed_mps > self.intervention_mps():
            self._brake(EbCause.CBTC_OVERSPEED)
        return []

    def _answered(self, message: MovementCommand) -> _Sent | None:
        """The report the command answers, if the unit holds it and it is newer than the one the
        held authority answers (an older one is out of order: its end may be stale)."""
        if not message.report_time_s > self._answered_s:
            return None
        for s in reversed(self._sent):
            if s.time_s == message.report_time_s:
                return s
        return None

    def _on_command(self, message: MovementCommand, now_s: float) -> None:
        if message.train_id != self.train_id:
            self.foreign_commands += 1
            return
        sent = self._answered(message)
        a, dt = message.authority_m, message.delay_s
        valid = (
            sent is not None
            and math.isfinite(a)
            and a >= 0.0
            and math.isfinite(dt)
            and dt >= 0.0
            and math.isfinite(message.speed_limit_mps)
            and math.isfinite(message.gradient_permille)
        )
        if sent is None or not valid:
            # Not an authority (DESIGN rule 10): the one held stays, and the cycle counts missed.
            self.refused_commands += 1
            return
        self.commands += 1
        self.watchdog.feed(now_s)
        # SPEC §4: Pc = Pp ± Δt·Vp of the answered report, computed as the controller did; the
        # authority is the distance from Pc [interpretation: anchored to the report, not to where
        # the train is when the command arrives].
        pc = sent.position_m + self.sign * (dt * sent.speed_mps)
        self.authority_end_m = pc + self.sign * a
        self.held_uncertainty_m = sent.uncertainty_m
        self._answered_s = sent.time_s
        self._sent = [s for s in self._sent if s.time_s > sent.time_s]
        self.speed_limit_mps = max(message.speed_limit_mps, 0.0)
        self.gradient_permille = message.gradient_permille
        if self.emergency_brake and self.speed_mps <= 0.0 and not math.isnan(self.position_m):
            # Standstill, and a fresh command since: the latch releases.
            self.emergency_brake = False
            self.eb_cause = None

    def start(self, now_s: float) -> None:
        """Start reporting now (the first report goes out at once)."""
        if not self.active:
            self.active = True
            self._next_report_s = now_s

    def next_deadline_s(self) -> float | None:
        return self._next_report_s if self.active else None

    def on_timer(self, now_s: float) -> list[Output]:
        p = self.params
        self._next_report_s = now_s + p.report_period_s
        # SPEC §4: a cycle without a command since the last report is a missed command.
        if self.watchdog.end_cycle():
            self._brake(EbCause.MISSED_COMMANDS)
        if math.isnan(self.position_m):
            return []  # no position yet (or none to trust): nothing to report
        # The values on the telegrams' grid; the uncertainty widened by what rounding moved the
        # position and rounded up, so that it still bounds the true front.
        x = cbtc_grid(self.position_m)
        sent = _Sent(
            time_s=cbtc_grid(now_s),
            position_m=x,
            speed_mps=cbtc_grid(max(self.speed_mps, 0.0)),
            uncertainty_m=cbtc_grid_up(self.uncertainty_m + abs(self.position_m - x)),
        )
        # [interpretation] A command answering a report older than the last missed_commands_eb
        # is too old to be an authority: by then the unit has counted that many cycles missed.
        self._sent = [*self._sent, sent][-p.missed_commands_eb :]
        report = PositionReport(
            train_id=self.train_id,
            position_m=sent.position_m,
            speed_mps=sent.speed_mps,
            direction=self.direction,
            time_s=sent.time_s,
            uncertainty_m=sent.uncertainty_m,
        )
        return [Output(to=self.uplink, message=report)]

    def _brake(self, cause: EbCause) -> None:
        if not self.emergency_brake:
            self.emergency_brake = True
            self.eb_cause = cause
            self.eb_count += 1
            self.eb_causes[cause] = self.eb_causes.get(cause, 0) + 1
