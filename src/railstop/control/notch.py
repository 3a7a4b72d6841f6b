"""Realising a continuous deceleration with the 7 service notches (SPEC §1).

A step-controlled brake has only B1..B7. A brake controller that must follow
a continuous target alternates between the two notches either side of it,
with the time shares that make the mean equal the target: a first-order
sigma-delta modulator, with a minimum hold time so the brake line is not
chattered. The actuator's lag smooths the alternation.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


def nearest_notch(decel_mps2: FloatArray, notch_decel_mps2: FloatArray) -> IntArray:
    """Notch 0..7 whose deceleration is nearest to the target (0 = released)."""
    table = np.concatenate(([0.0], notch_decel_mps2))
    return np.abs(np.asarray(decel_mps2)[:, None] - table[None, :]).argmin(axis=1)


@dataclass(slots=True, kw_only=True)
class NotchModulator:
    """Second-order sigma-delta between the two notches around the target.

    What matters for the stopping point is the position error, the double
    integral of (target - applied) deceleration, so the modulator keeps that
    double integral near zero (a first-order modulator only bounds the speed
    error). "Applied" is the notch deceleration passed through a first-order
    model of the brake response (time constant = dead time + lag), so the
    alternation is timed against what the brakes will really do. The
    integrators restart whenever a new target arrives: the wayside computed it
    from the train's measured state, which already contains the past error.
    """

    table_mps2: FloatArray  # (8,) with 0 for notch 0
    min_hold_s: float
    response_s: float
    notch: IntArray
    applied_mps2: FloatArray  # modelled brake response to the notches
    target_mps2: FloatArray  # modelled response to the target
    e1_mps: FloatArray
    e2_m: FloatArray
    held_s: FloatArray
    changes: IntArray

    @classmethod
    def create(
        cls, n: int, notch_decel_mps2: list[float], min_hold_s: float, response_s: float
    ) -> NotchModulator:
        return cls(
            table_mps2=np.concatenate(([0.0], np.asarray(notch_decel_mps2, dtype=np.float64))),
            min_hold_s=min_hold_s,
            response_s=response_s,
            notch=np.zeros(n, dtype=np.int64),
            applied_mps2=np.zeros(n),
            target_mps2=np.zeros(n),
            e1_mps=np.zeros(n),
            e2_m=np.zeros(n),
            held_s=np.full(n, np.inf),
            changes=np.zeros(n, dtype=np.int64),
        )

    def restart(self, mask: NDArray[np.bool_]) -> None:
        """A new target arrived for the runs in ``mask``."""
        self.e1_mps = np.where(mask, 0.0, self.e1_mps)
        self.e2_m = np.where(mask, 0.0, self.e2_m)

    def update(self, target_mps2: FloatArray, active: NDArray[np.bool_], dt_s: float) -> IntArray:
        """Advance by ``dt_s`` (the controller's cycle) and return the notch to apply."""
        table = self.table_mps2
        target = np.clip(target_mps2, 0.0, table[-1])
        alpha = 1.0 - np.exp(-dt_s / self.response_s)
        self.applied_mps2 += (table[self.notch] - self.applied_mps2) * alpha
        self.target_mps2 += (target - self.target_mps2) * alpha
        self.e1_mps += (self.target_mps2 - self.applied_mps2) * dt_s
        self.e2_m += self.e1_mps * dt_s
        lo = np.clip(np.searchsorted(table, target, side="right") - 1, 0, 7)
        hi = np.minimum(lo + 1, 7)
        # Look ahead one response time: brake more when the position error
        # (train ahead of the plan: e2 > 0) would otherwise still grow.
        horizon = self.response_s + self.min_hold_s
        want = np.where(self.e2_m + self.e1_mps * horizon > 0.0, hi, lo)
        want = np.where(table[lo] == target, lo, want)
        can_change = self.held_s + 1e-9 >= self.min_hold_s
        outside = (self.notch < lo) | (self.notch > hi)
        new = np.where(outside | can_change, want, self.notch)
        new = np.where(active, new, 0)
        changed = new != self.notch
        self.changes += changed & active
        self.held_s = np.where(changed, dt_s, self.held_s + dt_s)
        self.notch = new
        return new
