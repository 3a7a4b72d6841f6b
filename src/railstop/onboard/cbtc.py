"""The onboard CBTC unit of SPEC §4, pure, one per train.

Every ``report_period_s`` it sends a position report (a) with the train's
onboard position (SPEC §2 positioning) and speed; the zone controller answers
each with a command (b): the movement authority as a distance from the
compensated position, the gradient and the speed limit there. The unit turns
the distance into an authority end on its own chainage (its position when
the command arrives plus the distance) and supervises the train against it:

* **2 consecutive missed commands -> emergency brake** (SPEC §4): a cycle
  with no command since the previous report counts as one missed;
* **overspeed**: faster than the braking curve to the authority's end (full
  service ``curve_decel_mps2`` after ``response_s``, less the command's
  downhill gradient or plus its uphill one) or than the speed limit,
  each with ``overspeed_tolerance_mps`` -> emergency brake (DESIGN rule 10;
  the supervision SPEC §4 implies but does not spell out);
* no command yet: no authority (end = where the train is).

The emergency brake is latched until the train stands still *and* a fresh
command has arrived since ([interpretation]: the usual release rule).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from railstop.config.layout import Cbtc
from railstop.errors import InterlockError
from railstop.messages import Message, MovementCommand, OnboardPosition, Output, PositionReport

G_MPS2 = 9.81
EB_MISSED_COMMANDS = "missed-commands"
EB_OVERSPEED = "overspeed"


def permitted_speed_mps(distance_m: float, decel_mps2: float, response_s: float) -> float:
    """The highest speed from which the train stops within ``distance_m`` when its brake
    responds after ``response_s`` and then decelerates at ``decel_mps2``:
    v·t + v²/(2a) = d  ->  v = a·(-t + sqrt(t² + 2d/a))."""
    if distance_m <= 0.0:
        return 0.0
    a, t = decel_mps2, response_s
    return a * (-t + math.sqrt(t * t + 2.0 * distance_m / a))


@dataclass(slots=True)
class OnboardCbtc:
    train_id: int
    direction: str
    params: Cbtc
    curve_decel_mps2: float
    response_s: float = 1.0
    overspeed_tolerance_mps: float = 5.0 / 3.6
    start_s: float = 0.0
    active: bool = True  # reporting (False: starts with its first OnboardPosition)
    uplink: str = "zc"  # where the reports go: the zone controller, or the radio before it
    name: str = ""
    accepts: tuple[type, ...] = (MovementCommand, OnboardPosition)
    position_m: float = math.nan
    speed_mps: float = 0.0
    authority_end_m: float = math.nan  # on the train's own chainage; NaN: none yet
    speed_limit_mps: float = 0.0
    gradient_permille: float = 0.0
    missed: int = 0
    emergency_brake: bool = False
    eb_cause: str | None = None
    commands: int = 0
    eb_count: int = 0  # emergency brakes applied (each latch counts once)
    eb_causes: dict[str, int] = field(default_factory=dict)  # the same, by cause
    foreign_commands: int = 0  # commands for another train: ignored, counted
    _next_report_s: float = 0.0
    _command_since_report: bool = True  # nothing to miss before the first report

    def __post_init__(self) -> None:
        if self.direction not in ("R", "L"):
            raise InterlockError(f"onboard CBTC: direction must be R or L (got {self.direction!r})")
        if not self.curve_decel_mps2 > 0.0:
            raise InterlockError(f"onboard CBTC: curve_decel_mps2 must be > 0 (got {self.curve_decel_mps2})")
        self.name = self.name or f"cbtc-{self.train_id}"
        self._next_report_s = self.start_s

    @property
    def sign(self) -> float:
        return 1.0 if self.direction == "R" else -1.0

    def distance_to_end_m(self) -> float:
        """What is left of the authority ahead (0 without one)."""
        if math.isnan(self.authority_end_m) or math.isnan(self.position_m):
            return 0.0
        return max(self.sign * (self.authority_end_m - self.position_m), 0.0)

    def permitted_mps(self) -> float:
        # SPEC §4: the command's gradient enters the braking curve (+ uphill helps the brake, -
        # downhill works against it); never below a tenth of the curve's deceleration.
        decel = max(
            self.curve_decel_mps2 + G_MPS2 * self.gradient_permille / 1000.0, 0.1 * self.curve_decel_mps2
        )
        curve = permitted_speed_mps(self.distance_to_end_m(), decel, self.response_s)
        return min(curve, self.speed_limit_mps)

    # ------------------------------------------------------------------ the contract

    def handle(self, message: Message, now_s: float) -> list[Output]:
        if isinstance(message, OnboardPosition):
            if not self.active:
                self.start(now_s)  # the first position starts the reports
            self.position_m = message.position_m
            self.speed_mps = message.speed_mps
            if self.speed_mps > self.permitted_mps() + self.overspeed_tolerance_mps:
                self._brake(EB_OVERSPEED)
            return []
        if isinstance(message, MovementCommand):
            if message.train_id != self.train_id:
                self.foreign_commands += 1
                return []
            self.commands += 1
            self._command_since_report = True
            self.missed = 0
            if not (math.isnan(self.position_m) or message.authority_m < 0.0):
                self.authority_end_m = self.position_m + self.sign * message.authority_m
            self.speed_limit_mps = max(message.speed_limit_mps, 0.0)
            self.gradient_permille = message.gradient_permille
            if self.emergency_brake and self.speed_mps <= 0.0:
                # Standstill, and a fresh command since: the latch releases.
                self.emergency_brake = False
                self.eb_cause = None
            return []
        raise InterlockError(f"onboard CBTC: cannot take a {type(message).__name__}")

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
        if not self._command_since_report:
            self.missed += 1
            if self.missed >= p.missed_commands_eb:
                self._brake(EB_MISSED_COMMANDS)
        self._command_since_report = False
        if math.isnan(self.position_m):
            return []  # no position yet: nothing to report
        report = PositionReport(
            train_id=self.train_id,
            position_m=self.position_m,
            speed_mps=max(self.speed_mps, 0.0),
            direction=self.direction,
            time_s=now_s,
        )
        return [Output(to=self.uplink, message=report)]

    def _brake(self, cause: str) -> None:
        if not self.emergency_brake:
            self.emergency_brake = True
            self.eb_cause = cause
            self.eb_count += 1
            self.eb_causes[cause] = self.eb_causes.get(cause, 0) + 1
