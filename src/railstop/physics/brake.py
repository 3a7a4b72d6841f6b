"""The brake chain of SPEC §1: brake line codes, PWM, brake ECU and actuator.

Everything works on numpy arrays of shape ``(n,)``: one detailed stop is
``n = 1``, a campaign chunk is ``n = 10^4`` (DESIGN rule 1).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from railstop.config.schema import BrakeModel
from railstop.jit import njit_inline, njit_step

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
BoolArray = NDArray[np.bool_]

# SPEC §1 fig. 3: the 3-wire step code (a, b, c) of the brake line.
# Notch 0 (000) is "no service brake"; wire e carries the emergency brake.
STEP_CODE: dict[int, tuple[int, int, int]] = {
    0: (0, 0, 0),
    1: (0, 0, 1),
    2: (0, 1, 0),
    3: (0, 1, 1),
    4: (1, 0, 0),
    5: (1, 0, 1),
    6: (1, 1, 0),
    7: (1, 1, 1),
}
_CODE_A = np.array([STEP_CODE[k][0] for k in range(8)], dtype=np.int8)
_CODE_B = np.array([STEP_CODE[k][1] for k in range(8)], dtype=np.int8)
_CODE_C = np.array([STEP_CODE[k][2] for k in range(8)], dtype=np.int8)
_DECODE = {v: k for k, v in STEP_CODE.items()}
_DECODE_TABLE = np.array([_DECODE[((i >> 2) & 1, (i >> 1) & 1, i & 1)] for i in range(8)])


@dataclass(frozen=True, slots=True, kw_only=True)
class BrakeLine:
    """The wires of the brake line (SPEC §1): service wires a, b, c and emergency wire e."""

    a: NDArray[np.int8]
    b: NDArray[np.int8]
    c: NDArray[np.int8]
    e: NDArray[np.int8]


def encode_step(notch: IntArray, emergency: BoolArray | None = None) -> BrakeLine:
    """Brake signal distributor (encoder): notch 0..7 -> wires a, b, c (SPEC §1 fig. 3)."""
    notch = np.asarray(notch)
    if np.any((notch < 0) | (notch > 7)):
        bad = notch[(notch < 0) | (notch > 7)][0]
        raise ValueError(f"notch must be 0..7, got {bad}")
    e = np.zeros(notch.shape, np.int8) if emergency is None else emergency.astype(np.int8)
    return BrakeLine(a=_CODE_A[notch], b=_CODE_B[notch], c=_CODE_C[notch], e=e)


def decode_step(line: BrakeLine) -> IntArray:
    """Brake ECU input: wires a, b, c -> notch 0..7, by the table of SPEC §1 fig. 3."""
    idx = (line.a.astype(np.int64) << 2) | (line.b.astype(np.int64) << 1) | line.c.astype(np.int64)
    return _DECODE_TABLE[idx]


def notch_decel(notch: IntArray, brake: BrakeModel) -> FloatArray:
    """Deceleration demanded by a service notch (0 = released)."""
    table = np.concatenate(([0.0], np.asarray(brake.notch_decel_mps2, dtype=np.float64)))
    return table[np.asarray(notch)]


def pwm_to_decel(duty: FloatArray, brake: BrakeModel) -> FloatArray:
    """Brake ECU PWM input: duty ratio -> deceleration by the vehicle's map."""
    return np.interp(duty, brake.pwm_duty, brake.pwm_decel_mps2)


def decel_to_pwm(decel_mps2: FloatArray, brake: BrakeModel) -> FloatArray:
    """Inverse of :func:`pwm_to_decel` on the map's rising part (smallest duty giving decel)."""
    duty = np.asarray(brake.pwm_duty, dtype=np.float64)
    dec = np.asarray(brake.pwm_decel_mps2, dtype=np.float64)
    d = np.clip(np.asarray(decel_mps2, dtype=np.float64), dec.min(), dec.max())
    # The map may have flat stretches; invert each rising segment on its own,
    # the first (lowest-duty) segment containing the value wins.
    out = np.full(d.shape, np.nan)
    for i in range(dec.size - 1):
        if dec[i + 1] > dec[i]:
            m = np.isnan(out) & (d >= dec[i]) & (d <= dec[i + 1])
            out[m] = duty[i] + (d[m] - dec[i]) * (duty[i + 1] - duty[i]) / (dec[i + 1] - dec[i])
    # Values on the lowest plateau: the last duty that still gives it.
    low_end = duty[int(np.flatnonzero(dec == dec.min())[-1])]
    return np.where(np.isnan(out), low_end, out)


def superimpose_pwm(existing_duty: FloatArray, onboard_duty: FloatArray) -> FloatArray:
    """SPEC §1 config 3: OR of two PWM pulse trains synchronised at the zero crossing.

    Both pulses start at the same zero crossing, so their OR is high for the
    longer of the two: the ECU sees the larger duty (existing 50 % + onboard
    70 % -> 70 %).
    """
    return np.maximum(existing_duty, onboard_duty)


def or_pulse_duty(duty_1: FloatArray, duty_2: FloatArray, phase: FloatArray) -> FloatArray:
    """Duty of the OR of two pulses of one period when pulse 2 starts ``phase`` periods later.

    ``phase = 0`` is the synchronised case of :func:`superimpose_pwm`; any other
    phase makes the union longer than either pulse, which is why SPEC §1
    config 3 synchronises to the zero crossing.
    """
    d1 = np.asarray(duty_1, dtype=np.float64)
    d2 = np.asarray(duty_2, dtype=np.float64)
    p = np.mod(np.asarray(phase, dtype=np.float64), 1.0)
    # Pulse 2 occupies [p, p + d2) modulo 1; split it at the period end.
    seg1_lo, seg1_hi = p, np.minimum(p + d2, 1.0)
    seg2_hi = np.maximum(p + d2 - 1.0, 0.0)  # wrapped part [0, seg2_hi)
    # Measure of [0, d1) ∪ [seg1_lo, seg1_hi) ∪ [0, seg2_hi)
    first = np.maximum(d1, seg2_hi)  # [0, first) covered
    extra = np.maximum(seg1_hi - np.maximum(seg1_lo, first), 0.0)
    return np.minimum(first + extra, 1.0)


@dataclass(slots=True, kw_only=True)
class ActuatorState:
    """Brake actuator chain state for n runs: dead time, jerk limiter, first-order lag."""

    ring: FloatArray  # (n, L) delayed demands, written at column k % L
    delay_steps: IntArray  # (n,)
    limited_mps2: FloatArray  # after the jerk limiter
    output_mps2: FloatArray  # after the first-order lag
    lag_alpha: FloatArray  # 1 - exp(-dt / tau)
    jerk_step_mps2: float
    emergency_mps2: float
    k: int = 0

    @classmethod
    def create(
        cls,
        *,
        n: int,
        dt_s: float,
        dead_time_s: FloatArray,
        time_constant_s: FloatArray,
        jerk_limit_mps3: float,
        emergency_mps2: float,
    ) -> ActuatorState:
        delay = np.rint(np.asarray(dead_time_s) / dt_s).astype(np.int64)
        length = int(delay.max()) + 1 if delay.size else 1
        return cls(
            ring=np.zeros((n, length)),
            delay_steps=delay,
            limited_mps2=np.zeros(n),
            output_mps2=np.zeros(n),
            lag_alpha=1.0 - np.exp(-dt_s / np.asarray(time_constant_s, dtype=np.float64)),
            jerk_step_mps2=jerk_limit_mps3 * dt_s,
            emergency_mps2=emergency_mps2,
        )


def actuator_step(state: ActuatorState, demand_mps2: FloatArray) -> FloatArray:
    """Advance the actuator one step; returns the deceleration the brakes now give.

    SPEC §1 / issue: dead time (pure delay, rounded to the step), then the ECU
    jerk limiter (rate limit, bypassed by the emergency brake), then the
    build-up first-order lag: y += (u - y)(1 - e^(-dt/tau)), exact for a
    piecewise-constant input.
    """
    length = state.ring.shape[1]
    col = state.k % length
    state.ring[:, col] = demand_mps2
    rows = np.arange(state.ring.shape[0])
    delayed = state.ring[rows, (state.k - state.delay_steps) % length]
    step = np.clip(delayed - state.limited_mps2, -state.jerk_step_mps2, state.jerk_step_mps2)
    emergency = delayed >= state.emergency_mps2 - 1e-9
    state.limited_mps2 = np.where(emergency, delayed, state.limited_mps2 + step)
    state.output_mps2 = state.output_mps2 + (state.limited_mps2 - state.output_mps2) * state.lag_alpha
    state.k += 1
    return state.output_mps2


def ecu_demand_mps2(
    *, line: BrakeLine | None, duty: FloatArray | None, emergency: BoolArray, brake: BrakeModel
) -> FloatArray:
    """Brake ECU: the deceleration it is asked for, from the step code or the PWM duty.

    Wire e (emergency) overrides the service command (SPEC §1 fig. 2).
    """
    if line is not None:
        demand = notch_decel(decode_step(line), brake)
        emergency = emergency | (line.e > 0)
    elif duty is not None:
        demand = pwm_to_decel(duty, brake)
    else:
        raise ValueError("the ECU needs a step-coded brake line or a PWM duty")
    return np.where(emergency, brake.emergency_decel_mps2, demand)


def braking_decel_mps2(
    actuator_out_mps2: FloatArray,
    *,
    brake_gain: FloatArray,
    believed_effective_kg: FloatArray,
    effective_kg: FloatArray,
) -> FloatArray:
    """Deceleration the brakes give the real train.

    Load compensation: the ECU sets the brake force to demand x the mass it
    believes (load weighing); the train's real mass and the brake's real
    effectiveness (``brake_gain`` = actual / nominal) decide what that force does.
    """
    return actuator_out_mps2 * brake_gain * believed_effective_kg / effective_kg


# --------------------------------------------------------------------------
# Compiled scalar cores (railstop.jit): the one implementation the stop kernel runs.

_STEP_A = np.array([STEP_CODE[k][0] for k in range(8)], dtype=np.int64)
_STEP_B = np.array([STEP_CODE[k][1] for k in range(8)], dtype=np.int64)
_STEP_C = np.array([STEP_CODE[k][2] for k in range(8)], dtype=np.int64)
_STEP_DECODE = _DECODE_TABLE.astype(np.int64)


@njit_inline
def line_notch(notch: int) -> int:
    """SPEC §1 fig. 3: notch -> wires a, b, c (the encoder) -> notch (the ECU's decoder)."""
    wires = (_STEP_A[notch] << 2) | (_STEP_B[notch] << 1) | _STEP_C[notch]
    return int(_STEP_DECODE[wires])


@njit_inline
def interp_1(x: float, xp: FloatArray, fp: FloatArray) -> float:
    """``np.interp`` of one number, by numpy's own algorithm (the same result to the bit).

    Below the first point fp[0], above the last fp[-1]; on a point its value
    exactly; otherwise slope · (x - xp[j]) + fp[j]. (numba's np.interp on a
    scalar allocates and costs ~300 ns per call; this costs a few.)
    """
    if x != x:
        return x
    n = xp.size
    j = 0
    while j < n and x >= xp[j]:
        j += 1
    j -= 1
    if j == -1:
        return fp[0]
    if j == n - 1:
        return fp[n - 1]
    if xp[j] == x:
        return fp[j]
    slope = (fp[j + 1] - fp[j]) / (xp[j + 1] - xp[j])
    y = slope * (x - xp[j]) + fp[j]
    if y != y:
        y = slope * (x - xp[j + 1]) + fp[j + 1]
        if y != y and fp[j] == fp[j + 1]:
            y = fp[j]
    return y


@njit_inline
def pwm_to_decel_1(duty: float, pwm_duty: FloatArray, pwm_decel: FloatArray) -> float:
    """Brake ECU PWM input: duty -> deceleration by the vehicle's map (linear interpolation)."""
    return interp_1(duty, pwm_duty, pwm_decel)


@njit_step
def decel_to_pwm_1(decel_mps2: float, pwm_duty: FloatArray, pwm_decel: FloatArray) -> float:
    """Inverse of the PWM map on its rising part: the smallest duty giving ``decel_mps2``.

    The map may have flat stretches; each rising segment is inverted on its
    own and the first (lowest-duty) one containing the value wins; a value on
    the lowest plateau gets the last duty that still gives it.
    """
    lo = pwm_decel[0]
    hi = pwm_decel[0]
    for value in pwm_decel:
        lo = min(lo, value)
        hi = max(hi, value)
    d = decel_mps2 if decel_mps2 != decel_mps2 else min(max(decel_mps2, lo), hi)
    for i in range(pwm_decel.size - 1):
        if pwm_decel[i + 1] > pwm_decel[i] and d >= pwm_decel[i] and d <= pwm_decel[i + 1]:
            return float(
                pwm_duty[i]
                + (d - pwm_decel[i]) * (pwm_duty[i + 1] - pwm_duty[i]) / (pwm_decel[i + 1] - pwm_decel[i])
            )
    last = 0
    for i in range(pwm_decel.size):
        if pwm_decel[i] == lo:
            last = i
    return float(pwm_duty[last])


@njit_inline
def actuator_step_1(
    ring: FloatArray,
    k: int,
    delay_steps: int,
    demand_mps2: float,
    limited_mps2: float,
    output_mps2: float,
    lag_alpha: float,
    jerk_step_mps2: float,
    emergency_mps2: float,
) -> tuple[float, float]:
    """One step of the actuator chain; returns (limited, output): the brakes' deceleration is ``output``.

    Dead time (pure delay of ``delay_steps``, ring of at least delay + 1
    slots), the ECU jerk limiter (rate limit, bypassed by the emergency
    brake), then the build-up first-order lag y += (u - y)(1 - e^(-dt/tau)),
    exact for a piecewise-constant input.
    """
    length = ring.size
    slot = k % length
    ring[slot] = demand_mps2
    past = slot - delay_steps  # (k - delay) mod length, without a second division
    delayed = ring[past + length if past < 0 else past]
    step = min(max(delayed - limited_mps2, -jerk_step_mps2), jerk_step_mps2)
    limited = delayed if delayed >= emergency_mps2 - 1e-9 else limited_mps2 + step
    return limited, output_mps2 + (limited - output_mps2) * lag_alpha
