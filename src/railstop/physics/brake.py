"""The brake chain of SPEC §1: brake line codes, PWM, brake ECU and actuator.

The stop kernel (``railstop.model``) runs the compiled scalar cores at
the end of this module, one run at a time (DESIGN rule 1); the kernel itself
applies the ECU's load compensation.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from railstop.jit import njit_inline, njit_step

FloatArray = NDArray[np.float64]

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


def or_pulse_duty(duty_1: FloatArray, duty_2: FloatArray, phase: FloatArray) -> FloatArray:
    """Duty of the OR of two pulses of one period when pulse 2 starts ``phase`` periods later.

    ``phase = 0`` is the synchronised case of SPEC §1 config 3 (the ECU sees the larger
    duty: ``railstop.onboard.tasc_receiver.receiver_pwm_output_1``); any other
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


# --------------------------------------------------------------------------
# Compiled scalar cores (railstop.jit): the one implementation the stop kernel runs.

# The wires a, b, c of a brake line as the bits of one number: a = 4, b = 2, c = 1.
_STEP_WIRES = np.array([4 * a + 2 * b + c for a, b, c in (STEP_CODE[k] for k in range(8))], dtype=np.int64)
_STEP_DECODE = np.zeros(8, dtype=np.int64)
_STEP_DECODE[_STEP_WIRES] = np.arange(8)


@njit_inline
def encode_step_1(notch: int) -> int:
    """Brake signal distributor (encoder), SPEC §1 fig. 3: notch 0..7 -> wires a, b, c as the
    bits of one number (a = 4, b = 2, c = 1)."""
    return int(_STEP_WIRES[notch])


@njit_inline
def decode_step_1(wires: int) -> int:
    """Brake ECU input, SPEC §1 fig. 3: wires a, b, c (bits a = 4, b = 2, c = 1) -> notch 0..7."""
    return int(_STEP_DECODE[wires])


@njit_inline
def line_notch(notch: int) -> int:
    """SPEC §1 fig. 3: notch -> wires a, b, c (the encoder) -> notch (the ECU's decoder)."""
    return decode_step_1(encode_step_1(notch))


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
