"""The ground TASC control law of SPEC §1, compiled, one run at a time.

The wayside controller computes "the braking deceleration required to stop at
the stopping point" from the distance to go, allowing for the time until a new
command acts (radio latency, brake dead time, build-up lag, jerk-limited
ramp), and closes the loop by comparing the deceleration it measures with the
deceleration it commanded (SPEC §1, claims 2 and 19). The comparison gives a
loop gain g = measured / expected; the next command is required / g. This
cancels whatever makes the brakes act differently from nominal: load, brake
effectiveness, a wrong load-weighing signal. Gradient and running resistance
are not brake errors: the wayside's database holds the track gradient and
the vehicle's Davis coefficients, so they are modelled as an external
deceleration along the remaining path and kept out of the gain.
**[interpretation]** The patent says only that measured and required
deceleration are compared; the multiplicative gain, the equivalent-dead-time
model of the brake response and the piecewise command history below are
railstop's reading of it. The errors the loop cancels are constant over one
stop, so the gain is their least-squares estimate over every measurement
window of the stop, not the last window alone: a brake controller that
alternates two notches makes one window's deceleration ripple by several
per cent, which a single-window gain would pass straight into the command.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from railstop.config.schema import Vehicle
from railstop.control.supervision import guard_limit_1
from railstop.jit import njit_inline, njit_step
from railstop.physics.train import G_MPS2, mean_gradient_1

FloatArray = NDArray[np.float64]


class BrakeCurves(NamedTuple):
    """The train's nominal braking as the plan uses it (the wayside's database, the onboard
    unit's memory): the deceleration of each notch (0 first) and the PWM curve."""

    table: FloatArray  # deceleration per notch (m/s²)
    pwm_duty: FloatArray  # the PWM curve: duty ...
    pwm_decel: FloatArray  # ... and its deceleration (m/s²)


class Approach(NamedTuple):
    """The line data of the approach as the plan uses it: the detectors' distances to the stopping
    point, the external forces' parameters (EXT_*) and the gradient ``grad`` (breakpoints, values
    in permille, elevation at the breakpoints)."""

    det_to_stop: FloatArray
    ext: FloatArray
    grad: tuple[FloatArray, FloatArray, FloatArray]


GAIN_MIN = 0.5
GAIN_MAX = 2.0
HISTORY = 8
MIN_WINDOW_CMD = 0.05  # m/s²: a window whose modelled command is smaller does not count in the gain
SAMPLES = 24  # points per window for model-weighted means
# Stop model 17, the start of braking [interpretation] (SPEC §1 does not say at which detector
# braking starts; it computes "the braking deceleration required" at each): a train that has not
# been told to brake holds its speed, and the first braking command waits for a later detector
# while the stop needs less than START_FLOOR of full service and holding the speed to the next
# detector (and the command's response there) would need no more than START_LIMIT of it. A stop
# begun on a small demand ends on a small deceleration wherever the path's own deceleration falls
# away (a steep uphill approach, a level platform): there a centimetre of energy error is
# decimetres of stop, the brakes can only add, and a notch train's smallest notch is already more
# than the demand (issue 36). The floor is 0 (braking starts at the first command, as before model
# 17) where the wayside models the train's own commands, forms 1-5 without a Doppler radar
# (start_floor_mps2): a hold on one side and a brake on the other, near the floor, would leave
# the wayside's speed at a passage resting on braking the train never made.
START_FLOOR = 0.2
START_LIMIT = 0.5


def start_floor_mps2(full_service_mps2: float, form: int, has_doppler: bool) -> float:
    """The command under which the first braking waits for the next detector (``START_FLOOR``
    of full service; 0, no wait, for forms 1-5 without a Doppler radar)."""
    return START_FLOOR * full_service_mps2 if form >= 6 or has_doppler else 0.0


# --------------------------------------------------------------------------
# Compiled scalar cores (railstop.jit): the one implementation of the law.
#
# One run at a time. The external model is a small parameter vector (EXT_*)
# plus the run's gradient ``grad`` = (breakpoints, values permille, elevation
# at breakpoints); the command history is two arrays of HISTORY entries,
# values and effect times (+inf where empty, entries in time order). The
# modelled brake deceleration at time t is ``gain × value`` of the newest
# command whose effect time is <= t (0 before the first one).

EXT_STOP = 0  # stopping point chainage (m)
EXT_LENGTH = 1  # train length (m)
EXT_MASS_RATIO = 2  # static / effective mass at nominal load
EXT_DAVIS_A = 3  # m/s²
EXT_DAVIS_B = 4  # 1/s
EXT_DAVIS_C = 5  # 1/m
EXT_SIZE = 6

_FRAC_TRAPZ = np.linspace(0.0, 1.0, SAMPLES)  # path samples of the gradient integral
_FRAC_MID = (np.arange(SAMPLES) + 0.5) / SAMPLES  # window samples of the model-weighted means
REG_WEIGHTS = _FRAC_MID * (1.0 - _FRAC_MID)
REG_WEIGHTS = REG_WEIGHTS / REG_WEIGHTS.sum()


def external_params(vehicle: Vehicle, stop_point_m: float) -> FloatArray:
    """The EXT_* vector of the external model: deceleration from gradient and running
    resistance, as the database knows it.

    SPEC §1 database unit: stopping point, detector positions, braking data.
    The wayside (and the onboard unit for forms 1-5) predicts with the track
    gradient under the train and nominal Davis resistance at half load.
    """
    static = vehicle.tare_mass_kg + 0.5 * vehicle.crush_payload_kg
    eff = static + vehicle.tare_mass_kg * vehicle.rotating_mass_factor
    out = np.zeros(EXT_SIZE)
    out[EXT_STOP] = stop_point_m
    out[EXT_LENGTH] = vehicle.length_m
    out[EXT_MASS_RATIO] = static / eff
    out[EXT_DAVIS_A] = vehicle.davis_a_n / eff
    out[EXT_DAVIS_B] = vehicle.davis_b_n_per_mps / eff
    out[EXT_DAVIS_C] = vehicle.davis_c_n_per_mps2 / eff
    return out


@njit_step
def clip_1(x: float, lo: float, hi: float) -> float:
    """``np.clip`` of one number (NaN stays NaN)."""
    if x != x:
        return x
    return min(max(x, lo), hi)


@njit_step
def propagate_1(distance_m: float, speed_mps: float, decel_mps2: float, dt_s: float) -> tuple[float, float]:
    """Distance to go and speed after ``dt_s`` at constant deceleration (stops at zero speed)."""
    dt = max(dt_s, 0.0)
    v_end = speed_mps - decel_mps2 * dt
    if decel_mps2 > 0.0 and v_end <= 0.0:
        return distance_m - speed_mps * speed_mps / (2.0 * decel_mps2), 0.0
    return distance_m - (speed_mps * dt - 0.5 * decel_mps2 * dt * dt), v_end


@njit_step
def required_decel_1(distance_m: float, speed_mps: float) -> float:
    """SPEC §1: deceleration that stops from ``speed`` in exactly ``distance``: v² / 2s.

    A train already at or past the stopping point gets +inf (brake as hard as
    allowed); a stopped train needs nothing.
    """
    if speed_mps <= 0.0:
        return 0.0
    if distance_m > 0.0:
        return speed_mps * speed_mps / (2.0 * distance_m)
    return np.inf


@njit_step
def external_decel_1(
    ext: FloatArray, grad: tuple[FloatArray, FloatArray, FloatArray], distance_m: float, speed_mps: float
) -> float:
    """External deceleration now (+ = helps braking: uphill, resistance), as the database knows it."""
    x = ext[EXT_STOP] - distance_m
    grade = G_MPS2 * ext[EXT_MASS_RATIO] * mean_gradient_1(x, ext[EXT_LENGTH], grad[0], grad[1], grad[2])
    v = max(speed_mps, 0.0)
    return grade + ext[EXT_DAVIS_A] + ext[EXT_DAVIS_B] * v + ext[EXT_DAVIS_C] * v * v


@njit_step
def guard_limit_on_path_1(
    limit_mps2: float,
    emergency_mps2: float,
    gain: float,
    ext: FloatArray,
    grad: tuple[FloatArray, FloatArray, FloatArray],
    distance_m: float,
    end_margin_m: float,
) -> float:
    """The overrun guard's limit on the path left (stop model 18,
    :func:`~railstop.control.supervision.guard_limit_1`): with the lesser of what gradient and
    resistance (at rest) give at the platform end, ``end_margin_m`` beyond the stopping point, and
    with the train ``distance_m`` before it (NaN: not known, the end alone). The wayside and the
    onboard unit both set their guard's limit by this."""
    ext_min = external_decel_1(ext, grad, -end_margin_m, 0.0)
    if math.isfinite(distance_m):
        ext_min = min(ext_min, external_decel_1(ext, grad, distance_m, 0.0))
    return guard_limit_1(limit_mps2, emergency_mps2, gain, ext_min)


@njit_step
def external_path_integral_1(
    ext: FloatArray, grad: tuple[FloatArray, FloatArray, FloatArray], distance_m: float, speed_mps: float
) -> float:
    """Integral of the external deceleration over the remaining distance (m²/s²).

    Gradient: trapezoid over SAMPLES points of the path. Resistance: for a
    uniform stop from v over s, v² falls linearly with distance, so the mean
    of v over distance is 2v/3 and of v² is v²/2.
    """
    s = max(distance_m, 0.0)
    stop = ext[EXT_STOP]
    length = ext[EXT_LENGTH]
    prev = mean_gradient_1(stop - s * (1.0 - _FRAC_TRAPZ[0]), length, grad[0], grad[1], grad[2])
    total = 0.0
    for j in range(1, SAMPLES):
        g = mean_gradient_1(stop - s * (1.0 - _FRAC_TRAPZ[j]), length, grad[0], grad[1], grad[2])
        total += (_FRAC_TRAPZ[j] - _FRAC_TRAPZ[j - 1]) * (g + prev) / 2.0
        prev = g
    v = max(speed_mps, 0.0)
    resist = ext[EXT_DAVIS_A] + ext[EXT_DAVIS_B] * 2.0 * v / 3.0 + ext[EXT_DAVIS_C] * v * v / 2.0
    return s * (G_MPS2 * ext[EXT_MASS_RATIO] * total + resist)


@njit_step
def brake_need_1(
    ext: FloatArray, grad: tuple[FloatArray, FloatArray, FloatArray], distance_m: float, speed_mps: float
) -> float:
    """SPEC §1: the deceleration the brake must give to stop from ``speed`` in ``distance``: v² / 2s
    less what gradient and resistance give over the path (+inf at or past the stopping point)."""
    need = required_decel_1(distance_m, speed_mps)
    if distance_m > 0.0:
        need -= external_path_integral_1(ext, grad, distance_m, speed_mps) / distance_m
    return need


@njit_step
def history_push_1(values: FloatArray, effects: FloatArray, value_mps2: float, effect_s: float) -> None:
    """Append one command (the oldest drops out when the history is full)."""
    count = 0
    for j in range(HISTORY):
        if math.isfinite(effects[j]):
            count += 1
    if count >= HISTORY:
        for j in range(HISTORY - 1):
            values[j] = values[j + 1]
            effects[j] = effects[j + 1]
    slot = min(count, HISTORY - 1)
    values[slot] = value_mps2
    effects[slot] = effect_s


@njit_step
def history_value_at_1(values: FloatArray, effects: FloatArray, t_s: float) -> float:
    """Commanded value in effect at ``t_s`` (0 before the first command takes effect)."""
    count = 0
    for j in range(HISTORY):
        if effects[j] <= t_s:
            count += 1
    return values[count - 1] if count > 0 else 0.0


@njit_step
def history_response_at_1(values: FloatArray, effects: FloatArray, t_s: float, lag_s: float) -> float:
    """Modelled brake response at ``t_s``: each change of command relaxes with the first-order
    lag, started ``lag_s`` before its effect time (its mean delay is then the equivalent dead time
    the planner uses). Without it a measurement window holding a command change compares the
    measured deceleration with a step the brakes never made."""
    total = 0.0
    prev = 0.0
    tau = max(lag_s, 1e-6)
    for j in range(HISTORY):
        if not math.isfinite(effects[j]):
            break
        since = t_s - (effects[j] - lag_s)
        total += (values[j] - prev) * (1.0 - math.exp(-max(since, 0.0) / tau))
        prev = values[j]
    return total


@njit_step
def history_predict_1(
    values: FloatArray,
    effects: FloatArray,
    distance_m: float,
    speed_mps: float,
    now_s: float,
    until_s: float,
    gain: float,
    external_mps2: float,
) -> tuple[float, float]:
    """Distance to go and speed at ``until_s`` if the train follows the commands sent."""
    s = distance_m
    v = speed_mps
    start = now_s
    value = 0.0
    for j in range(HISTORY):
        edge = min(max(effects[j], now_s), until_s)
        s, v = propagate_1(s, v, gain * value + external_mps2, max(edge - start, 0.0))
        start = edge
        value = values[j]
    s, v = propagate_1(s, v, gain * value + external_mps2, max(until_s - start, 0.0))
    return s, v


@njit_step
def regression_taus_1(t0_s: float, t1_s: float, taus: FloatArray) -> None:
    """Sample times of a least-squares slope over [t0, t1]; its weights are ``REG_WEIGHTS``.

    The slope of a least-squares line through speed samples is the mean of
    the deceleration weighted by (τ - t0)(t1 - τ): comparing it with the same
    weighted mean of the modelled deceleration makes the gain unbiased while
    the deceleration changes inside the window.
    """
    for i in range(SAMPLES):
        taus[i] = t0_s + (t1_s - t0_s) * _FRAC_MID[i]


@njit_step
def hat_weights_1(t0_s: float, t1_s: float, t2_s: float, taus: FloatArray, weights: FloatArray) -> None:
    """Sample times and weights of the hat function on [t0, t2] peaking at t1 (variant 2)."""
    rise_den = max(t1_s - t0_s, 1e-9)
    fall_den = max(t2_s - t1_s, 1e-9)
    total = 0.0
    for i in range(SAMPLES):
        tau = t0_s + (t2_s - t0_s) * _FRAC_MID[i]
        taus[i] = tau
        w = (tau - t0_s) / rise_den if tau <= t1_s else (t2_s - tau) / fall_den
        weights[i] = w
        total += w
    total = max(total, 1e-12)
    for i in range(SAMPLES):
        weights[i] = weights[i] / total


@njit_step
def modelled_means_1(
    values: FloatArray,
    effects: FloatArray,
    taus: FloatArray,
    weights: FloatArray,
    braking_from_s: float,
    lag_s: float,
    ext: FloatArray,
    grad: tuple[FloatArray, FloatArray, FloatArray],
    distance_m: float,
    speed_mps: float,
    decel_mps2: float,
    now_s: float,
) -> tuple[float, float]:
    """Weighted means over a measurement window of (commanded brake decel, external decel).

    The external part counts only while the train was braking (before that it
    held its speed with traction), taken where the train was at each sample
    time, traced back from now with the measured deceleration: over a 1.5 s
    window the train moves 20 m, and the mean gradient under it can change by
    a few per mille meanwhile.
    """
    a = decel_mps2 if math.isfinite(decel_mps2) else 0.0
    cmd = 0.0
    ext_mean = 0.0
    for i in range(SAMPLES):
        tau = taus[i]
        cmd += history_response_at_1(values, effects, tau, lag_s) * weights[i]
        if tau >= braking_from_s:
            back = now_s - tau
            v_then = speed_mps + a * back
            s_then = distance_m + speed_mps * back + 0.5 * a * back * back
            ext_mean += external_decel_1(ext, grad, s_then, v_then) * weights[i]
    return cmd, ext_mean


@njit_step
def plan_command_1(
    distance_m: float,
    speed_mps: float,
    now_s: float,
    values: FloatArray,
    effects: FloatArray,
    gain: float,
    base_delay_s: float,
    jerk_limit_mps3: float,
    max_decel_mps2: float,
    ext: FloatArray,
    grad: tuple[FloatArray, FloatArray, FloatArray],
    det_to_stop: FloatArray,
    start_floor_mps2: float,
) -> tuple[float, float, float]:
    """The command to send now: (commanded decel, required brake decel, effect time).

    The new command acts after ``base_delay_s`` (latency + dead time + lag
    time constant, the equivalent dead time of a first-order lag) plus half
    the jerk-limited ramp from the current level; until then the train
    follows the commands already sent. From that predicted state the brake
    must supply v²/2s (SPEC §1) less what gradient and resistance give over
    the remaining path; dividing by the loop gain turns it into the command.
    If the train is predicted to stop before a new command could act, the
    brake is held (never released to roll on: DESIGN rule 10). Before any
    braking, a small command waits for the next detector (``START_FLOOR``).
    """
    current = history_value_at_1(values, effects, now_s)
    ext_now = external_decel_1(ext, grad, distance_m, speed_mps)
    delay = base_delay_s
    need = 0.0
    v_t = speed_mps
    for _ in range(2):  # the ramp depends on the answer: one fixed-point refinement
        s_t, v_t = history_predict_1(
            values, effects, distance_m, speed_mps, now_s, now_s + delay, gain, ext_now
        )
        need = brake_need_1(ext, grad, s_t, v_t)
        ramp = abs(clip_1(need / gain, 0.0, max_decel_mps2) - current) / (2.0 * jerk_limit_mps3)
        delay = base_delay_s + ramp
    command = current if v_t <= 0.0 else clip_1(need / gain, 0.0, max_decel_mps2)
    if command > 0.0 and _start_later_1(
        values, effects, command, distance_m, speed_mps, gain, base_delay_s, max_decel_mps2, start_floor_mps2,
        det_to_stop, ext, grad,
    ):  # fmt: skip
        command = 0.0  # the train holds its speed to the next detector
    return command, need, now_s + delay


@njit_step
def _start_later_1(
    values: FloatArray,
    effects: FloatArray,
    command: float,
    distance_m: float,
    speed_mps: float,
    gain: float,
    base_delay_s: float,
    max_decel_mps2: float,
    start_floor_mps2: float,
    det_to_stop: FloatArray,
    ext: FloatArray,
    grad: tuple[FloatArray, FloatArray, FloatArray],
) -> bool:
    """Whether the first braking command waits for the next detector (``START_FLOOR``): no
    braking commanded yet, ``command`` under ``start_floor_mps2``, and at the next detector
    ahead, reached at the speed held and acted on ``base_delay_s`` later, a command within
    ``START_LIMIT``."""
    if command >= start_floor_mps2:
        return False
    for j in range(HISTORY):
        if math.isfinite(effects[j]) and values[j] > 0.0:
            return False  # braking has begun: the plan never releases to hold the speed again
    ahead = -1.0
    for d in det_to_stop:
        if d < distance_m - 1.0 and d > ahead:
            ahead = d
    if ahead <= 0.0:
        return False
    acts_m = ahead - speed_mps * base_delay_s
    if acts_m <= 0.0:
        return False
    return brake_need_1(ext, grad, acts_m, speed_mps) / gain <= START_LIMIT * max_decel_mps2


@njit_step
def gain_value_1(num: float, den: float) -> float:
    """Least-squares loop gain Σ c(m - e) / Σ c² (1.0 before any usable window)."""
    return clip_1(num / den, GAIN_MIN, GAIN_MAX) if den > 0.0 else 1.0


@njit_step
def gain_update_1(
    num: float, den: float, measured_decel_mps2: float, expected_brake_mps2: float, external_mps2: float
) -> tuple[float, float]:
    """SPEC §1 loop closure (claims 2, 19): add one measurement window to the gain's sums.

    The measured deceleration less the modelled gradient and resistance over the
    same window (``external_mps2``, see :func:`modelled_means_1`) is compared with
    the modelled command (``expected_brake_mps2``): each window gives one equation
    ``measured - external = g × commanded``. A window with too small a command
    (before braking) or no measurement does not count. The wayside unit and the
    onboard planner of forms 1-5 both close the loop with this, then plan with
    :func:`plan_command_1`.
    """
    if expected_brake_mps2 >= MIN_WINDOW_CMD and math.isfinite(measured_decel_mps2):
        num += expected_brake_mps2 * (measured_decel_mps2 - external_mps2)
        den += expected_brake_mps2 * expected_brake_mps2
    return num, den


@njit_inline
def _ring_at(i: int, size: int) -> int:
    """``i % size`` for ``-size <= i < size`` (a ring's index counted back from its newest), with
    no integer division: the fits below take it for every sample of a window."""
    return i + size if i < 0 else i


@njit_step
def line_fit_1(ring: FloatArray, newest: int, count: int, dt_s: float) -> tuple[float, float]:
    """Least-squares line through the newest ``count`` samples of a ring buffer: (value now, slope).

    ``ring[newest]`` is the newest sample, older ones precede it cyclically;
    sample of age a is at time -a·dt. Fewer than 2 samples: (newest, NaN).
    """
    if count < 2:
        return ring[newest], np.nan
    size = ring.size
    count = min(count, size)  # a ring holds no more (the callers' counts never exceed it)
    m = float(count)
    st = 0.0
    sv = 0.0
    for a in range(count):
        st += -a * dt_s
        sv += ring[_ring_at(newest - a, size)]
    t_mean = st / m
    v_mean = sv / m
    sxx = 0.0
    sxy = 0.0
    for a in range(count):
        d = -a * dt_s - t_mean
        sxx += d * d
        sxy += d * (ring[_ring_at(newest - a, size)] - v_mean)
    slope = sxy / sxx
    return v_mean - slope * t_mean, slope


@njit_step
def fit_ring_1(
    ring: FloatArray, newest: int, count: int, dt_s: float, speed_samples: int
) -> tuple[float, float]:
    """Speed now and deceleration from the newest ``count`` speed samples of a ring buffer.

    The deceleration is minus the slope of a line through all ``count``
    samples. The speed now is the mean of the newest ``speed_samples`` (the
    speed at their middle) carried forward to the newest sample's time with
    that long line's slope. A short window follows a deceleration that
    ripples (a brake alternating two notches): the end of the long line
    misses its last part by a few cm/s, which near the stop is several per
    cent of the speed. Within the short window the mean is the estimate of
    least variance: a line fitted through the short window alone extrapolates
    its own slope, and its value at the end has four times the variance of the
    mean (stop model 11; **[interpretation]** SPEC §1 measures the speed with
    the Doppler radar and leaves the estimator open).
    """
    v_now, slope = line_fit_1(ring, newest, count, dt_s)
    if speed_samples < ring.size and count >= 2:
        m = min(count, max(speed_samples, 2))
        size = ring.size
        sv = 0.0
        for a in range(m):
            sv += ring[_ring_at(newest - a, size)]
        v_now = sv / m + slope * (m - 1) * dt_s / 2.0
    return v_now, -slope


# The running line fit of speed over time since a command took effect (the measurement
# interval between commands): 5 sums at ``at`` in a unit's state vector.
FIT_SUMS = 5


@njit_inline
def interval_fit_reset_1(state: FloatArray, at: int) -> None:
    for j in range(FIT_SUMS):
        state[at + j] = 0.0


@njit_inline
def interval_fit_add_1(state: FloatArray, at: int, t_rel_s: float, speed_mps: float) -> None:
    """One speed sample ``t_rel_s`` after the interval's start (sums of 1, t, t², v, t·v)."""
    state[at] += 1.0
    state[at + 1] += t_rel_s
    state[at + 2] += t_rel_s * t_rel_s
    state[at + 3] += speed_mps
    state[at + 4] += t_rel_s * speed_mps


@njit_inline
def interval_fit_decel_1(state: FloatArray, at: int) -> tuple[int, float]:
    """(samples, deceleration) of the interval's line fit: the deceleration over the whole
    interval between commands (a brake controller alternating two notches matches its target
    only on average over its alternation); NaN with fewer than two samples."""
    c = state[at]
    if c < 2.0:
        return int(c), np.nan
    st = state[at + 1]
    sxx = state[at + 2] - st * st / c
    slope = (state[at + 4] - st * state[at + 3] / c) / sxx if sxx > 0.0 else 0.0
    return int(c), -slope


@njit_step
def fit_passages_1(t_s: FloatArray, x_m: FloatArray, count: int) -> tuple[float, float]:
    """SPEC §1 variant 2: speed at the newest passage and deceleration from passage times.

    With 3 passages a parabola through them is exact for constant
    deceleration; with 2 the mean speed over the interval (deceleration NaN).
    """
    if count < 2:
        return np.nan, np.nan
    v12 = (x_m[2] - x_m[1]) / (t_s[2] - t_s[1])
    if count < 3:
        return v12, np.nan
    v01 = (x_m[1] - x_m[0]) / (t_s[1] - t_s[0])
    accel = 2.0 * (v12 - v01) / (t_s[2] - t_s[0])
    return v12 + accel * (t_s[2] - t_s[1]) / 2.0, -accel
