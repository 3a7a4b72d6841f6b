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

The causes are numbered for the results (``EB_*``); a run records the first
cause and the time it fired. The emergency brake is latched to standstill.
"""

from __future__ import annotations

from railstop.jit import njit_inline

EB_NONE = 0
EB_TIMEOUT = 1  # onboard: no braking telegram for supervision_timeout_s inside the zone
EB_ONBOARD_GUARD = 2  # onboard: overrun guard on the train's own odometry
EB_WAYSIDE_GUARD = 3  # wayside: overrun guard on the Doppler / passage measurements, by telegram
EB_OVERSPEED = 4  # SPEC §3 ATS / ATC: over the limit or indicated speed for longer than the grace
EB_PERMITTED_SPEED = 5  # SPEC §3 ATC: above the permitted speed

EB_CAUSES: dict[int, str] = {
    EB_TIMEOUT: "telegram-timeout",
    EB_ONBOARD_GUARD: "onboard-overrun-guard",
    EB_WAYSIDE_GUARD: "wayside-overrun-guard",
    EB_OVERSPEED: "overspeed-3s",
    EB_PERMITTED_SPEED: "over-permitted",
}


def eb_cause_name(code: int) -> str | None:
    """The cause's name (None: no emergency brake)."""
    return EB_CAUSES.get(int(code))


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
    a = max(decel_mps2, 0.0) if decel_mps2 == decel_mps2 else 0.0  # NaN: not known, assume none
    t = min(response_s, speed_mps / a) if a > 0.0 else response_s
    v = speed_mps - a * t
    avail = distance_to_end_m - (speed_mps * t - 0.5 * a * t * t)
    if avail <= 0.0:
        return True
    return v * v / (2.0 * avail) > limit_mps2
