"""A test per signal form stops a train (issue 13): every form of SPEC §1 claim 3 with every TASC
controller at Riverside, nominal and at crush load with weak brakes, and what each form's
telegrams carry on the air (forms 1-5: para 92's combinations; forms 7, 8: the wayside's
notch modulation).

``benchmarks/tasc_forms.py`` measures the same stops at every default station."""

from __future__ import annotations

from functools import cache
from typing import Any

import numpy as np
import pytest

from railstop.config import default_line, default_vehicle
from railstop.config.disturbances import load_disturbances
from railstop.controllers import (
    TASC_BRAKE_CONTROLLER,
    TASC_CONTROLLERS,
    TASC_PWM,
    TASC_STEP,
    TASC_SWITCHED_PWM,
)
from railstop.link.codec import TASC_FORM_TYPES
from railstop.sim.engine import BatchResult
from railstop.sim.single import StopResult, run_stop
from railstop.wayside.tasc_unit import SignalForm

LINE = default_line()
VEHICLE = default_vehicle()
STATION = LINE.station("Riverside")  # the line's first, the CLI's default
STANDARD = load_disturbances("standard")
FORMS = list(SignalForm)
# (load factor, brake gain, band): the single-stop targets of the ground-TASC issue.
CASES = {"nominal": (0.0, 1.0, 0.10), "crush": (1.0, 0.85, 0.35)}
STEP_CODED = (TASC_BRAKE_CONTROLLER, TASC_STEP)  # config 1 and config 2's step code: notches only

# SPEC §1 para 92: the measurements each of forms 1-5 must carry (the train computes the rest).
PARA_92: dict[SignalForm, tuple[str, ...]] = {
    SignalForm.POSITION: ("distance_m", "interval_s", "position_m"),
    SignalForm.DISTANCE: ("distance_m", "interval_s", "position_m"),
    SignalForm.INTERVAL_TIME: ("distance_m", "interval_s", "position_m"),
    SignalForm.SPEED: ("distance_m", "speed_mps"),
    SignalForm.DECELERATION: ("distance_m", "decel_mps2"),
}
# Absent (None) allowed: the interval before the second detector, the deceleration before the
# wayside can measure one.
MAY_BE_ABSENT = ("interval_s", "decel_mps2")


@cache
def _stop(form: SignalForm, controller: str, case: str) -> tuple[StopResult, BatchResult]:
    load, gain, _ = CASES[case]
    return run_stop(
        line=LINE,
        station=STATION,
        vehicle=VEHICLE,
        controller=controller,
        seed=1,
        load_factor=load,
        brake_gain=gain,
        form=form,
    )


def _standard_run(controller: str, form: SignalForm, run: int) -> tuple[StopResult, BatchResult]:
    """Run ``run`` of the standard set (seed 1) at the station, as ``railstop stop --disturbances
    standard --run N`` replays it."""
    return run_stop(
        line=LINE, station=STATION, vehicle=VEHICLE, controller=controller, seed=1, form=form,
        disturbances=STANDARD, run=run,
    )  # fmt: skip


def _assert_served(result: StopResult) -> None:
    """No emergency brake, and the stop within ±0.30 m."""
    assert result.emergency_brake is None
    assert abs(result.stop_error_m) <= 0.30, f"{result.stop_error_m:+.3f} m"


def _telegrams(form: SignalForm, controller: str, case: str) -> list[dict[str, Any]]:
    """The command records of the stop; every one went on the air as a telegram of the form."""
    commands = _stop(form, controller, case)[1].commands
    assert commands, "no telegram was sent"
    want = TASC_FORM_TYPES[int(form)].TYPE
    assert [c["telegram_type"] for c in commands] == [want] * len(commands)
    return commands


# Every form with every TASC controller in both cases at Riverside. Until stop model 11 form 8
# on the switched PWM train, nominal, ended +0.320 m (a strict xfail here): the wayside's
# modulator stepped the train down a notch in the step of the last detector's passage and form 8
# brings it back one notch per 0.3 s. Since model 11 (the Doppler speed from the short window's
# mean, the form-8 modulator moving one notch per hold along the planned ramp) that stop ends
# +0.015 m (docs/results.md, "Signal forms").
@pytest.mark.parametrize(
    ("form", "controller", "case"),
    [
        pytest.param(
            form,
            controller,
            case,
            id=f"form{int(form)}-{controller}-{case}",
        )
        for form in FORMS
        for controller in TASC_CONTROLLERS
        for case in CASES
    ],
)
def test_form_stops_the_train_within_its_band(form: SignalForm, controller: str, case: str) -> None:
    result, _ = _stop(form, controller, case)
    band = CASES[case][2]
    assert result.form == int(form)
    assert result.stopped
    assert result.emergency_brake is None
    assert abs(result.stop_error_m) <= band, f"{result.stop_error_m:+.3f} m"


@pytest.mark.parametrize("case", list(CASES))
@pytest.mark.parametrize("controller", TASC_CONTROLLERS)
@pytest.mark.parametrize("form", sorted(PARA_92), ids=lambda f: f"form{int(f)}")
def test_forms_1_to_5_carry_the_para_92_combination(form: SignalForm, controller: str, case: str) -> None:
    """Measurements only, in para 92's combination: the distance in every form, the interval and
    the position in forms 1-3, the speed in form 4, the deceleration in form 5; never the
    required deceleration (claim 10: the train computes it)."""
    for telegram in (c["telegram"] for c in _telegrams(form, controller, case)):
        assert "required_mps2" not in telegram
        for key in PARA_92[form]:
            assert key in telegram, key
            if key not in MAY_BE_ABSENT:
                assert telegram[key] is not None, key
        if "interval_s" in PARA_92[form] and telegram["detector"] > 0:
            assert telegram["interval_s"] is not None and telegram["interval_s"] > 0.0


@pytest.mark.parametrize("case", list(CASES))
@pytest.mark.parametrize("controller", STEP_CODED)
def test_form_7_the_wayside_modulates_the_notch(controller: str, case: str) -> None:
    """A step-coded train gets more telegrams than the 5 detector commands: the wayside sends a
    new one whenever its modulator's notch changes, so between two detector commands every
    telegram changes the notch."""
    result, _ = _stop(SignalForm.BRAKE_COMMAND, controller, case)
    assert result.commands > 5
    telegrams = _telegrams(SignalForm.BRAKE_COMMAND, controller, case)
    assert len(telegrams) > 5
    for prev, this in zip(telegrams, telegrams[1:], strict=False):
        if this["detector"] == prev["detector"]:  # a modulation telegram, not a detector command
            assert this["telegram"]["notch"] != prev["telegram"]["notch"], this["t_s"]


@pytest.mark.parametrize("case", list(CASES))
@pytest.mark.parametrize("controller", TASC_CONTROLLERS)
def test_form_8_one_notch_step_per_telegram_spaced(controller: str, case: str) -> None:
    """Every telegram is one notch up or down, and the wayside spaces its steps at least the
    train's minimum notch hold apart."""
    hold = VEHICLE.brake.controller_min_hold_s
    telegrams = _telegrams(SignalForm.INCREASE_DECREASE, controller, case)
    assert [c["telegram"]["delta"] for c in telegrams] == [c["delta"] for c in telegrams]
    assert all(c["telegram"]["delta"] in (-1, 1) for c in telegrams)
    times = [c["t_s"] for c in telegrams]
    for earlier, later in zip(times, times[1:], strict=False):
        assert later - earlier >= hold - 1e-9, (earlier, later)


# Stop model 12 (issue 36): the onboard unit of forms 1-5 calibrates its tachometer only over
# stretches in which its wheel-slide protection did not act. Standard run 840 slides on a
# low-adhesion patch between the first two detectors: on model 11 the interval's tachometer
# distance, short by the slide, set the scale a half too high and forms 1 and 5 ended 143 m
# short, form 4 (its loop gain updated over the slide) 7.2 m short.
@pytest.mark.parametrize(
    "form", [SignalForm.POSITION, SignalForm.SPEED, SignalForm.DECELERATION], ids=lambda f: f"form{int(f)}"
)
def test_a_slide_does_not_calibrate_the_tachometer(form: SignalForm) -> None:
    result, batch = _standard_run(TASC_PWM, form, 840)
    assert bool(batch.slid[0]), "run 840 no longer slides: pick another run"
    _assert_served(result)


# Form 4 calibrates its tachometer from the wayside's distances (stop model 12). These standard
# runs approach uphill at 17-20 per mille with the odometer's wheel diameter 0.9-1.4 % below the
# actual: the brake gives a third of the deceleration, and the uncalibrated tachometer's
# deceleration biased the loop gain so that on model 11 they ended 0.42, 0.43 and 0.42 m short,
# silently.
@pytest.mark.parametrize("run", [2131, 6781, 9429])
def test_form_4_calibrates_its_tachometer_from_the_wayside_distances(run: int) -> None:
    result, batch = _standard_run(TASC_PWM, SignalForm.SPEED, run)
    assert not bool(batch.slid[0])
    assert abs(result.stop_error_m) <= 0.30, f"{result.stop_error_m:+.3f} m"


# Stop model 14 (HZ-TASC-06): standard runs in which every transmission of one form-8 step was
# lost (the attempts at 32.53, 32.63 and 32.73 s of run 8450; on models 14-16, at 32.16, 32.26 and
# 32.36 s of run 1172). On model 13 the train then braked a notch off the wayside's belief for the
# rest of the stop: run 8450 (tasc-pwm) ended 2.06 m past the stopping point, run 1172
# (tasc-step) 31.09 m short, both silently. On model 17 run 1172's braking starts at a later
# detector and no step of it is lost; run 6007 is the standard run of `tasc-step` with form 8
# that loses one now (the only one of 10,000 that did not slide).
@pytest.mark.parametrize(("controller", "run"), [(TASC_PWM, 8450), (TASC_STEP, 6007)])
def test_a_lost_form_8_step_hands_the_stop_to_degraded_mode(controller: str, run: int) -> None:
    result, batch = _standard_run(controller, SignalForm.INCREASE_DECREASE, run)
    assert result.stopped and not bool(batch.slid[0])
    # It took no more steps and aimed at a deceleration of its own (degraded mode): a form-8 train
    # otherwise only ever aims at one of its eight notches.
    assert batch.trace is not None
    targets = batch.trace.target_decel_mps2[:, 0]
    assert np.unique(targets[np.isfinite(targets)]).size > 8
    assert result.stop_error_m <= STATION.platform_end - STATION.stop_point_m  # never past the end
    # Degraded mode stops it at the platform or, failing that, the guard brakes it: no silent miss.
    assert abs(result.stop_error_m) <= STATION.psd_tolerance_m or result.emergency_brake is not None, (
        f"{result.stop_error_m:+.3f} m"
    )
    # The step numbers on the air: 1, 2, ... one per telegram (none skipped by the wayside), after
    # a first telegram of step 0 where the braking waited for a later detector (a hold).
    steps = [c["telegram"]["step"] for c in batch.commands if not c["emergency"]]
    first = 0 if steps[:1] == [0] else 1
    assert steps == [(i + first) % 256 for i in range(len(steps))]


# Stop model 17: slow standard runs on an uphill approach whose braking waits for a later detector
# (control.tasc.START_FLOOR). Form 8 sends no telegram for a command that changes no notch, so
# without its first telegram (a hold, step 0) these trains heard nothing inside the zone, and the
# onboard supervision braked them by emergency brake 147-159 m short (telegram time-out).
@pytest.mark.parametrize("run", [1436, 8139])
def test_a_form_8_stop_whose_braking_waits_sends_a_hold_first(run: int) -> None:
    result, batch = _standard_run(TASC_PWM, SignalForm.INCREASE_DECREASE, run)
    first = batch.commands[0]
    assert first["telegram"]["step"] == 0 and first["telegram"]["delta"] == 0  # a hold
    assert [c["telegram"]["step"] for c in batch.commands[1:3]] == [1, 2]  # then the steps
    _assert_served(result)


# Stop model 19: form 7's wayside identifies the brake response, as form 6's does, and its notch
# modulator times the notches by it. These standard runs of tasc-brake-controller have slow
# brakes (dead time 0.47 s, lag 0.58 s; 0.45 s, 0.60 s); on model 18, timed by the nominal
# response, they ended 0.406 m and 0.343 m short with no emergency brake.
@pytest.mark.parametrize("run", [6373, 8719])
def test_form_7_times_its_notches_by_the_identified_brake_response(run: int) -> None:
    result, _ = _standard_run(TASC_BRAKE_CONTROLLER, SignalForm.BRAKE_COMMAND, run)
    assert result.brake_delay_identified_s is not None and result.brake_lag_identified_s is not None
    assert result.brake_delay_identified_s > 0.9  # slower than the nominal 0.80 s equivalent delay
    _assert_served(result)


# Stop model 20, form 8. The end phase of the wayside's notch modulator chose only between the two
# notches either side of the target, so a train whose notch came down a step at a time from above
# the target (the braking of the higher notches still building up) could not brake less than the
# lower one however short it was going to stop. These standard runs of tasc-step ended 0.319 m
# and 0.372 m short with no emergency brake on model 19.
@pytest.mark.parametrize("run", [8573, 9478])
def test_form_8_end_phase_may_step_below_the_targets_lower_notch(run: int) -> None:
    result, _ = _standard_run(TASC_STEP, SignalForm.INCREASE_DECREASE, run)
    _assert_served(result)


# Stop model 20, form 8: a tasc-brake-controller train takes each step at its brake controller's
# next cycle, on average half a cycle after it arrives, and the wayside now allows for that wait.
# These standard runs have slow brakes (dead time 0.46 s, lag 0.59 s in run 8775); on model 19
# they ended 0.488 m, 0.351 m and 0.395 m short with no emergency brake.
@pytest.mark.parametrize("run", [8775, 1408, 8702])
def test_form_8_allows_for_the_brake_controllers_cycle(run: int) -> None:
    result, _ = _standard_run(TASC_BRAKE_CONTROLLER, SignalForm.INCREASE_DECREASE, run)
    _assert_served(result)


# Stop model 23, forms 7 and 8: with a Doppler radar the wayside's end phase aims at the stopping
# point its radar measures, not where the last command's target would stop the train. These
# standard runs ended with no emergency brake 0.31-0.43 m short on model 22 (run 6358 with
# tasc-brake-controller: slow brakes, 63 km/h on a 14 per mille downhill; stepped a notch up
# 1.1 m before the stop, where 0.3 m/s^2 was needed, and stopped 0.36 m short).
@pytest.mark.parametrize(
    ("controller", "run"),
    [
        (TASC_BRAKE_CONTROLLER, 6358),
        (TASC_BRAKE_CONTROLLER, 6373),
        (TASC_BRAKE_CONTROLLER, 9049),
        (TASC_BRAKE_CONTROLLER, 9649),
        (TASC_STEP, 3201),
        (TASC_STEP, 7748),
        (TASC_SWITCHED_PWM, 3632),
        (TASC_SWITCHED_PWM, 8719),
    ],
)
def test_form_8_end_phase_aims_at_the_measured_stopping_point(controller: str, run: int) -> None:
    result, _ = _standard_run(controller, SignalForm.INCREASE_DECREASE, run)
    _assert_served(result)
