"""Traction over arrays of runs (DESIGN rule 1): tractive-effort curve, adhesion in traction, slip.

The tractive effort at the wheel is limited by the curve of the traction
equipment: a constant force ``F_max`` up to the base speed, constant power
``P = F_max · v_base`` above it::

    F(v) = F_max            v <= v_base
    F(v) = P / v            v >  v_base

The traction control aims at ``max_accel_mps2`` (load-weighed), so the
demanded acceleration is the smaller of that aim, the caller's demand and
F(v) / m_eff. Adhesion limits what the motored axles can transmit:
``mu · g · m_static · motored_fraction / m_eff``; a demand above it makes the
wheels slip, the anti-slip control then holds them ``slip_ratio`` faster than
the train while the force follows adhesion.

The result is a *traction acceleration* that the caller hands to
:func:`railstop.physics.train.motion_step` as a negative braking deceleration,
so there is one copy of the equation of motion.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from railstop.config.schema import Traction
from railstop.physics.train import G_MPS2, TrainMass
from railstop.quantities import MPS_PER_KMH

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]


def tractive_effort_n(traction: Traction, speed_mps: FloatArray) -> FloatArray:
    """Largest tractive effort (N) at ``speed_mps``: constant force, then constant power."""
    v = np.abs(np.asarray(speed_mps, dtype=np.float64))
    base = traction.base_speed_kmh * MPS_PER_KMH
    return np.where(v <= base, traction.max_force_n, traction.max_power_w / np.maximum(v, base))


def traction_adhesion_limit_mps2(mu: FloatArray, mass: TrainMass, traction: Traction) -> FloatArray:
    """Largest traction acceleration adhesion allows: mu · g · m · motored fraction / m_eff."""
    return mu * G_MPS2 * mass.static_kg * traction.motored_axle_fraction / mass.effective_kg


@dataclass(frozen=True, slots=True, kw_only=True)
class TractionOutput:
    """What the traction equipment gives in one step, for n runs."""

    accel_mps2: FloatArray  # traction force / m_eff actually transmitted (>= 0)
    slipping: BoolArray  # demand above adhesion: anti-slip control active


def traction_step(
    traction: Traction,
    *,
    demand_accel_mps2: FloatArray,
    speed_mps: FloatArray,
    mass: TrainMass,
    adhesion_mu: FloatArray,
) -> TractionOutput:
    """The traction acceleration for a demand (m/s², >= 0), limited by the curve and adhesion."""
    demand = np.clip(np.asarray(demand_accel_mps2, dtype=np.float64), 0.0, traction.max_accel_mps2)
    curve = tractive_effort_n(traction, speed_mps) / mass.effective_kg
    wanted = np.minimum(demand, curve)
    limit = traction_adhesion_limit_mps2(adhesion_mu, mass, traction)
    slipping = wanted > limit
    return TractionOutput(accel_mps2=np.minimum(wanted, limit), slipping=slipping)
