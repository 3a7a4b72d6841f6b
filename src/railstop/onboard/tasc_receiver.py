"""The onboard signal control unit of SPEC §1 in its three configurations, array-first.

- ``tasc-brake-controller`` (config 1, claims 9-11): the command goes to the
  train's own brake controller, whose logic picks the notch every control
  cycle (alternating the two notches around a continuous target, with a
  minimum hold) and drives the encoder -> 3-wire step code.
- ``tasc-step`` (config 2, claims 12-14): the onboard controller turns the
  required deceleration into the B1..B7 step code itself and forces wires
  a, b, c through the switching unit (SW1-SW3), every simulation step.
- ``tasc-pwm`` (config 3, claims 15, 25): a PWM duty synchronised to the zero
  crossing of the existing PWM brake signal and superimposed on it: the ECU
  sees the larger duty, latched once per carrier period.

For signal forms 1-5 the receiver computes the required deceleration itself
(SPEC §1) with the same control law as the wayside, from the telegram's
measurement completed by its own tachometer and station data.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum

import numpy as np
from numpy.typing import NDArray

from railstop.config.schema import Station, Vehicle
from railstop.control.notch import NotchModulator
from railstop.control.tasc import (
    CommandHistory,
    ExternalModel,
    GainEstimate,
    closed_loop_command,
    fit_doppler,
    modelled_means,
    regression_weights,
)
from railstop.physics.brake import BrakeLine, decel_to_pwm, encode_step, superimpose_pwm
from railstop.physics.train import GradientProfile
from railstop.wayside.tasc_unit import SignalForm, TascTelegrams

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
BoolArray = NDArray[np.bool_]


class OnboardConfig(StrEnum):
    BRAKE_CONTROLLER = "tasc-brake-controller"
    STEP = "tasc-step"
    PWM = "tasc-pwm"


@dataclass(frozen=True, slots=True, kw_only=True)
class BrakeSignal:
    """What reaches the brake ECU: a step-coded brake line or a PWM duty."""

    line: BrakeLine | None  # step-controlled trains
    duty: FloatArray | None  # PWM-controlled trains
    emergency: BoolArray


class TascReceiver:
    """Onboard TASC receiver for n runs."""

    def __init__(
        self,
        *,
        config: OnboardConfig,
        station: Station,
        vehicle: Vehicle,
        gradient: GradientProfile,
        n: int,
        dt_s: float,
        form: SignalForm,
    ) -> None:
        self.config = config
        self.station = station
        self.vehicle = vehicle
        self.n = n
        self.dt_s = dt_s
        self.form = form
        brake = vehicle.brake
        self.active = np.zeros(n, dtype=bool)
        self.target_mps2 = np.zeros(n)
        self.fixed_notch = np.full(n, -1, dtype=np.int64)  # form 7 (step trains)
        self.fixed_duty = np.full(n, np.nan)  # form 7 (PWM trains)
        self.received = np.zeros(n, dtype=np.int64)
        hold = (
            brake.controller_min_hold_s if config == OnboardConfig.BRAKE_CONTROLLER else brake.tasc_min_hold_s
        )
        self.modulator = NotchModulator.create(
            n, brake.notch_decel_mps2, hold, brake.dead_time_s + brake.time_constant_s
        )
        self.cycle_steps = (
            max(1, round(brake.controller_cycle_s / dt_s)) if config == OnboardConfig.BRAKE_CONTROLLER else 1
        )
        self.pwm_steps = max(1, round(1.0 / (brake.pwm_carrier_hz * dt_s)))
        self.existing_duty = np.zeros(n)  # the train's own PWM brake signal (released)
        self.latched_duty = np.zeros(n)
        self.step_index = 0
        self.notch = np.zeros(n, dtype=np.int64)
        # Forms 1-5: the onboard planner (same law as the wayside).
        self.det_to_stop_m = np.asarray(station.tasc.detectors_before_stop_m, dtype=np.float64)
        self.history = CommandHistory.create(n)
        self.gain = GainEstimate.create(n)
        self.window = max(2, round(1.0 / dt_s))
        self.speed_samples = max(2, round(0.3 / dt_s))  # as the wayside's Doppler speed window
        self.tach_buf = np.zeros((self.window, n))  # (sample slot, run)
        self.tach_count = np.zeros(n, dtype=np.int64)
        self.tach_col = -1
        self.base_delay_s = brake.dead_time_s + brake.time_constant_s
        self.first_rx_s = np.full(n, np.inf)
        self.external = ExternalModel.create(vehicle, gradient, station.stop_point_m)

    @property
    def notch_changes(self) -> IntArray:
        return self.modulator.changes

    def observe_tachometer(self, speed_mps: FloatArray) -> None:
        """Onboard speed from the tachometer (only the forms 1-5 planner uses it)."""
        if self.form > SignalForm.DECELERATION:
            return
        self.tach_col = (self.tach_col + 1) % self.window
        self.tach_buf[self.tach_col] = speed_mps
        self.tach_count = np.minimum(self.tach_count + 1, self.window)

    def receive(self, tele: TascTelegrams, delivered: BoolArray, now_s: float) -> None:
        """Take the telegrams delivered now."""
        if not delivered.any():
            return
        self.active |= delivered
        # (set after the target below: the train holds its speed until told to brake)
        self.received += delivered
        self.modulator.restart(delivered)
        form = tele.form
        if form == SignalForm.REQUIRED_DECELERATION:
            self.target_mps2 = np.where(delivered, tele.required_mps2, self.target_mps2)
        elif form == SignalForm.BRAKE_COMMAND:
            self.fixed_notch = np.where(delivered, tele.notch, self.fixed_notch)
            self.fixed_duty = np.where(delivered, tele.duty, self.fixed_duty)
            table = np.concatenate(([0.0], self.vehicle.brake.notch_decel_mps2))
            self.target_mps2 = np.where(delivered, table[np.maximum(tele.notch, 0)], self.target_mps2)
        elif form == SignalForm.INCREASE_DECREASE:
            # SPEC §1 config 1: increase / decrease passed as such: one notch per telegram.
            step = self.vehicle.brake.notch_decel_mps2[0]
            new = np.clip(self.target_mps2 + tele.delta * step, 0.0, self.vehicle.brake.full_service_mps2)
            self.target_mps2 = np.where(delivered, new, self.target_mps2)
        else:
            self._plan_onboard(tele, delivered, now_s)
        brake_now = delivered & (self.target_mps2 > 0.0)
        self.first_rx_s = np.where(brake_now, np.minimum(self.first_rx_s, now_s), self.first_rx_s)

    @property
    def braking(self) -> BoolArray:
        """Runs told to brake: until then the train holds its speed with its own traction control."""
        return np.isfinite(self.first_rx_s)

    def _plan_onboard(self, tele: TascTelegrams, rows: BoolArray, now_s: float) -> None:
        """Forms 1-5: complete the measurement and compute the required deceleration onboard."""
        order = (self.tach_col + 1 + np.arange(self.window)) % self.window
        samples = self.tach_buf[np.ix_(order, np.flatnonzero(rows))].T
        tach_v, tach_a = fit_doppler(samples, self.dt_s, self.tach_count[rows], self.speed_samples)
        form = tele.form
        det = tele.detector[rows]
        since = now_s - tele.passage_s[rows]
        a_est = np.where(np.isfinite(tach_a), tach_a, 0.0)
        if form == SignalForm.DECELERATION:
            a_est = np.where(np.isfinite(tele.decel_mps2[rows]), tele.decel_mps2[rows], a_est)
        speed = tach_v
        if form == SignalForm.SPEED:
            speed = tele.speed_mps[rows] - a_est * (now_s - tele.measured_s[rows])
        elif form == SignalForm.INTERVAL_TIME:
            # Mean speed over the last interval belongs to its midpoint in time.
            spacing = self.det_to_stop_m[np.maximum(det - 1, 0)] - self.det_to_stop_m[det]
            interval = tele.interval_s[rows]
            ok = np.isfinite(interval) & (interval > 0) & (det > 0)
            v_mid = spacing / np.where(ok, interval, 1.0)
            speed = np.where(ok, v_mid - a_est * (since + interval / 2.0), tach_v)
        if form == SignalForm.POSITION:
            distance = self.station.stop_point_m - tele.position_m[rows]
        elif form == SignalForm.DISTANCE:
            distance = tele.distance_m[rows]
        else:
            distance = self.det_to_stop_m[det] - (speed * since + 0.5 * a_est * since * since)
        if form == SignalForm.POSITION or form == SignalForm.DISTANCE:
            lag = now_s - tele.measured_s[rows]
            distance = distance - (speed * lag + 0.5 * a_est * lag * lag)
        idx = np.flatnonzero(rows)
        now = np.full(speed.shape, now_s)
        hist = self.history.subset(idx)
        count = self.tach_count[rows]
        taus, w = regression_weights(now - (count - 1) * self.dt_s, now)
        cmd_mean, ext_mean = modelled_means(
            hist,
            taus,
            w,
            self.first_rx_s[idx],
            lag_s=self.vehicle.brake.time_constant_s,
            external=self.external,
            distance_m=distance,
            speed_mps=speed,
            decel_mps2=a_est,
            now_s=now,
            rows=idx,
        )
        _, command, _, effect = closed_loop_command(
            distance_m=distance,
            speed_mps=speed,
            now_s=now,
            history=hist,
            gain=self.gain,
            measured_decel_mps2=a_est,
            commanded_mean_mps2=cmd_mean,
            external_mean_mps2=ext_mean,
            base_delay_s=self.base_delay_s,
            jerk_limit_mps3=self.vehicle.brake.jerk_limit_mps3,
            max_decel_mps2=self.vehicle.brake.full_service_mps2,
            external=self.external,
            rows=idx,
        )
        full_cmd = np.zeros(self.n)
        full_cmd[rows] = command
        full_eff = np.zeros(self.n)
        full_eff[rows] = effect
        self.history.push(rows, full_cmd, full_eff)
        self.target_mps2 = np.where(rows, full_cmd, self.target_mps2)

    def output(self, speed_mps: FloatArray) -> BrakeSignal:
        """The brake signal of this step, for the ECU (``speed_mps``: the tachometer's speed)."""
        k = self.step_index
        self.step_index += 1
        emergency = np.zeros(self.n, dtype=bool)
        brake = self.vehicle.brake
        if self.config == OnboardConfig.PWM:
            onboard = np.where(
                np.isfinite(self.fixed_duty), self.fixed_duty, decel_to_pwm(self.target_mps2, brake)
            )
            onboard = np.where(self.active, onboard, 0.0)
            if k % self.pwm_steps == 0:
                # Zero crossing of the existing PWM: both pulses start together,
                # the ECU sees their OR = the larger duty (SPEC §1 config 3).
                self.latched_duty = superimpose_pwm(self.existing_duty, onboard)
            return BrakeSignal(line=None, duty=self.latched_duty, emergency=emergency)
        if k % self.cycle_steps == 0:
            dt = self.cycle_steps * self.dt_s
            notch = self.modulator.update(self.target_mps2, self.active, dt, speed_mps)
            self.notch = np.where(self.fixed_notch >= 0, self.fixed_notch, notch)
        # Config 1: brake controller -> encoder; config 2: the switching unit
        # forces a, b, c; wire e always passes through from the train.
        return BrakeSignal(line=encode_step(self.notch, emergency), duty=None, emergency=emergency)
