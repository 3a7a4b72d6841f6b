"""The wayside signal control unit of SPEC §1, array-first over runs.

Fed with wheel-sensor passages and Doppler samples, it computes at every
detector (and, with ``update = "continuous"``, every ``continuous_period_s``
between detectors) the braking deceleration required to stop at the stopping
point, and emits a braking control signal in one of the eight forms of
claim 3. Time is an argument; it draws no random numbers and does no I/O
(DESIGN rule 2). Every command and its inputs are returned for the database
(claims 8, 20).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import IntEnum
from typing import Any

import numpy as np
from numpy.typing import NDArray

from railstop.config.schema import Station, Vehicle
from railstop.control.notch import nearest_notch
from railstop.control.tasc import (
    CommandHistory,
    ExternalModel,
    GainEstimate,
    closed_loop_command,
    fit_doppler,
    fit_passages,
    hat_weights,
    modelled_means,
    regression_weights,
)
from railstop.physics.brake import decel_to_pwm
from railstop.physics.train import GradientProfile

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
BoolArray = NDArray[np.bool_]


class SignalForm(IntEnum):
    """SPEC §1 claim 3: the forms the train braking control signal may take."""

    POSITION = 1
    DISTANCE = 2
    INTERVAL_TIME = 3
    SPEED = 4
    DECELERATION = 5
    REQUIRED_DECELERATION = 6
    BRAKE_COMMAND = 7
    INCREASE_DECREASE = 8


FORM_NAMES = {
    SignalForm.POSITION: "train position",
    SignalForm.DISTANCE: "distance to stopping point",
    SignalForm.INTERVAL_TIME: "time between two detectors",
    SignalForm.SPEED: "speed",
    SignalForm.DECELERATION: "deceleration",
    SignalForm.REQUIRED_DECELERATION: "required braking deceleration",
    SignalForm.BRAKE_COMMAND: "brake-system control command",
    SignalForm.INCREASE_DECREASE: "increase / decrease braking",
}


@dataclass(slots=True, kw_only=True)
class TascTelegrams:
    """Braking control signals sent this step (rows where ``mask`` is set).

    Fields not carried by the form are NaN (forms 1-5 carry measurements,
    SPEC §1: "the onboard unit computes the required deceleration itself").
    """

    form: SignalForm
    mask: BoolArray
    detector: IntArray  # index of the last detector passed (-1 none)
    passage_s: FloatArray  # time of that passage
    measured_s: FloatArray  # time the measurement refers to (= send time)
    position_m: FloatArray
    distance_m: FloatArray
    interval_s: FloatArray
    speed_mps: FloatArray
    decel_mps2: FloatArray
    required_mps2: FloatArray
    notch: IntArray
    duty: FloatArray
    delta: IntArray


@dataclass(kw_only=True)
class GroundTascUnit:
    station: Station
    vehicle: Vehicle
    gradient: GradientProfile
    n: int
    dt_s: float
    form: SignalForm = SignalForm.REQUIRED_DECELERATION
    record: bool = False
    records: list[dict[str, Any]] = field(default_factory=list)

    def __post_init__(self) -> None:
        tasc = self.station.tasc
        n = self.n
        self.det_to_stop_m = np.asarray(tasc.detectors_before_stop_m, dtype=np.float64)
        self.det_pos_m = self.station.stop_point_m - self.det_to_stop_m
        self.has_doppler = tasc.doppler is not None
        w = round(tasc.doppler.fit_window_s / self.dt_s) if tasc.doppler else 1
        self.window = max(int(w), 2)
        self.speed_samples = max(round(tasc.doppler.speed_window_s / self.dt_s), 2) if tasc.doppler else 2
        self.doppler_buf = np.zeros((self.window, n))  # (sample slot, run): one contiguous write per step
        self.doppler_count = np.zeros(n, dtype=np.int64)
        self.doppler_col = -1
        # Running sums of a least-squares line through the Doppler samples since
        # the last command took effect (time relative to that start): the
        # deceleration over the whole interval between commands. A brake
        # controller alternating two notches matches the target only on
        # average over its alternation; a window of the interval sees that
        # average, a short one can see mostly one notch.
        self.win_start_s = np.zeros(n)
        self.win_sums = np.zeros((5, n))  # count, Σt, Σt², Σv, Σtv
        self.pass_t = np.full((n, 3), np.nan)
        self.pass_x = np.full((n, 3), np.nan)
        self.pass_count = np.zeros(n, dtype=np.int64)
        self.last_detector = np.full(n, -1, dtype=np.int64)
        self.last_passage_s = np.full(n, np.nan)
        self.travel_m = np.zeros(n)  # Doppler-integrated travel since the last passage
        self.history = CommandHistory.create(n)
        self.gain = GainEstimate.create(n)
        self.believed_mps2 = np.zeros(n)  # form 8: what the train is believed to apply
        self.sent = np.zeros(n, dtype=np.int64)
        self.first_sent_s = np.full(n, np.inf)  # the train holds its speed until then
        self.external = ExternalModel.create(self.vehicle, self.gradient, self.station.stop_point_m)
        self.next_update_s = np.full(n, np.inf)
        brake = self.vehicle.brake
        self.notch_table = np.asarray(brake.notch_decel_mps2, dtype=np.float64)
        self.max_mps2 = brake.full_service_mps2
        # Equivalent dead time until a new command acts (SPEC §1: "allowing
        # for the brake's dead time and lag"): radio latency + dead time + tau.
        self.base_delay_s = tasc.assumed_link_latency_s + brake.dead_time_s + brake.time_constant_s

    # -- measurements -------------------------------------------------------
    def _measure(
        self, now_s: float, rows: IntArray, new_passage: BoolArray
    ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray, FloatArray]:
        """For ``rows``: speed now, measured decel, distance to go, and the window's
        modelled means (commanded brake decel, external decel while braking)
        that the measured deceleration is to be compared with; plus interval time.
        """
        hist = self.history.subset(rows)
        interval = self.pass_t[rows, 2] - self.pass_t[rows, 1]
        now = np.full(rows.size, now_s)
        if self.has_doppler:
            order = (self.doppler_col + 1 + np.arange(self.window)) % self.window
            samples = self.doppler_buf[np.ix_(order, rows)].T  # (runs, samples), oldest first
            count = self.doppler_count[rows]
            speed, decel = fit_doppler(samples, self.dt_s, count, self.speed_samples)
            # Prefer the interval since the last command took effect when it is longer.
            c, st, stt, sv, stv = self.win_sums[:, rows]
            longer = c > count
            sxx = stt - st * st / np.maximum(c, 1.0)
            slope = np.where(
                longer & (sxx > 0), (stv - st * sv / np.maximum(c, 1.0)) / np.where(sxx > 0, sxx, 1.0), 0.0
            )
            decel = np.where(longer, -slope, decel)
            count = np.where(longer, c.astype(np.int64), count)
            since = now_s - self.last_passage_s[rows]
            # At a passage, the travel since it is reconstructed from the fit.
            travel = np.where(
                new_passage[rows],
                speed * since + 0.5 * decel * since * since,
                self.travel_m[rows],
            )
            self.travel_m[rows] = travel
            distance = self.det_to_stop_m[self.last_detector[rows]] - travel
            taus, w = regression_weights(now - (count - 1) * self.dt_s, now)
            cmd_mean, ext_mean = modelled_means(
                hist,
                taus,
                w,
                self.first_sent_s[rows],
                lag_s=self.vehicle.brake.time_constant_s,
                external=self.external,
                distance_m=distance,
                speed_mps=speed,
                decel_mps2=decel,
                now_s=now,
                rows=rows,
            )
            return speed, decel, distance, cmd_mean, ext_mean, interval
        # SPEC §1 variant 2: passage times only. The mean speed over the last
        # interval is corrected to the newest passage with the modelled
        # deceleration; three passages measure the (hat-weighted) deceleration.
        t = self.pass_t[rows]
        x = self.pass_x[rows]
        count = self.pass_count[rows]
        gain = self.gain.value(rows)
        v_mean = (x[:, 2] - x[:, 1]) / (t[:, 2] - t[:, 1])
        # v(t2) = mean speed - (1/Δ) ∫_{t1}^{t2} (τ - t1) a(τ) dτ
        frac = (np.arange(16) + 0.5) / 16
        taus = t[:, 1, None] + (t[:, 2] - t[:, 1])[:, None] * frac[None, :]
        ext = self.external.decel_at(self.det_to_stop_m[self.last_detector[rows]], v_mean, rows)
        a_model = gain[:, None] * hist.value_at(taus) + ext[:, None] * (taus >= self.first_sent_s[rows, None])
        v_p = v_mean - (t[:, 2] - t[:, 1]) * (a_model * frac[None, :]).mean(axis=1)
        a_now = gain * hist.value_at(now) + ext * (now >= self.first_sent_s[rows])
        since = now_s - t[:, 2]
        speed = v_p - a_now * since
        distance = self.det_to_stop_m[self.last_detector[rows]] - (v_p * since - 0.5 * a_now * since**2)
        decel = np.full(rows.size, np.nan)
        cmd_mean = np.zeros(rows.size)
        ext_mean = np.zeros(rows.size)
        if (count >= 3).any():
            _, decel = fit_passages(t, x, count)
            taus3, w3 = hat_weights(t[:, 0], t[:, 1], t[:, 2])
            cmd_mean, ext_mean = modelled_means(
                hist,
                taus3,
                w3,
                self.first_sent_s[rows],
                lag_s=self.vehicle.brake.time_constant_s,
                external=self.external,
                distance_m=distance,
                speed_mps=speed,
                decel_mps2=decel,
                now_s=now,
                rows=rows,
            )
        return speed, decel, distance, cmd_mean, ext_mean, interval

    # -- the unit -----------------------------------------------------------
    def step(
        self,
        now_s: float,
        *,
        passed: BoolArray,
        detector: IntArray,
        passage_s: FloatArray,
        doppler_mps: FloatArray | None,
    ) -> TascTelegrams | None:
        """Take this step's measurements; return the telegrams to send (or None)."""
        if self.has_doppler and doppler_mps is not None:
            # Ring buffer with one write column for all runs (no copying per step).
            self.doppler_col = (self.doppler_col + 1) % self.window
            self.doppler_buf[self.doppler_col] = doppler_mps
            t_rel = np.maximum(now_s - self.win_start_s, -1.0)
            use = t_rel >= 0.0
            sums = self.win_sums
            sums[0] += use
            tu = np.where(use, t_rel, 0.0)
            vu = np.where(use, doppler_mps, 0.0)
            sums[1] += tu
            sums[2] += tu * tu
            sums[3] += vu
            sums[4] += tu * vu
            self.doppler_count = np.minimum(self.doppler_count + 1, self.window)
            self.travel_m += doppler_mps * self.dt_s
        if passed.any():
            self.pass_t[passed] = np.roll(self.pass_t[passed], -1, axis=1)
            self.pass_x[passed] = np.roll(self.pass_x[passed], -1, axis=1)
            self.pass_t[passed, 2] = passage_s[passed]
            self.pass_x[passed, 2] = self.det_pos_m[detector[passed]]
            self.pass_count[passed] += 1
            self.last_detector[passed] = detector[passed]
            self.last_passage_s[passed] = passage_s[passed]
        # SPEC §1: control at every detector (variant 2 needs two passages for a speed).
        need = self.pass_count >= (1 if self.has_doppler else 2)
        due = passed & need
        if self.station.tasc.update == "continuous":
            due = due | (need & (now_s >= self.next_update_s))
        if not due.any():
            return None
        return self._command(now_s, due, passed)

    def _command(self, now_s: float, due: BoolArray, passed: BoolArray) -> TascTelegrams:
        rows = np.flatnonzero(due)
        speed, decel, distance, cmd_mean, ext_mean, interval = self._measure(now_s, rows, passed)
        # Loop closure (SPEC §1 claims 2, 19) and the next command.
        gain, command, a_true, effect = closed_loop_command(
            distance_m=distance,
            speed_mps=speed,
            now_s=np.full(rows.size, now_s),
            history=self.history.subset(rows),
            gain=self.gain,
            measured_decel_mps2=decel,
            commanded_mean_mps2=cmd_mean,
            external_mean_mps2=ext_mean,
            base_delay_s=self.base_delay_s,
            jerk_limit_mps3=self.vehicle.brake.jerk_limit_mps3,
            max_decel_mps2=self.max_mps2,
            external=self.external,
            rows=rows,
        )
        now = np.full(rows.size, now_s)
        form = self.form
        notch = nearest_notch(command, self.notch_table)
        delta = np.zeros(speed.shape, dtype=np.int64)
        executed = command
        if form == SignalForm.BRAKE_COMMAND:
            executed = np.concatenate(([0.0], self.notch_table))[notch]
        elif form == SignalForm.INCREASE_DECREASE:
            # SPEC §1 form 8: one notch up or down per telegram.
            step = self.notch_table[0]
            believed = self.believed_mps2[due]
            delta = np.where(command > believed + step / 2, 1, np.where(command < believed - step / 2, -1, 0))
            executed = np.clip(believed + delta * step, 0.0, self.max_mps2)
            self.believed_mps2[due] = executed
        if form >= SignalForm.REQUIRED_DECELERATION:
            self.history.push(due, _scatter(due, executed), _scatter(due, effect))
        self.sent[due] += 1
        # The train holds its speed (its own traction control) until it is told to brake.
        self.first_sent_s[due] = np.where(
            executed > 0.0, np.minimum(self.first_sent_s[due], now_s), self.first_sent_s[due]
        )
        # The next measurement interval starts when this command takes effect.
        self.win_start_s[due] = effect
        self.win_sums[:, due] = 0.0
        if self.station.tasc.update == "continuous":
            self.next_update_s[due] = now_s + self.station.tasc.continuous_period_s
        det = self.last_detector[due]
        tele = TascTelegrams(
            form=form,
            mask=due,
            detector=_scatter(due, det, -1),
            passage_s=_scatter(due, self.last_passage_s[due]),
            measured_s=_scatter(due, now),
            position_m=_scatter(due, self.station.stop_point_m - distance),
            distance_m=_scatter(due, distance),
            interval_s=_scatter(due, interval),
            speed_mps=_scatter(due, speed),
            decel_mps2=_scatter(due, decel),
            required_mps2=_scatter(due, command),
            notch=_scatter(due, notch, 0),
            duty=_scatter(due, decel_to_pwm(command, self.vehicle.brake)),
            delta=_scatter(due, delta, 0),
        )
        _blank_unsent_fields(tele)
        if self.record:
            rows = np.flatnonzero(due)
            for i, r in enumerate(rows):
                self.records.append(
                    {
                        "run": int(r),
                        "t_s": float(now_s),
                        "form": int(form),
                        "detector": int(det[i]),
                        "passage_s": float(self.last_passage_s[r]),
                        "distance_m": float(distance[i]),
                        "speed_mps": float(speed[i]),
                        "measured_decel_mps2": _f(decel[i]),
                        "gain": float(gain[i]),
                        "required_decel_mps2": _f(a_true[i]),
                        "command_decel_mps2": float(command[i]),
                        "notch": int(notch[i]),
                        "delta": int(delta[i]),
                        "effect_s": float(effect[i]),
                    }
                )
        return tele


def _f(x: float) -> float | None:
    return float(x) if np.isfinite(x) else None


def _scatter(mask: BoolArray, values: NDArray[Any], fill: float = np.nan) -> NDArray[Any]:
    """Full-length array with ``values`` at the rows of ``mask`` and ``fill`` elsewhere."""
    values = np.asarray(values)
    dtype = values.dtype if values.dtype.kind in "iu" else np.float64
    out = np.full(mask.shape, fill, dtype=dtype)
    out[mask] = values
    return out


def _blank_unsent_fields(t: TascTelegrams) -> None:
    """Forms 1-5 carry only their measurement; the rest is not on the air (NaN)."""
    keep = {
        SignalForm.POSITION: {"position_m"},
        SignalForm.DISTANCE: {"distance_m"},
        SignalForm.INTERVAL_TIME: {"interval_s"},
        SignalForm.SPEED: {"speed_mps"},
        SignalForm.DECELERATION: {"decel_mps2"},
    }.get(t.form)
    if keep is None:
        return
    for name in (
        "position_m",
        "distance_m",
        "interval_s",
        "speed_mps",
        "decel_mps2",
        "required_mps2",
    ):
        if name not in keep:
            setattr(t, name, np.full(t.mask.shape, np.nan))
