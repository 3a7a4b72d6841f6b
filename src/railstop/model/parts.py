"""The station stop split by place, for drivers that run one stop across processes (live operation).

One step of the stop model (:func:`railstop.model.step.stop_step`) is, in
order: the wayside's reading and command (``doppler_reading_1``,
``wayside_command_1``), the link, the train's onboard unit
(``tasc_onboard_1``) and its ECU (``ecu_1``), the plant (``actuator_1``,
``move_1``, ``sensors_1``). Live operation runs the wayside in the stations
process, the onboard unit in the trains process and the plant in the plant
process, with UDP between them. Each process holds the records of the stop
(:class:`~railstop.model.run.StopRecords`, from the same draw) and steps its
own part of them through the compiled entries here, so every process runs the
stop model's own code (DESIGN rule 1); only the clock and the link differ.
Wired without delay in one process on the stop's clock, the three parts give
the campaign's run of the same draw bit for bit (``tests/live/test_live_tasc.py``).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from railstop.config.scenario import Scenario
from railstop.jit import njit_step
from railstop.model.build import KernelModel
from railstop.model.records import KP_DT, RunParams, StopOutputs, StopParams, StopState
from railstop.model.run import StopRecords, compiled_for
from railstop.model.step import (
    actuator_1,
    doppler_reading_1,
    ecu_1,
    external_eb_1,
    move_1,
    sensors_1,
    tach_speed_1,
    tasc_onboard_1,
    wayside_command_1,
)


@njit_step
def plant_part(
    p: StopParams, run: RunParams, s: StopState, out: StopOutputs, k: int, t: float, demand: float,
    braking: bool,
) -> tuple[bool, float, bool, int, float]:  # fmt: skip
    """Step ``k`` of the plant at ``t``: the station's sensors read the train as it is (the radar's
    sample, the detector passage found in the last step), then the actuator, the motion and the
    sensors under the onboard unit's ``demand`` (``braking``: traction lets go). Returns (stands,
    the reading: Doppler, passed, detector, passage time)."""
    se, tr = s.sense[0], s.train[0]
    doppler = doppler_reading_1(p, run, s, k)
    passed, det_idx, pass_s = se.passed, se.det_idx, se.pass_s
    se.transponder_m = np.nan  # the last step's passage went with its sensing
    x0, v0 = tr.position_m, tr.speed_mps
    brake_decel = actuator_1(p, run, s, k, demand)
    x, accel, sliding, stopped = move_1(p, run, s, t, x0, v0, brake_decel, not braking)
    sensors_1(p, run, s, out, t, x0, v0, x, accel, sliding)
    return stopped, doppler, passed, det_idx, pass_s


@njit_step
def plant_sense(run: RunParams, s: StopState) -> tuple[float, float, float, bool, bool]:
    """What the train's own sensors tell its onboard unit before the next step: (the tachometer's
    speed, the odometer's last step, a transponder passed in it (NaN: none), standing, the
    wheel-slide protection acting)."""
    tr = s.train[0]
    return tach_speed_1(run, s), tr.odometer_step_m, s.sense[0].transponder_m, tr.stopped, tr.sliding


@njit_step
def onboard_part(
    p: StopParams, run: RunParams, s: StopState, k: int, t: float, tach_v: float, odometer_step_m: float,
    transponder_m: float, stopped: bool, wsp: bool, new: bool, copy: bool,
) -> tuple[float, bool, bool]:  # fmt: skip
    """Step ``k`` of the train's onboard unit at ``t`` on its sensing (``plant_sense``) and the
    telegram (``new``: a new one in ``s.pending``; ``copy``: a copy of the one it has): (the ECU's
    brake demand, braking, emergency brake) for the plant."""
    tr, se = s.train[0], s.sense[0]
    tr.odometer_step_m = odometer_step_m
    tr.stopped = stopped
    tr.sliding = wsp
    se.transponder_m = transponder_m
    notch, duty, braking, eb = tasc_onboard_1(p, run, s, k, t, tach_v, new, copy)
    if external_eb_1(s, t):
        eb = braking = True
    demand, _ = ecu_1(p, s, notch, duty, eb)
    return demand, braking, eb


@njit_step
def wayside_part(
    p: StopParams, run: RunParams, s: StopState, out: StopOutputs, k: int, t: float, doppler: float,
    passed: bool, det_idx: int, pass_s: float,
) -> bool:  # fmt: skip
    """The wayside unit's step on one reading: True when a new command is due (its telegram, as
    quantised for the air, in ``s.pending``; its record in ``s.crow``)."""
    return wayside_command_1(p, run, s, out, k, t, doppler, passed, det_idx, pass_s)


class PlantPart:
    """The plant of one stop (the plant process): the train, its brakes, its sensors and the
    station's sensors reading it, from the stop's draw (its entry speed the train's own);
    ``start_m``: where the train is handed over (None: where a campaign's run starts)."""

    def __init__(
        self, model: KernelModel, scenario: Scenario, *, seed: int, run: int, start_m: float | None = None
    ) -> None:
        self.records = r = StopRecords(model, scenario, seed=seed, run=run)
        if start_m is not None:
            # [interpretation] live hands the train over where it is (a few centimetres past the
            # hand-over point at most: the plant's step), not where a campaign's run starts.
            r.train["position_m"] = start_m
        self._step = compiled_for(plant_part, (r.p, r.run, r.state, r.out, 0, 0.0, 0.0, False))
        self._sense = compiled_for(plant_sense, (r.run, r.state))

    def step(
        self, k: int, t_s: float, demand_mps2: float, braking: bool
    ) -> tuple[bool, float, bool, int, float]:
        """Step ``k`` at ``t_s`` (:func:`plant_part`)."""
        r = self.records
        got = self._step(r.p, r.run, r.state, r.out, k, t_s, demand_mps2, braking)
        stands, doppler, passed, det, pass_s = got
        return bool(stands), float(doppler), bool(passed), int(det), float(pass_s)

    def sense(self) -> tuple[float, float, float, bool, bool]:
        """:func:`plant_sense`."""
        tach, odo, transponder, stands, wsp = self._sense(self.records.run, self.records.state)
        return float(tach), float(odo), float(transponder), bool(stands), bool(wsp)

    @property
    def tally(self) -> Any:
        """The stop's tallies (``TALLY_DTYPE``: ``max_accel_change_mps2``, ...)."""
        return self.records.state.tally[0]

    @property
    def max_jerk_mps3(self) -> float:
        """The largest jerk under braking so far, as the stop's result gives it (``stop_finish``:
        the largest change of the acceleration between two steps, over the step)."""
        return float(self.tally["max_accel_change_mps2"]) / float(self.records.p.kp[KP_DT])


class _UnitPart:
    """A unit's side of one stop: the stop's records for the station (its parameters; the draw
    decides nothing the wayside or the onboard unit computes with) and the telegram it holds."""

    def __init__(self, model: KernelModel, scenario: Scenario) -> None:
        self.records = StopRecords(model, scenario, seed=0, run=0)

    @property
    def pending(self) -> Any:
        """The telegram (``TEL_*``): the wayside's latest command as quantised for the air; the one
        the onboard unit works with (a new one is written here before its cycle)."""
        return self.records.state.pending


class OnboardPart(_UnitPart):
    """The train's onboard TASC unit for one stop (the trains process)."""

    def __init__(self, model: KernelModel, scenario: Scenario) -> None:
        super().__init__(model, scenario)
        r = self.records
        self._cycle = compiled_for(
            onboard_part, (r.p, r.run, r.state, 0, 0.0, 0.0, 0.0, math.nan, False, False, False, False)
        )

    @property
    def rx(self) -> Any:
        """The receiver's state (``RX_*``)."""
        return self.records.state.rx

    def cycle(
        self, k: int, t_s: float, tach_mps: float, odometer_step_m: float, transponder_m: float, stands: bool,
        wsp: bool, new: bool, copy: bool,
    ) -> tuple[float, bool, bool]:  # fmt: skip
        """Step ``k`` at ``t_s`` (:func:`onboard_part`): (demand, braking, emergency brake)."""
        r = self.records
        demand, braking, eb = self._cycle(
            r.p, r.run, r.state, k, t_s, tach_mps, odometer_step_m, transponder_m, stands, wsp, new, copy
        )
        return float(demand), bool(braking), bool(eb)


class WaysidePart(_UnitPart):
    """A station's wayside TASC unit for one stop (the stations process)."""

    def __init__(self, model: KernelModel, scenario: Scenario) -> None:
        super().__init__(model, scenario)
        r = self.records
        self._command = compiled_for(wayside_part, (r.p, r.run, r.state, r.out, 0, 0.0, 0.0, False, 0, 0.0))

    @property
    def crow(self) -> Any:
        """The latest command's record (``tasc_unit`` ``CR_*``)."""
        return self.records.state.crow

    def command(
        self, k: int, t_s: float, doppler_mps: float, passed: bool, detector: int, passage_s: float
    ) -> bool:
        """The unit's step on one reading (:func:`wayside_part`): True when a new command is due."""
        r = self.records
        due = self._command(r.p, r.run, r.state, r.out, k, t_s, doppler_mps, passed, detector, passage_s)
        return bool(due)
