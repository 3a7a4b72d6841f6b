"""Fail-safe supervision of a TASC stop (DESIGN rules 4 and 10), compiled, shared by both sides.

Nothing in the patent (SPEC §1) applies the emergency brake; DESIGN rule 10
(fail safe) needs it, and SPEC §1 names the wire that carries it (wire e of
the brake line). Two rules use it:

* **telegram supervision** (onboard): once the train is in the TASC zone,
  braking telegrams (a new command or a cyclic repeat of the latest) must
  keep arriving; none for ``supervision_timeout_s`` -> emergency brake;
* **overrun guard** (onboard on its own odometry, and wayside on its own
  measurements): when stopping before the platform end would need more than
  full service after the brake's response time, the service brake can no
  longer do it -> emergency brake.

Every emergency brake of the tree has its cause in one enum, :class:`EbCause` (DESIGN rule 4:
one name for one thing): the stop model's supervision above, the CBTC units of SPEC §4 and the
live processes. A run of the compiled model records the first cause as its int value (the
``EB_*`` constants, 0: none) and the time it fired; what is printed, stored or sent as JSON is the
cause's ``label`` (the strings the office, the database and the tests read). The emergency brake
is latched to standstill.

The CBTC units' supervision of the reports and commands that must keep arriving is a
:class:`Watchdog` (SPEC §4: 2 missed reports -> lost, 2 missed commands -> emergency brake).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import IntEnum

from railstop.jit import njit_inline


class EbCause(IntEnum):
    """Why an emergency brake was applied. The values 1-5 are the compiled stop model's codes
    (``RX_EB``, ``SV_EB``, the results' ``emergency_brake``; 0 there means none) and never change:
    recorded results hold them."""

    TELEGRAM_TIMEOUT = 1  # onboard TASC: no braking telegram for supervision_timeout_s in the zone
    ONBOARD_OVERRUN_GUARD = 2  # onboard TASC: overrun guard on the train's own odometry
    WAYSIDE_OVERRUN_GUARD = 3  # wayside TASC: overrun guard on the Doppler / passages, by telegram
    OVERSPEED_GRACE = 4  # SPEC §3 ATS / ATC: over the limit or indicated speed longer than the grace
    OVER_PERMITTED = 5  # SPEC §3 ATC: above the permitted speed
    MISSED_COMMANDS = 6  # SPEC §4 onboard CBTC: missed_commands_eb commands missed in a row
    CBTC_OVERSPEED = 7  # onboard CBTC: over the intervention speed (safe braking model, limit)
    POSITION_INVALID = 8  # onboard CBTC: a position it cannot trust (DESIGN rule 10)
    PLANT_LOST = 9  # live: the plant process went silent; every train brakes (DESIGN rule 10)
    DWELL_FAULT = 10  # live: a SPEC §5 dwell fault; the train stands for its reset
    CBTC = 11  # a TASC stop (line, live): the CBTC unit braked, not the TASC onboard unit

    @property
    def label(self) -> str:
        """The cause as printed, stored and sent (``telegram-timeout``, ``plant-lost``, ...)."""
        return _LABELS[self]


_LABELS: dict[EbCause, str] = {
    EbCause.TELEGRAM_TIMEOUT: "telegram-timeout",
    EbCause.ONBOARD_OVERRUN_GUARD: "onboard-overrun-guard",
    EbCause.WAYSIDE_OVERRUN_GUARD: "wayside-overrun-guard",
    EbCause.OVERSPEED_GRACE: "overspeed-3s",
    EbCause.OVER_PERMITTED: "over-permitted",
    EbCause.MISSED_COMMANDS: "missed-commands",
    EbCause.CBTC_OVERSPEED: "overspeed",
    EbCause.POSITION_INVALID: "position-invalid",
    EbCause.PLANT_LOST: "plant-lost",
    EbCause.DWELL_FAULT: "dwell-fault",
    EbCause.CBTC: "cbtc",
}

# The compiled code's view (numba reads module-level ints as constants).
EB_NONE = 0
EB_TIMEOUT = int(EbCause.TELEGRAM_TIMEOUT)
EB_ONBOARD_GUARD = int(EbCause.ONBOARD_OVERRUN_GUARD)
EB_WAYSIDE_GUARD = int(EbCause.WAYSIDE_OVERRUN_GUARD)
EB_OVERSPEED = int(EbCause.OVERSPEED_GRACE)
EB_PERMITTED_SPEED = int(EbCause.OVER_PERMITTED)
EB_CBTC = int(EbCause.CBTC)

#: Code -> label of every cause (the results' counts by cause).
EB_CAUSES: dict[int, str] = {int(c): c.label for c in EbCause}


def eb_cause_name(code: int) -> str | None:
    """The label of a recorded cause code (None: 0, no emergency brake)."""
    return EB_CAUSES.get(int(code))


@njit_inline
def guard_limit_1(limit_mps2: float, emergency_mps2: float, gain: float, external_mps2: float) -> float:
    """The overrun guard's limit as this train can keep it here (stop model 18, DESIGN rule 10).

    The guard (:func:`overrun_guard_1`) brakes by emergency brake when stopping before the
    platform end needs more than ``limit_mps2``, on the premise that the emergency brake has margin
    over that. **[interpretation]** The premise holds only for the emergency brake this train's
    brakes give on this path: its nominal deceleration (``emergency_mps2``) times the brake gain
    the loop has measured (``gain``, never above 1: a strong brake does not loosen the guard),
    plus what gradient and resistance give (``external_mps2``, negative downhill: the steepest
    the train meets before the platform end). A weak brake on a downhill lowers the limit, so the
    guard fires while the emergency brake can still stop the train before the end.
    """
    return min(limit_mps2, emergency_mps2 * min(gain, 1.0) + external_mps2)


# The overrun guard's bound is taken only this far (relative) inside its limit.
_BOUND_MARGIN = 1e-9


@njit_inline
def overrun_guard_1(
    speed_mps: float, decel_mps2: float, distance_to_end_m: float, response_s: float, limit_mps2: float
) -> bool:
    """True when stopping before the end (``distance_to_end_m`` ahead) needs more than
    ``limit_mps2`` once the brake has responded (``response_s``), the train slowing at
    ``decel_mps2`` (its present deceleration, which a stronger brake demand cannot lessen)
    meanwhile.

    **[interpretation]** The issue asks for a guard "when the required deceleration exceeds
    full service with margin"; the margin here is the response and, for the limit, the
    platform end beyond the stopping point: the emergency brake (stronger than full service,
    no jerk limit) still stops the train before the end when the guard fires.
    """
    if speed_mps <= 0.0:
        return distance_to_end_m < 0.0
    # A bound first, without a division (the test below runs every step of every stop): the
    # speed after the response is at most the present one, the distance run meanwhile at most
    # speed x response. When even so stopping needs less than the limit, with a margin far above
    # the rounding of either computation, the exact test below would say no: it is not taken.
    # (A NaN anywhere makes the comparison false: the exact test decides.)
    if speed_mps * speed_mps * (1.0 + _BOUND_MARGIN) < 2.0 * limit_mps2 * (
        distance_to_end_m - speed_mps * response_s
    ):
        return False
    a = max(decel_mps2, 0.0) if decel_mps2 == decel_mps2 else 0.0  # NaN: not known, assume none
    t = min(response_s, speed_mps / a) if a > 0.0 else response_s
    v = speed_mps - a * t
    avail = distance_to_end_m - (speed_mps * t - 0.5 * a * t * t)
    if avail <= 0.0:
        return True
    return v * v / (2.0 * avail) > limit_mps2


# The timers' float sums (a deadline k periods on) may land a hair before the time the clock
# delivers; within this a deadline counts as come.
_DUE_EPS_S = 1e-9


@dataclass(frozen=True, slots=True, kw_only=True)
class WatchdogLimits:
    """What a watchdog allows, as data: something is expected once every ``period_s``; ``misses``
    cycles in a row without it and the watchdog has expired. ``grace_cycles``: a cycle timed from
    the last feed counts as missed this many cycles after it was due (radio jitter: late is not
    missed)."""

    period_s: float
    misses: int
    grace_cycles: float = 0.0


@dataclass(slots=True)
class Watchdog:
    """The supervision of something that must keep arriving (SPEC §4: the trains' position reports
    at the zone controller, the commands at the onboard unit), pure: the time is an argument.

    It counts missed cycles in a row one of two ways; a holder uses one:

    * timed from the last feed (:meth:`expired`, :meth:`next_deadline_s`): the k-th cycle after
      the feed is missed at ``fed_s + (k + grace_cycles) * period_s``; the count stops at the limit;
    * on the holder's own cycle (:meth:`end_cycle`): a cycle of the holder's that saw no feed is
      missed (the onboard unit's report cycle: a cycle without a command since the last report).

    A feed clears the count. Expired, the holder acts fail safe (DESIGN rule 10).
    """

    limits: WatchdogLimits
    fed_s: float = -math.inf  # the last feed (-inf: none yet)
    missed: int = 0  # cycles missed in a row
    fed_in_cycle: bool = True  # fed since the holder's cycle began (nothing to miss before the first)

    def feed(self, now_s: float) -> None:
        """What is supervised arrived at ``now_s``."""
        self.fed_s = now_s
        self.missed = 0
        self.fed_in_cycle = True

    def clear_misses(self) -> None:
        """Forgive the misses counted so far; the cycles stay timed from the last feed."""
        self.missed = 0

    @property
    def lapsed(self) -> bool:
        """Whether the misses have reached the limit."""
        return self.missed >= self.limits.misses

    def next_deadline_s(self) -> float | None:
        """When the next cycle timed from the last feed counts as missed (None: expired already)."""
        if self.lapsed:
            return None
        lim = self.limits
        return self.fed_s + (self.missed + 1 + lim.grace_cycles) * lim.period_s

    def expired(self, now_s: float) -> bool:
        """Count the cycles timed from the last feed that are missed by ``now_s``; whether the
        watchdog has expired."""
        while (due := self.next_deadline_s()) is not None and now_s >= due - _DUE_EPS_S:
            self.missed += 1
        return self.lapsed

    def end_cycle(self) -> bool:
        """The holder's cycle ends: missed if nothing arrived in it. Whether this made (or kept) the
        watchdog expired; a cycle that saw a feed never does."""
        missed_now = not self.fed_in_cycle
        self.fed_in_cycle = False
        if not missed_now:
            return False
        self.missed += 1
        return self.lapsed
