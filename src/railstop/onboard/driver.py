"""The human driver of a manually driven train (SPEC §3), a compiled scalar core of the stop kernel.

SPEC §3 says only that manual stopping depends on the driver's skill; the
model below is railstop's, its values are data (``railstop/data/driver.toml``,
with the sources they lean on), and every run draws its own driver:

* **skill**: a level (novice / experienced / expert by default) drawn with
  the levels' shares, then each parameter from that level's distribution;
* **looks**: the driver looks at speed, distance and marks every
  ``look_interval_s`` (openBVE's AI driver looks every 0.2-1.2 s). A look
  reads the speed with a scatter (``speed_read_sd_kmh``) and judges the
  distances left with the run's bias and a look-to-look scatter, both a
  share of the distance (Weber's law), plus a small floor near the mark;
* **reaction**: what a look decides acts ``reaction_s`` later (perception to
  handle). The driver knows his own delay and judges from where the train
  will be then;
* **braking-point judgement**: before braking the train holds its speed
  (traction); braking starts when the deceleration needed to stop at the
  mark (or to pass the next speed-code point ``code_margin_kmh`` below its
  code) reaches ``brake_start_fraction`` of ``planned_decel_mps2``;
* **notch handling**: each look picks the notch whose nominal deceleration,
  scaled by the brake effectiveness the driver has felt so far (learned from
  the deceleration he feels once a notch has acted for a second), best gives
  the deceleration needed, with a hysteresis of a fifth of a notch step;
  with little deceleration needed the driver coasts, and creeps (holds a low
  speed) when the train is slow and still short of the mark;
* **power**: a train too slow for the distance left (braked early, or
  below a code) is powered up again at a low notch (``[running]``), up to
  the lowest of the held code, the next code point's speed and the speed from
  which a light brake stops at the mark;
* **codes**: route knowledge gives the code points ahead (ATS oscillators,
  ATC circuits); the held limit / ADU indicated speed is a target at once:
  above it the driver brakes to be below it within about 1.5 s (SPEC §3:
  the driver must service-brake below the indicated speed within the 3 s
  grace);
* **re-stop**: at standstill the F / R lamp makes the driver move the train
  (after ``reaction_s``, reversing also ``reverse_setup_s``) by the distance
  he judges from the platform marks, at walking pace, or, far short (an
  emergency brake), at the held code (:func:`move_speed_1`).

An *incapacitated* driver (the supervision check of SPEC §3: "a driver who
is unconscious ...") never brakes: the train keeps its speed until the
supervision stops it.
"""

from __future__ import annotations

import math

import numpy as np

from railstop.config.driver import LV_CUMULATIVE, LV_PARAMS, LV_WIDTH
from railstop.jit import njit_inline, njit_step
from railstop.quantities import KMH_PER_MPS
from railstop.stream_cores import key_normal, key_uniform

# The run's driver (drawn once): the level's row, then its parameters in config.driver LEVEL_PARAMETERS order.
DR_LEVEL = 0
DR_REACTION = 1
DR_LOOK = 2
DR_BIAS = 3  # fraction
DR_NOISE = 4  # fraction
DR_SPEED_SD = 5  # m/s
DR_PLANNED = 6
DR_START = 7
DR_MARGIN = 8  # m/s
DR_SIZE = 9
_N_PARAMS = 8

# The driver's state.
DV_NEXT_LOOK = 0
DV_NOTCH = 1  # the handle
DV_BRAKING = 2  # braking has started
DV_HOLD = 3  # traction holds the speed
DV_GAIN = 4  # the brake effectiveness felt (decel felt / notch's nominal)
DV_NOTCH_T = 5  # when the handle last moved
DV_LOOKS = 6
DV_PENDING = 7  # the decided notch (-1: none) ...
DV_PENDING_T = 8  # ... and when the hand moves it
DV_PENDING_HOLD = 9
DV_REQUIRED = 10  # the deceleration the last look found needed
DV_ACTION = 11  # ACT_* of the last look
DV_POWER = 12  # the driver takes power (traction at RS_POWER_ACCEL)
DV_PENDING_POWER = 13
DV_SIZE = 14

# What the driver is doing (the approach plot's driver actions).
ACT_HOLD = 0  # traction holds the speed
ACT_COAST = 1
ACT_BRAKE = 2
ACT_CREEP_FORWARD = 3
ACT_REVERSE = 4
ACT_WAIT = 5  # at a stand: perceiving a lamp, setting up
ACT_DONE = 6
ACT_POWER = 7  # traction: the train is too slow for the distance left

# Re-stop parameters (config.driver driver_arrays).
RS_CREEP_SPEED = 0
RS_CREEP_ACCEL = 1
RS_CREEP_DECEL = 2
RS_JUDGEMENT_FRACTION = 3
RS_JUDGEMENT_FLOOR = 4
RS_REVERSE_SETUP = 5
RS_MAX = 6
RS_EB_RESET = 7
RS_POWER_ACCEL = 8  # config.driver Running
RS_POWER_BAND = 9  # m/s
RS_DRIVE_BEYOND = 10  # m: a longer forward correction is driven at the held code
RS_SIZE = 11

# Counters of the run's driver stream.
_C_LEVEL = 0
_C_PARAMS = 1  # .. _C_PARAMS + _N_PARAMS - 1
_C_LOOK = 64  # 3 draws per look
_C_RESTOP = 1 << 40  # 2 draws per correction

_SETTLE_S = 1.0  # a notch has acted this long before the driver judges its effect
_FIX_S = 1.5  # above the held limit: below it within this long
_GAIN_RATE = 0.3
_HYSTERESIS = 0.2  # of a notch step
_COAST_FRACTION = 0.15  # of the planned deceleration: less needed -> coast
_CREEP_BELOW_MPS = 2.0  # creep (hold) when slower than this and still short of the mark ...
_CREEP_SHORT_M = 3.0  # ... by more than this
_OVER_FRACTION = 1.0  # of the planned deceleration: the least brake over the indicated speed


@njit_inline
def driver_draw_1(dr: np.ndarray, levels: np.ndarray, key: np.uint64) -> None:
    """Draw the run's driver: the level by the shares, then each parameter (normal, clipped)."""
    u = key_uniform(key, _C_LEVEL)
    row = levels.shape[0] - 1
    for i in range(levels.shape[0]):
        if u < levels[i, LV_CUMULATIVE]:
            row = i
            break
    dr[DR_LEVEL] = row
    for j in range(_N_PARAMS):
        base = LV_PARAMS + LV_WIDTH * j
        mean = levels[row, base]
        sd = levels[row, base + 1]
        x = mean + sd * key_normal(key, _C_PARAMS + j) if sd > 0.0 else mean
        dr[1 + j] = min(max(x, levels[row, base + 2]), levels[row, base + 3])
    dr[DR_BIAS] *= 0.01
    dr[DR_NOISE] *= 0.01
    dr[DR_SPEED_SD] /= KMH_PER_MPS  # the data's km/h
    dr[DR_MARGIN] /= KMH_PER_MPS


@njit_inline
def driver_init_1(dv: np.ndarray) -> None:
    dv[DV_NEXT_LOOK] = 0.0
    dv[DV_NOTCH] = 0.0
    dv[DV_BRAKING] = 0.0
    dv[DV_HOLD] = 1.0
    dv[DV_GAIN] = 1.0
    dv[DV_NOTCH_T] = 0.0
    dv[DV_LOOKS] = 0.0
    dv[DV_PENDING] = -1.0
    dv[DV_PENDING_T] = np.inf
    dv[DV_PENDING_HOLD] = 1.0
    dv[DV_REQUIRED] = 0.0
    dv[DV_ACTION] = ACT_HOLD
    dv[DV_POWER] = 0.0
    dv[DV_PENDING_POWER] = 0.0


@njit_inline
def _needed_for_1(vp: float, target: float, distance: float) -> float:
    """Deceleration from ``vp`` to ``target`` in ``distance`` (0 if already slow enough)."""
    if vp <= target:
        return 0.0
    if distance <= 0.5:
        return (vp - target) / _FIX_S + 1.0  # at or past the point: as hard as it takes
    return (vp * vp - target * target) / (2.0 * distance)


@njit_inline
def _need_ahead_1(vp: float, felt: float, ahead: float, target: float, distance: float) -> float:
    """The deceleration to reach ``target`` at ``distance`` once a change acts ``ahead`` from now,
    the train decelerating at ``felt`` meanwhile. If the train would be slow enough before that,
    the deceleration that does it from now (a lower bound: ease off at once)."""
    v_then = vp - felt * ahead
    if v_then > target + 0.1:
        return _needed_for_1(v_then, target, distance - (vp * ahead - 0.5 * felt * ahead * ahead))
    return _needed_for_1(vp, target, distance)


@njit_step
def driver_look_1(
    dv: np.ndarray,
    dr: np.ndarray,
    table: np.ndarray,
    key: np.uint64,
    t: float,
    x: float,
    v: float,
    accel: float,
    stop_point: float,
    code_pos: np.ndarray,
    code_lim: np.ndarray,
    limit_now: float,
    incapacitated: bool,
    response_s: float,
    rs: np.ndarray,
) -> None:
    """A look at ``t`` (when due): decide the handle, to act ``reaction_s`` later.
    ``response_s``: the brake's response the driver knows (dead time + build-up); ``rs``: the
    re-stop and running parameters (RS_*: the judgement's floor, creep speed, power)."""
    if t < dv[DV_NEXT_LOOK] - 1e-9:
        return
    dv[DV_NEXT_LOOK] = t + dr[DR_LOOK]
    if incapacitated:
        dv[DV_ACTION] = ACT_HOLD
        return
    c = _C_LOOK + 3 * int(dv[DV_LOOKS])
    dv[DV_LOOKS] += 1.0
    vp = max(v + dr[DR_SPEED_SD] * key_normal(key, c), 0.0)
    scale = 1.0 + dr[DR_BIAS] + dr[DR_NOISE] * key_normal(key, c + 1)
    # Every target is judged from where the train will be when a new notch acts (the hand after
    # reaction_s, the brake after its response), at the deceleration felt now.
    felt = max(-accel, 0.0)
    ahead = dr[DR_REACTION] + response_s
    d_stop = (stop_point - x) * scale + rs[RS_JUDGEMENT_FLOOR] * key_normal(key, c + 2)
    need = _need_ahead_1(vp, felt, ahead, 0.0, d_stop)
    # The speed codes: the held one at once, the points ahead by route knowledge.
    margin = dr[DR_MARGIN]
    held = max(limit_now - margin, 0.5)
    if vp > held:
        need = max(need, (vp - held) / _FIX_S)
    if v > limit_now:
        # Over the limit / indicated speed on his speedometer (the ADU shows it; under ATC the
        # alarm follows the grace): a firm brake, at least the planned deceleration, not a coast.
        need = max(need, _OVER_FRACTION * dr[DR_PLANNED])
    for i in range(code_pos.size):
        if code_pos[i] > x:
            target = max(code_lim[i] - margin, 0.5)
            need = max(need, _need_ahead_1(vp, felt, ahead, target, (code_pos[i] - x) * scale))
    dv[DV_REQUIRED] = need
    planned = dr[DR_PLANNED]
    n_notches = table.size - 1
    notch = int(dv[DV_NOTCH])
    if dv[DV_BRAKING] == 0.0:
        if need < dr[DR_START] * planned:
            dv[DV_ACTION] = ACT_HOLD
            return
        dv[DV_BRAKING] = 1.0
    # Learn the brake's effectiveness from the deceleration felt (a settled notch, still moving).
    if notch > 0 and t - dv[DV_NOTCH_T] >= _SETTLE_S and v > 1.0:
        ratio = -accel / table[notch]
        dv[DV_GAIN] += _GAIN_RATE * (min(max(ratio, 0.5), 1.5) - dv[DV_GAIN])
    hold = False
    power = False
    if need < _COAST_FRACTION * planned:
        choice = 0
        # [interpretation] (config.driver Running) Too slow for the distance left: power up to the
        # aim, the lowest of the held code, each code point's speed ahead, and the speed from which
        # the coasting share of the planned deceleration stops the train at the mark.
        light = _COAST_FRACTION * planned
        short = (stop_point - x) * scale
        aim = min(held, math.sqrt(2.0 * light * max(short, 0.0)))
        for i in range(code_pos.size):
            if code_pos[i] > x:
                target = max(code_lim[i] - margin, 0.5)
                aim = min(aim, math.sqrt(target * target + 2.0 * light * (code_pos[i] - x) * scale))
        if short > _CREEP_SHORT_M:
            aim = max(aim, min(rs[RS_CREEP_SPEED], held))  # at least walking pace to the mark
        # Power is taken below aim - band and kept up to aim - band / 4 (a hysteresis against
        # the scatter of his speed readings; the band at most a quarter of the aim); he judges
        # the speed power will have given by the time his hand has moved after his next look.
        band = min(rs[RS_POWER_BAND], 0.25 * aim)
        powering = dv[DV_PENDING_POWER] > 0.0 if dv[DV_PENDING] >= 0.0 else dv[DV_POWER] > 0.0
        gain_ahead = min(rs[RS_POWER_ACCEL] * (dr[DR_REACTION] + dr[DR_LOOK]), 0.5 * aim)
        if vp + gain_ahead < aim - (0.25 if powering else 1.0) * band:
            power = True
            dv[DV_ACTION] = ACT_POWER
        else:
            hold = vp < _CREEP_BELOW_MPS and short > _CREEP_SHORT_M
            dv[DV_ACTION] = ACT_HOLD if hold else ACT_COAST
    else:
        want = need / dv[DV_GAIN]
        choice = 0
        best = abs(want)
        for n in range(1, n_notches + 1):
            if abs(table[n] - want) < best:
                best = abs(table[n] - want)
                choice = n
        step = table[n_notches] / n_notches
        if choice != notch and best > abs(table[notch] - want) - _HYSTERESIS * step:
            choice = notch  # not worth a move
        dv[DV_ACTION] = ACT_BRAKE if choice > 0 else ACT_COAST
    if choice != notch or hold != (dv[DV_HOLD] > 0.0) or power != (dv[DV_POWER] > 0.0):
        # A decision already on its way keeps its time (the hand is moving); this look updates it.
        if dv[DV_PENDING] < 0.0:
            dv[DV_PENDING_T] = t + dr[DR_REACTION]
        dv[DV_PENDING] = choice
        dv[DV_PENDING_HOLD] = 1.0 if hold else 0.0
        dv[DV_PENDING_POWER] = 1.0 if power else 0.0
    else:
        dv[DV_PENDING] = -1.0
        dv[DV_PENDING_T] = np.inf


@njit_inline
def driver_output_1(dv: np.ndarray, t: float) -> tuple[int, bool, bool]:
    """The handle at ``t`` (a decision acts once its reaction time has passed): (notch, hold,
    power)."""
    if dv[DV_PENDING] >= 0.0 and t >= dv[DV_PENDING_T] - 1e-9:
        dv[DV_NOTCH] = dv[DV_PENDING]
        dv[DV_HOLD] = dv[DV_PENDING_HOLD]
        dv[DV_POWER] = dv[DV_PENDING_POWER]
        dv[DV_NOTCH_T] = t
        dv[DV_PENDING] = -1.0
        dv[DV_PENDING_T] = np.inf
    return int(dv[DV_NOTCH]), dv[DV_HOLD] > 0.0, dv[DV_POWER] > 0.0


@njit_inline
def move_speed_1(rs: np.ndarray, distance: float, forward: bool, held: float) -> float:
    """The top speed of a correction of ``distance`` (> 0): walking pace, but a forward move longer
    than RS_DRIVE_BEYOND (a train stopped far short, e.g. by an emergency brake) is driven at
    ``held``, the code held less the driver's margin (config.driver Restop)."""
    if forward and distance > rs[RS_DRIVE_BEYOND]:
        return max(rs[RS_CREEP_SPEED], held)
    return rs[RS_CREEP_SPEED]


@njit_inline
def _creep_peak_1(distance: float, rs: np.ndarray, top: float) -> float:
    """The peak speed of a move of ``distance``: ``top``, or less if the move is too short."""
    accel, decel = rs[RS_CREEP_ACCEL], rs[RS_CREEP_DECEL]
    if distance >= top * top * (0.5 / accel + 0.5 / decel):
        return top
    return math.sqrt(2.0 * distance / (1.0 / accel + 1.0 / decel))


@njit_inline
def creep_time_1(distance: float, rs: np.ndarray, top: float) -> float:
    """Time of a move of ``distance`` (> 0) at up to ``top`` (:func:`move_speed_1`; the re-stop
    parameters ``rs``): accelerate, run, brake (a trapezoid, or a triangle when the move is too
    short to reach ``top``)."""
    accel, decel = rs[RS_CREEP_ACCEL], rs[RS_CREEP_DECEL]
    peak = _creep_peak_1(distance, rs, top)
    ramps = 0.5 * peak * peak * (1.0 / accel + 1.0 / decel)
    return peak / accel + peak / decel + (distance - ramps) / peak


@njit_inline
def creep_position_1(distance: float, rs: np.ndarray, tau: float, top: float) -> float:
    """How far a move of ``distance`` has gone ``tau`` after it started (same profile as creep_time_1)."""
    total = creep_time_1(distance, rs, top)
    if tau >= total:
        return distance
    accel, decel = rs[RS_CREEP_ACCEL], rs[RS_CREEP_DECEL]
    peak = _creep_peak_1(distance, rs, top)
    t_up = peak / accel
    t_down = peak / decel
    if tau <= t_up:
        return 0.5 * accel * tau * tau
    if tau <= total - t_down:
        return 0.5 * peak * t_up + peak * (tau - t_up)
    rest = total - tau
    return distance - 0.5 * decel * rest * rest


@njit_inline
def restop_judgement_1(rs: np.ndarray, key: np.uint64, correction: int, distance: float) -> float:
    """The distance the driver moves for a true ``distance`` to the mark (signed), judged from the
    platform marks: off by a share of it and a floor (SPEC §3 F / R lamps; config.driver)."""
    c = _C_RESTOP + 2 * correction
    return distance * (1.0 + rs[RS_JUDGEMENT_FRACTION] * key_normal(key, c)) + rs[
        RS_JUDGEMENT_FLOOR
    ] * key_normal(key, c + 1)
