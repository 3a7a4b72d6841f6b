"""ATS and ATC speed supervision of manually driven trains (SPEC §3), a pure unit on the train.

* **ATS** (intermittent): each wayside point gives a speed limit, held until
  the next point; over the limit for **more than 3 s** -> emergency brake,
  whatever the signal aspect (SPEC §3: it stops a driver who is unconscious
  or cannot see in fog or snow).
* **ATC** (continuous): the speed code picked up from the track is the ADU's
  indicated speed; actual above indicated -> **3 s grace, then the alarm**;
  the driver must service-brake below it in the grace. If the speed is still
  above it when the grace ends, the emergency brake (SPEC §3 ATC option 1:
  "even if the emergency brake is applied after 3 s, the train stops within
  the station"). Above the **permitted** speed (the indicated speed plus
  ``permitted_margin_mps``, [interpretation]: the source names a permitted
  speed above the indicated one without a value) the brake applies at once.
  [interpretation] SPEC §3's source says the train is then braked
  automatically ("decelerated"); railstop applies the emergency brake,
  latched to standstill like the grace's. A service brake released at the
  indicated speed would let the train of an incapacitated driver run on at
  the station's code through the platform (the codes never fall to 0 there),
  and the source's claim that option 1 stops such a train within the station
  rests on the emergency brake.

The emergency brake is latched to standstill (DESIGN rule 10). No limit
received yet: the most restrictive, 0 (a train must not run unsupervised).
The grace is timed by ``next_deadline_s`` / ``on_timer`` (DESIGN rule 2).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from railstop.control.supervision import EB_OVERSPEED, EB_PERMITTED_SPEED, eb_cause_name
from railstop.errors import InterlockError
from railstop.jit import njit_inline
from railstop.messages import BROADCAST, Message, Output, SpeedCode, SupervisionState, TrainSpeed
from railstop.quantities import kmh_to_mps

MODES = ("ats", "atc")

# --------------------------------------------------------------------------
# Compiled scalar core (railstop.jit): the rules, shared by the unit below and the stop kernel.

SV_OVER_SINCE = 0  # when the speed went above the limit (NaN: it is not)
SV_ALARM = 1
SV_EB = 2  # the cause code (control.supervision EB_*; 0: no emergency brake)
SV_SIZE = 3


@njit_inline
def supervision_init_1(sv: np.ndarray) -> None:
    sv[SV_OVER_SINCE] = np.nan
    sv[SV_ALARM] = 0.0
    sv[SV_EB] = 0.0


@njit_inline
def supervise_1(
    sv: np.ndarray, atc: bool, grace_s: float, margin_mps: float, v: float, limit: float, now: float
) -> None:
    """One judgement at ``now`` of speed ``v`` against the limit / indicated speed ``limit``."""
    if sv[SV_EB] > 0.0:
        if v <= 0.0:  # DESIGN rule 10: latched to standstill
            supervision_init_1(sv)
        return
    if v > limit:
        if math.isnan(sv[SV_OVER_SINCE]):
            sv[SV_OVER_SINCE] = now
        # SPEC §3 ATC: above the permitted speed the brake applies at once ([interpretation]).
        if atc and v > limit + margin_mps:
            sv[SV_EB] = EB_PERMITTED_SPEED
            return
        # SPEC §3: the grace ends -> ATS: emergency brake; ATC: the alarm, and the brake.
        if now - sv[SV_OVER_SINCE] >= grace_s - 1e-9:
            sv[SV_ALARM] = 1.0 if atc else 0.0
            sv[SV_EB] = EB_OVERSPEED
    else:
        sv[SV_OVER_SINCE] = np.nan
        sv[SV_ALARM] = 0.0


@dataclass(slots=True)
class SpeedSupervision:
    mode: str
    grace_s: float = 3.0  # SPEC §3
    permitted_margin_mps: float = kmh_to_mps(5.0)  # ATC only ([interpretation], see the module)
    name: str = "speed-supervision"
    accepts: tuple[type, ...] = (SpeedCode, TrainSpeed)
    limit_mps: float = 0.0
    speed_mps: float = 0.0
    last: SupervisionState | None = None
    _sv: NDArray[np.float64] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        if self.mode not in MODES:
            raise InterlockError(
                f"speed supervision: mode must be one of {', '.join(MODES)} (got {self.mode!r})"
            )
        if not (math.isfinite(self.grace_s) and self.grace_s >= 0.0):
            raise InterlockError(f"speed supervision: grace_s must be >= 0 (got {self.grace_s})")
        self._sv = np.empty(SV_SIZE)
        supervision_init_1(self._sv)

    @property
    def over_since_s(self) -> float:
        """When the speed went above the limit (NaN: it is not)."""
        return float(self._sv[SV_OVER_SINCE])

    @property
    def alarm(self) -> bool:
        return bool(self._sv[SV_ALARM] > 0.0)

    @property
    def emergency_brake(self) -> bool:
        return bool(self._sv[SV_EB] > 0.0)

    @property
    def cause(self) -> str | None:
        """The emergency brake's cause as its label (``EbCause``; None: none applied)."""
        return eb_cause_name(int(self._sv[SV_EB]))

    def handle(self, message: Message, now_s: float) -> list[Output]:
        if isinstance(message, SpeedCode):
            # An invalid limit is no limit: the most restrictive (DESIGN rule 10).
            ok = math.isfinite(message.limit_mps) and message.limit_mps >= 0.0
            self.limit_mps = message.limit_mps if ok else 0.0
        elif isinstance(message, TrainSpeed):
            self.speed_mps = message.speed_mps if math.isfinite(message.speed_mps) else math.inf
        else:
            raise InterlockError(f"speed supervision: cannot take a {type(message).__name__}")
        self._judge(now_s)
        return self._changed()

    def next_deadline_s(self) -> float | None:
        if math.isnan(self.over_since_s) or self.emergency_brake:
            return None
        return self.over_since_s + self.grace_s

    def on_timer(self, now_s: float) -> list[Output]:
        self._judge(now_s)
        return self._changed()

    # ------------------------------------------------------------------ the rules

    def _judge(self, now_s: float) -> None:
        supervise_1(
            self._sv,
            self.mode == "atc",
            self.grace_s,
            self.permitted_margin_mps,
            self.speed_mps,
            self.limit_mps,
            now_s,
        )

    def _changed(self) -> list[Output]:
        now = SupervisionState(alarm=self.alarm, emergency_brake=self.emergency_brake, cause=self.cause)
        if now == self.last:
            return []
        self.last = now
        return [Output(to=BROADCAST, message=now)]
