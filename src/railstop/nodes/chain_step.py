"""The line's SPEC §2 position step of every train, compiled into one loop.

Each step of the line, every train's odometer counts the distance it ran, its GNSS clock moves
on (free-running in a shadow without a repeater), the wayside's track-circuit devices detect the
fronts that entered a circuit, and the onboard positioning unit logs its cycle's sample. These
are the units' own compiled scalar cores (``sensors.odometer``, ``sensors.gnss_clock``,
``sensors.track_circuit``, ``onboard.positioning``), called here in one compiled loop over the
trains instead of one numpy call per unit and array (DESIGN rule 1: the same cores the units'
array methods run; the line's results are the same to the bit). What follows a detection (the
wayside stamps it, the telegram goes on the radio) and a telegram's arrival stay the
occupancy chain's (:meth:`OccupancyChain.detected`, :meth:`OccupancyChain.arrivals`): they
happen a few times a minute.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from railstop.jit import njit
from railstop.nodes.occupancy_chain import OccupancyChain
from railstop.onboard.positioning import PositioningUnit, unit_calibrated_m, unit_log_run
from railstop.sensors.gnss_clock import clock_error_1, in_sections_1
from railstop.sensors.odometer import Tachometer, creep_1, odometer_1, revolutions_1, tacho_speed_1
from railstop.sensors.track_circuit import detect_runs, events_of

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
BoolArray = NDArray[np.bool_]


# The compiled step's arguments, grouped per unit as plain tuples (numba types a plain tuple of
# arrays in its C dispatcher; NamedTuples cost the line's run 4 %, measured: about 2.4 µs more per
# step). The step unpacks each into named locals first.

#: The trains' motion over the step: (on_line, x0_m, x1_m, v0_mps, v1_mps, sliding, slipping):
#: fronts x0 -> x1 (-inf for a train not on the line), speeds v0 -> v1, the wheels sliding /
#: slipping (on-line trains only).
TrainMotion = tuple[BoolArray, FloatArray, FloatArray, FloatArray, FloatArray, BoolArray, BoolArray]
#: The tachometers (``sensors.odometer.Tachometer``) and the wheels' creep: (revolutions,
#: actual_diameter_m, assumed_diameter_m, pulses_per_rev, slide_slip_ratio, traction_slip_ratio).
Tachometers = tuple[FloatArray, FloatArray, FloatArray, int, float, float]
#: The onboard GNSS clocks ((n, 1) arrays, ``sensors.gnss_clock.GnssClock``), whether the line has
#: GNSS and its shadows without a repeater: (error_s, residual_s, drift, disciplined, gnss, shadows).
Clocks = tuple[FloatArray, FloatArray, FloatArray, BoolArray, bool, FloatArray]
#: The wayside's track-circuit devices (``sensors.track_circuit.TrackCircuitDetector``):
#: (boundary_m, delay_s, next_index).
Devices = tuple[FloatArray, FloatArray, IntArray]
#: The positioning units (``onboard.positioning.PositioningUnit``) and the accelerometers (beyond
#: SPEC §2, the bias drawn per train): (state, istate, log, accel_bias_mps2, accelerometer).
Units = tuple[FloatArray, IntArray, FloatArray, FloatArray, bool]


@njit
def chain_step_runs(
    t0_s: float,
    dt_s: float,
    now_s: float,
    motion: TrainMotion,
    tacho: Tachometers,
    clocks: Clocks,
    devices: Devices,
    units: Units,
    out: FloatArray,
    wsp_active: BoolArray,
) -> tuple[IntArray, IntArray, FloatArray, FloatArray, IntArray]:
    """One step from ``t0_s`` (``dt_s`` long, ending at the line's ``now_s``) of every train
    (``motion``). Updates the tachometers' revolutions, the onboard clocks, the detectors'
    ``next_index`` and the positioning units in place; fills ``out`` (6, n): the distance each
    ran, the uniform acceleration that carries it from x0 at v0 to x1 (the devices see the
    front cross where it is), its odometer, its tachometer speed, its accelerometer's reading
    (NaN: none) and its calibrated position before any fix of this step; ``wsp_active``.
    Returns the detections (``sensors.track_circuit.detect_runs``)."""
    on_line, x0_m, x1_m, v0_mps, v1_mps, sliding, slipping = motion
    (
        revolutions,
        actual_diameter_m,
        assumed_diameter_m,
        pulses_per_rev,
        slide_slip_ratio,
        traction_slip_ratio,
    ) = tacho
    clock_error_s, clock_residual_s, clock_drift, clock_disciplined, gnss, shadows = clocks
    boundary_m, delay_s, next_index = devices
    unit_state, unit_istate, unit_log, accel_bias_mps2, accelerometer = units
    n = x0_m.size
    moved_m, accel_mps2, odometer_m, speed_mps, log_accel, calibrated_m = (
        out[0],
        out[1],
        out[2],
        out[3],
        out[4],
        out[5],
    )
    for i in range(n):
        on = on_line[i]
        sl = on and sliding[i]
        sp = on and slipping[i]
        creep = creep_1(sl, sp, slide_slip_ratio, traction_slip_ratio)
        moved = x1_m[i] - x0_m[i] if on else 0.0
        moved_m[i] = moved
        revolutions[i] = revolutions_1(revolutions[i], moved, creep, actual_diameter_m[i])
        accel_mps2[i] = 2.0 * (moved - v0_mps[i] * dt_s) / (dt_s * dt_s) if on else 0.0
        odometer_m[i] = odometer_1(revolutions[i], pulses_per_rev, assumed_diameter_m[i])
        speed_mps[i] = tacho_speed_1(v1_mps[i], creep, assumed_diameter_m[i], actual_diameter_m[i])
        wsp_active[i] = sl or sp
        # Beyond SPEC §2: the accelerometer that bridges a slide (its bias drawn per train).
        log_accel[i] = (v1_mps[i] - v0_mps[i]) / dt_s + accel_bias_mps2[i] if accelerometer else math.nan
        # SPEC §2 clocks: disciplined unless in a GNSS shadow without a repeater.
        disc = gnss and not in_sections_1(x1_m[i], shadows)
        clock_error_s[i, 0] = clock_error_1(
            clock_error_s[i, 0], clock_residual_s[i, 0], clock_drift[i, 0], disc, dt_s
        )
        clock_disciplined[i, 0] = disc
    # SPEC §2 S10: circuits entered; the device declares them after its delay.
    events = detect_runs(boundary_m, delay_s, next_index, x0_m, v0_mps, accel_mps2, x1_m, t0_s)
    for i in range(n):
        unit_log_run(
            unit_state[i],
            unit_istate[i],
            unit_log[i],
            now_s + clock_error_s[i, 0],
            odometer_m[i],
            speed_mps[i],
            wsp_active[i],
            log_accel[i],
        )
        calibrated_m[i] = unit_calibrated_m(unit_state[i])
    return events


@dataclass(frozen=True, slots=True)
class ChainStep:
    """What one step gave (views of buffers the next step overwrites)."""

    moved_m: FloatArray
    accel_mps2: FloatArray
    odometer_m: FloatArray
    speed_mps: FloatArray
    log_accel_mps2: FloatArray  # NaN: no accelerometer
    calibrated_m: FloatArray  # before any fix of the step
    wsp_active: BoolArray


class CompiledChainStep:
    """The position step of one chain, its unit and the trains' tachometers (one per line run)."""

    def __init__(
        self,
        chain: OccupancyChain,
        unit: PositioningUnit,
        tacho: Tachometer,
        *,
        slide_slip_ratio: float,
        traction_slip_ratio: float,
        accel_bias_mps2: FloatArray | None,
    ) -> None:
        n = chain.n
        self.chain, self.unit, self.tacho = chain, unit, tacho
        self.slide_slip_ratio = float(slide_slip_ratio)
        self.traction_slip_ratio = float(traction_slip_ratio)
        self.accelerometer = accel_bias_mps2 is not None
        self.accel_bias = np.ascontiguousarray(
            np.zeros(n) if accel_bias_mps2 is None else accel_bias_mps2, dtype=np.float64
        )
        self._out = np.empty((6, n))
        self._wsp = np.empty(n, dtype=np.bool_)
        o = self._out
        self._result = ChainStep(o[0], o[1], o[2], o[3], o[4], o[5], self._wsp)

    def step(
        self,
        *,
        now_s: float,
        dt_s: float,
        on_line: BoolArray,
        x0_m: FloatArray,
        x1_m: FloatArray,
        v0_mps: FloatArray,
        v1_mps: FloatArray,
        sliding: BoolArray,
        slipping: BoolArray,
    ) -> ChainStep:
        """The step ending at ``now_s``; the wayside then takes what the devices detected."""
        chain, unit, tacho = self.chain, self.unit, self.tacho
        clock, det = chain.onboard_clock, chain.detector
        t0 = now_s - dt_s
        run, idx, entry, occupied, pas = chain_step_runs(
            t0,
            dt_s,
            now_s,
            (on_line, x0_m, x1_m, v0_mps, v1_mps, sliding, slipping),
            (
                tacho.revolutions,
                tacho.actual_diameter_m,
                tacho.assumed_diameter_m,
                tacho.pulses_per_rev,
                self.slide_slip_ratio,
                self.traction_slip_ratio,
            ),
            (
                clock.error_s,
                clock.residual_s,
                clock.drift,
                clock.disciplined,
                chain.cfg.gnss,
                chain.shadow_array,
            ),
            (det.boundary_m, det.delay_s, det.next_index),
            (unit.state, unit.istate, unit.log_ring, self.accel_bias, self.accelerometer),
            self._out,
            self._wsp,
        )
        chain.detected(events_of(run, idx, entry, occupied, pas), t0_s=t0, dt_s=dt_s)
        return self._result
