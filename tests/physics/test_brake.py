"""The brake chain of SPEC §1: brake-line step code, PWM, ECU, actuator dynamics.

Expected values come from the SPEC table (fig. 3), from closed forms of the
first-order lag and from a brute-force sampling of pulse trains, never from
the code under test. The tests call the compiled scalar cores the stop kernel
runs (numba dispatchers are callable from Python); what the kernel does
inline (the ECU's demand, load compensation, the dead time in whole steps) is
checked on the recorded trace of detailed stops.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from railstop.config import default_line, default_vehicle
from railstop.config.scenario import Scenario
from railstop.config.schema import BrakeModel
from railstop.control.notch import MOD_SIZE
from railstop.control.tasc import HISTORY, SAMPLES, Approach, BrakeCurves, external_params
from railstop.controllers import TASC_PWM
from railstop.messages import TEL_DUTY, TEL_NOTCH, TEL_SIZE
from railstop.onboard.tasc_receiver import (
    RX_SIZE,
    receiver_init_1,
    receiver_params,
    receiver_pwm_output_1,
    receiver_receive_1,
    receiver_window,
)
from railstop.physics.brake import (
    STEP_CODE,
    actuator_step_1,
    decel_to_pwm_1,
    decode_step_1,
    encode_step_1,
    line_notch,
    or_pulse_duty,
    pwm_to_decel_1,
)
from railstop.sim.engine import DT_S, Trace, run_batch
from railstop.streams import RunStreams
from railstop.wayside.tasc_unit import SignalForm

# SPEC §1 fig. 3, copied from the SPEC: step -> wires (a, b, c); 000 = no service brake.
SPEC_FIG3 = {
    0: (0, 0, 0),
    1: (0, 0, 1),  # B1
    2: (0, 1, 0),  # B2
    3: (0, 1, 1),  # B3
    4: (1, 0, 0),  # B4
    5: (1, 0, 1),  # B5
    6: (1, 1, 0),  # B6
    7: (1, 1, 1),  # B7
}

LINE = default_line()
VEHICLE = default_vehicle()
BRAKE = VEHICLE.brake
FAST = settings(max_examples=60, deadline=None)


def _bits(a: int, b: int, c: int) -> int:
    """Wires a, b, c as the compiled encoder and decoder carry them: the bits a = 4, b = 2, c = 1."""
    return 4 * a + 2 * b + c


# --------------------------------------------------------------------------
# Step code (SPEC §1 fig. 3)


def test_step_code_table_is_spec_fig3() -> None:
    # A wrong wire pattern would make every ECU apply the wrong notch.
    assert STEP_CODE == SPEC_FIG3


def test_encode_step_gives_spec_wires() -> None:
    for n, (a, b, c) in SPEC_FIG3.items():
        assert encode_step_1(n) == _bits(a, b, c)


def test_decode_every_wire_pattern() -> None:
    # The ECU side must read every 3-bit pattern as the SPEC step.
    for n, (a, b, c) in SPEC_FIG3.items():
        assert decode_step_1(_bits(a, b, c)) == n


@pytest.mark.parametrize("notch", range(8))
def test_encode_decode_round_trip(notch: int) -> None:
    # What the stop kernel sends through the brake line: the ECU reads the notch sent.
    assert line_notch(notch) == notch


# --------------------------------------------------------------------------
# PWM map


def _map(brake: BrakeModel) -> tuple[np.ndarray, np.ndarray]:
    """The PWM map as the kernel passes it to the cores: (duties, decelerations)."""
    return np.asarray(brake.pwm_duty, dtype=np.float64), np.asarray(brake.pwm_decel_mps2, dtype=np.float64)


def _rising_part(brake: BrakeModel) -> tuple[float, float, float, float]:
    """(duty_lo, duty_hi, decel_lo, decel_hi) of the map's rising part."""
    duty, dec = brake.pwm_duty, brake.pwm_decel_mps2
    lo = max(i for i, d in enumerate(dec) if d == min(dec))
    hi = min(i for i, d in enumerate(dec) if d == max(dec))
    return duty[lo], duty[hi], dec[lo], dec[hi]


def _interp(x: float, xs: list[float], ys: list[float]) -> float:
    # Independent piecewise-linear evaluation (no numpy) of a map.
    if x <= xs[0]:
        return ys[0]
    for (x0, y0), (x1, y1) in itertools.pairwise(zip(xs, ys, strict=True)):
        if x <= x1:
            return y0 + (y1 - y0) * (x - x0) / (x1 - x0)
    return ys[-1]


@given(st.floats(0.0, 1.0))
@FAST
def test_pwm_to_decel_is_the_map(duty: float) -> None:
    got = pwm_to_decel_1(duty, *_map(BRAKE))
    assert got == pytest.approx(_interp(duty, BRAKE.pwm_duty, BRAKE.pwm_decel_mps2), abs=1e-12)


@given(st.floats(0.0, 1.0))
@FAST
def test_pwm_round_trip_duty(frac: float) -> None:
    # On the rising part the map is one-to-one: duty -> decel -> duty.
    u_lo, u_hi, _, _ = _rising_part(BRAKE)
    u = u_lo + frac * (u_hi - u_lo)
    back = decel_to_pwm_1(pwm_to_decel_1(u, *_map(BRAKE)), *_map(BRAKE))
    assert back == pytest.approx(u, abs=1e-9)


@given(st.floats(0.0, 1.0))
@FAST
def test_pwm_round_trip_decel(frac: float) -> None:
    # Any service deceleration the map can give is reproduced by its duty.
    _, _, d_lo, d_hi = _rising_part(BRAKE)
    d = d_lo + frac * (d_hi - d_lo)
    duty = decel_to_pwm_1(d, *_map(BRAKE))
    assert pwm_to_decel_1(duty, *_map(BRAKE)) == pytest.approx(d, abs=1e-9)


def test_pwm_inverse_with_plateau_in_map() -> None:
    # The schema allows a non-decreasing map (pwm_decel_mps2 "must not
    # decrease"), so a plateau in the middle is valid data. The inverse must
    # still give a duty whose deceleration is the one asked for.
    brake = BRAKE.model_copy(
        update={
            "pwm_duty": [0.0, 0.1, 0.4, 0.6, 0.9, 1.0],
            "pwm_decel_mps2": [0.0, 0.0, 0.5, 0.5, 1.0, 1.0],
        }
    )
    d = np.linspace(0.0, 1.0, 21)
    back = [pwm_to_decel_1(decel_to_pwm_1(x, *_map(brake)), *_map(brake)) for x in d]
    np.testing.assert_allclose(back, d, atol=1e-9)


# --------------------------------------------------------------------------
# PWM superposition (SPEC §1 config 3)


class _PwmReceiver:
    """The onboard receiver of a PWM train (config 3), set up as the stop kernel sets it up."""

    def __init__(self, existing_duty: float) -> None:
        station = LINE.stations[0]
        self.rp = receiver_params(TASC_PWM, int(SignalForm.BRAKE_COMMAND), VEHICLE, station, DT_S)
        self.rx = np.empty(RX_SIZE)
        self.mod = np.empty(MOD_SIZE)
        self.hist_v = np.empty(HISTORY)
        self.hist_e = np.empty(HISTORY)
        receiver_init_1(self.rx, self.mod, self.hist_v, self.hist_e)
        self.existing = existing_duty  # the train's own PWM brake signal
        self.tach = np.zeros(receiver_window(DT_S))
        self.taus = np.zeros(SAMPLES)
        self.table = np.concatenate(([0.0], np.asarray(BRAKE.notch_decel_mps2, dtype=np.float64)))
        self.det_to_stop = np.asarray(station.tasc.detectors_before_stop_m, dtype=np.float64)
        self.ext = external_params(VEHICLE, station.stop_point_m)
        self.grad = (np.zeros(0), np.zeros(1), np.zeros(1))  # level track

    def receive(self, duty: float, now_s: float) -> None:
        """A form-7 telegram (brake-system control command) carrying the onboard duty."""
        tele = np.full(TEL_SIZE, np.nan)
        tele[TEL_NOTCH] = 0.0
        tele[TEL_DUTY] = duty
        receiver_receive_1(
            self.rx,
            self.rp,
            self.mod,
            self.tach,
            self.hist_v,
            self.hist_e,
            self.taus,
            BrakeCurves(self.table, *_map(BRAKE)),
            Approach(self.det_to_stop, self.ext, self.grad),
            tele,
            now_s,
        )

    def output(self, k: int) -> float:
        """The duty the ECU sees in step ``k``."""
        return receiver_pwm_output_1(self.rx, self.rp, k, self.existing)


def _superimposed(existing: float, onboard: float) -> float:
    """The duty the ECU sees at the first zero crossing after a telegram carrying ``onboard``."""
    rx = _PwmReceiver(existing)
    rx.receive(onboard, 0.0)
    return rx.output(0)


def test_superimpose_spec_example() -> None:
    # SPEC §1: existing 50 % + onboard 70 % -> the ECU sees 70 %.
    assert _superimposed(0.5, 0.7) == pytest.approx(0.7)
    assert _superimposed(0.7, 0.5) == pytest.approx(0.7)


def test_superposition_is_latched_at_the_zero_crossing() -> None:
    # SPEC §1 config 3: the onboard pulse is synchronised to the zero crossing of the
    # existing PWM signal, so what the ECU sees changes once per carrier period.
    rx = _PwmReceiver(0.2)
    assert rx.output(0) == 0.2  # no telegram yet: the existing signal alone
    period = round(1.0 / (BRAKE.pwm_carrier_hz * DT_S))
    rx.receive(0.6, 0.0)
    assert all(rx.output(k) == 0.2 for k in range(1, period))  # until the next zero crossing
    assert rx.output(period) == pytest.approx(0.6)


def _sampled_or(d1: float, d2: float, phase: float, n: int = 10_000) -> float:
    # Brute force: sample one period at n midpoints; pulse 1 is high on
    # [0, d1), pulse 2 on [phase, phase + d2) modulo one period.
    t = (np.arange(n) + 0.5) / n
    high1 = t < d1
    high2 = np.mod(t - phase, 1.0) < d2
    return float(np.mean(high1 | high2))


duties = st.floats(0.0, 1.0)


@given(duties, duties)
@FAST
def test_or_pulse_phase_zero_is_max(d1: float, d2: float) -> None:
    # Synchronised at the zero crossing, OR of two pulses = the longer pulse.
    got = or_pulse_duty(np.array([d1]), np.array([d2]), np.array([0.0]))[0]
    assert got == pytest.approx(max(d1, d2), abs=1e-12)
    assert _superimposed(d1, d2) == pytest.approx(got, abs=1e-12)


@given(duties, duties, st.floats(-2.0, 2.0))
@FAST
def test_or_pulse_matches_sampled_union(d1: float, d2: float, phase: float) -> None:
    # Why SPEC §1 config 3 synchronises: an unsynchronised OR is longer than
    # either pulse, i.e. the ECU would brake harder than both commands.
    got = or_pulse_duty(np.array([d1]), np.array([d2]), np.array([phase]))[0]
    assert got >= max(d1, d2) - 1e-12
    assert got <= min(d1 + d2, 1.0) + 1e-12
    assert got == pytest.approx(_sampled_or(d1, d2, phase), abs=1e-3)


# --------------------------------------------------------------------------
# Actuator: dead time, jerk limiter, first-order lag

EMERGENCY = 1.3


def _run(
    demands: np.ndarray,
    *,
    dt: float,
    delay_steps: int,
    tau: float = 0.45,
    jerk: float = 1.0,
    emergency: float = EMERGENCY,
    ring_size: int | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Feed ``demands`` through one actuator; return the (limited, output) histories.

    The ring holds at least ``delay_steps + 1`` demands (the kernel sizes it for the
    longest dead time of a block, so a run's ring may be longer than its delay needs).
    """
    ring = np.zeros(delay_steps + 1 if ring_size is None else ring_size)
    lag_alpha = 1.0 - math.exp(-dt / tau)
    limited = output = 0.0
    lim = np.empty(len(demands))
    out = np.empty(len(demands))
    for k, u in enumerate(np.asarray(demands, dtype=np.float64)):
        limited, output = actuator_step_1(
            ring, k, delay_steps, float(u), limited, output, lag_alpha, jerk * dt, emergency
        )
        lim[k] = limited
        out[k] = output
    return lim, out


@pytest.mark.parametrize(("tau", "dt"), [(0.3, 0.01), (0.45, 0.01), (0.6, 0.02)])
def test_first_order_lag_time_constant(tau: float, dt: float) -> None:
    # Closed form of a first-order lag to a step u: y(t) = u (1 - e^(-t/tau));
    # after one time constant 63.2 %. Zero dead time and a jerk limit large
    # enough that the limiter passes the step at once.
    u = 1.0
    steps = round(3 * tau / dt)
    _, out = _run(np.full(steps, u), dt=dt, delay_steps=0, tau=tau, jerk=1e6)
    n_tau = round(tau / dt)
    assert out[n_tau - 1] / u == pytest.approx(1.0 - math.exp(-1.0), abs=0.01)
    assert out[n_tau - 1] / u == pytest.approx(0.632, abs=0.01)
    # And the whole response follows the closed form (output k is after k+1 steps).
    t = (np.arange(steps) + 1) * dt
    np.testing.assert_allclose(out, u * (1.0 - np.exp(-t / tau)), atol=1e-9)


@given(
    st.lists(st.integers(0, 40), min_size=1, max_size=4),
    st.integers(0, 5),
    st.lists(st.floats(0.0, 1.25), min_size=5, max_size=60),
)
@FAST
def test_dead_time_delays_by_whole_steps(
    delay_steps: list[int], spare: int, demand_values: list[float]
) -> None:
    # A pure delay of k steps: the delayed response is the undelayed one
    # shifted, and nothing happens before; whatever the ring's spare length.
    # (That the kernel takes k = round(dead time / dt) is checked on a detailed
    # stop below.)
    dt = 0.01
    steps = len(demand_values) + 50
    demand = np.zeros(steps)
    demand[: len(demand_values)] = demand_values
    lim_0, out_0 = _run(demand, dt=dt, delay_steps=0)
    for k in delay_steps:
        lim_d, out_d = _run(demand, dt=dt, delay_steps=k, ring_size=k + 1 + spare)
        assert np.all(out_d[:k] == 0.0)
        np.testing.assert_allclose(out_d[k:], out_0[: steps - k], atol=1e-12)
        np.testing.assert_allclose(lim_d[k:], lim_0[: steps - k], atol=1e-12)


@given(
    st.lists(st.floats(0.0, 1.25), min_size=2, max_size=80),
    st.floats(0.1, 5.0),
    st.sampled_from([0.005, 0.01, 0.02]),
)
@FAST
def test_jerk_limiter_bounds_rate(values: list[float], jerk: float, dt: float) -> None:
    # Comfort (SPEC §1 "non-safe braking"): below the emergency level the
    # limited demand never changes by more than jerk * dt per step.
    demand = np.repeat(np.array(values), 5)
    lim, out = _run(demand, dt=dt, delay_steps=0, jerk=jerk)
    steps = np.diff(np.concatenate(([0.0], lim)))
    assert np.all(np.abs(steps) <= jerk * dt * (1 + 1e-9) + 1e-15)
    # The lag output never leaves the range the limited demand spans.
    assert np.all(out >= -1e-12)
    assert np.all(out <= max(values) + 1e-12)


def test_jerk_limiter_reaches_held_demand() -> None:
    # A held demand is reached after demand / (jerk dt) steps, not before.
    dt, jerk, u = 0.01, 1.0, 0.8
    lim, _ = _run(np.full(200, u), dt=dt, delay_steps=0, jerk=jerk)
    ramp = np.minimum((np.arange(200) + 1) * jerk * dt, u)
    np.testing.assert_allclose(lim, ramp, atol=1e-12)


@pytest.mark.parametrize("dead_steps", [0, 7])
def test_emergency_bypasses_jerk_limiter(dead_steps: int) -> None:
    # Fail safe (DESIGN rule 7): the emergency brake is not softened by the
    # comfort limiter; it only waits for the dead time.
    dt = 0.01
    lim, _ = _run(np.full(20, EMERGENCY), dt=dt, delay_steps=dead_steps, jerk=1.0)
    assert np.all(lim[:dead_steps] == 0.0)
    assert lim[dead_steps] == pytest.approx(EMERGENCY)
    # A service demand just below emergency is rate limited (contrast).
    lim_s, _ = _run(np.full(20, EMERGENCY - 0.05), dt=dt, delay_steps=0, jerk=1.0)
    assert lim_s[0] == pytest.approx(1.0 * dt)


# --------------------------------------------------------------------------
# Brake ECU and the force it produces: what the stop kernel does inline, on
# the recorded trace of detailed stops.


def _detailed_stop(controller: str, **values: object) -> Trace:
    station = LINE.station("Riverside")
    scenario = Scenario.nominal(station, VEHICLE).with_values(**values)
    result = run_batch(
        station=station,
        vehicle=VEHICLE,
        scenario=scenario,
        controller=controller,
        streams=RunStreams.for_runs(1, 0, 1),
        record=True,
    )
    assert result.stopped[0]
    assert result.trace is not None
    return result.trace


def test_ecu_step_demand_uses_notch_table() -> None:
    # The ECU reads the notch off wires a, b, c and demands its deceleration (0 = released).
    trace = _detailed_stop("tasc-step")
    notch = trace.notch[:, 0]
    table = [0.0, *BRAKE.notch_decel_mps2]
    assert np.all((notch >= 0) & (notch <= 7))
    assert len(set(notch.tolist())) >= 3  # the stop used several notches
    np.testing.assert_array_equal(trace.demand_decel_mps2[:, 0], [table[n] for n in notch])


def test_ecu_pwm_demand_uses_map() -> None:
    trace = _detailed_stop("tasc-pwm")
    duty = trace.duty[:, 0]
    assert np.all(trace.notch[:, 0] == -1)
    assert np.ptp(duty) > 0.1  # the stop used a range of duties
    expected = [_interp(d, BRAKE.pwm_duty, BRAKE.pwm_decel_mps2) for d in duty]
    np.testing.assert_allclose(trace.demand_decel_mps2[:, 0], expected, atol=1e-12)


@pytest.mark.parametrize(
    ("load", "weighing_error", "gain", "dead_steps"),
    [(0.6, 0.08, 0.9, 23.7), (0.3, -0.05, 1.1, 23.3), (0.6, 0.0, 1.0, 20.2)],
)
def test_braking_decel_load_compensation(
    load: float, weighing_error: float, gain: float, dead_steps: float
) -> None:
    # The ECU sets force F = demand x believed mass x gain; the train decelerates at F / m.
    # The demand of every step passes the actuator (dead time rounded to whole steps,
    # jerk limit, lag) first: replayed here from the recorded demand.
    tau = BRAKE.time_constant_s
    trace = _detailed_stop(
        "tasc-pwm",
        load_factor=np.array([load]),
        load_weighing_error=np.array([weighing_error]),
        brake_gain=np.array([gain]),
        dead_time_s=np.array([dead_steps * DT_S]),
    )
    _, output = _run(
        trace.demand_decel_mps2[:, 0],
        dt=DT_S,
        delay_steps=round(dead_steps),
        tau=tau,
        jerk=BRAKE.jerk_limit_mps3,
        emergency=BRAKE.emergency_decel_mps2,
    )
    static = VEHICLE.tare_mass_kg + load * VEHICLE.crush_payload_kg
    rotating = VEHICLE.tare_mass_kg * VEHICLE.rotating_mass_factor
    believed = static * (1.0 + weighing_error) + rotating
    actual = static + rotating
    force_per_kg = output * believed * gain
    moving = slice(0, -1)  # the last step is the one the train came to a stand in
    np.testing.assert_allclose(trace.brake_decel_mps2[moving, 0], force_per_kg[moving] / actual, rtol=1e-12)
    assert np.max(output) > 0.3  # the stop braked
    if weighing_error == 0.0 and gain == 1.0:
        # With perfect weighing and a nominal brake the train gets exactly what the actuator gives.
        np.testing.assert_allclose(trace.brake_decel_mps2[moving, 0], output[moving], rtol=1e-12)
