"""The Python side of the stop model: station, vehicle and controller data -> the records' arrays.

:class:`KernelModel` holds, as arrays, everything the stop needs of a
station, vehicle, controller and signal form (``KernelModel.create``);
:func:`stop_params` makes it the step's :class:`~railstop.model.records.StopParams`
record; :func:`scenario_arrays` makes a :class:`~railstop.config.scenario.Scenario`
the runs' draws (``SC_*`` columns) and gradients.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from railstop.config.driver import (
    LEVEL_PARAMETERS,
    LV_PARAMS,
    LV_WIDTH,
    DriverFile,
    default_driver,
    driver_arrays,
)
from railstop.config.platform import (
    LAMP_CODES,
    START_BEFORE_HOME_M,
    PlatformFile,
    default_platform,
    sensor_positions,
)
from railstop.config.scenario import Scenario
from railstop.config.schema import Station, Track, Vehicle
from railstop.control.brake_ident import AFTER_S as ID_AFTER_S
from railstop.control.brake_ident import BEFORE_S as ID_BEFORE_S
from railstop.control.law import ControlLaw, law_params, loaded_law
from railstop.control.tasc import external_params, start_floor_mps2
from railstop.controllers import (
    CONTROLLERS,
    DRIVER_ATC1,
    DRIVER_ATC2,
    DRIVER_ATS,
    DRIVER_UNAIDED,
    TASC_BRAKE_CONTROLLER,
    is_corrected,
    known_controllers,
)
from railstop.errors import RailstopError, SimulationError
from railstop.link.channel import airtime_s, media_preset
from railstop.link.codec import TASC_FORM_TYPES, layout_of
from railstop.link.tasc_link import CARRIED, frame_bytes
from railstop.messages import TEL_FIELDS, TEL_PASSAGE, TEL_SIZE
from railstop.model.fixes import FixesLine
from railstop.model.records import (
    CTRL_ATO,
    CTRL_ATO_CORRECTED,
    CTRL_DRIVER_ATC1,
    CTRL_DRIVER_ATC2,
    CTRL_DRIVER_ATS,
    CTRL_DRIVER_UNAIDED,
    FP_DELAY_MEAN,
    FP_DELAY_PRIOR_VAR,
    FP_DELAY_SPREAD,
    FP_DRIVER_FIXES,
    FP_FIX_VAR,
    FP_GATE_SIGMA2,
    FP_GNSS_COUNTS,
    FP_LEARN,
    FP_MAX_EXTRAPOLATION,
    FP_SCALE_PRIOR_VAR,
    FP_SIZE,
    KP_AIRTIME,
    KP_APPROACH_LIMIT,
    KP_ATC,
    KP_ATC_MARGIN,
    KP_CONTROLLER,
    KP_CRUSH,
    KP_CYCLE,
    KP_DAVIS_A,
    KP_DAVIS_B,
    KP_DAVIS_C,
    KP_DOPPLER_RANGE,
    KP_DOPPLER_REACH,
    KP_DT,
    KP_EMERGENCY,
    KP_FRAME_BITS,
    KP_GRACE,
    KP_HAS_DOPPLER,
    KP_HOME,
    KP_IN_FLIGHT,
    KP_INCAPACITATED,
    KP_INITIAL_NOTCH,
    KP_JERK,
    KP_LENGTH,
    KP_MAX_AGE,
    KP_PASS,
    KP_QUANT_AGE,
    KP_REORDER_DELAY,
    KP_REPEAT,
    KP_ROTATING,
    KP_S1,
    KP_S2,
    KP_SENSOR_NOISE,
    KP_SIZE,
    KP_SLIDE_SLIP,
    KP_START_BEFORE_HOME,
    KP_STEPS,
    KP_STOP,
    KP_TARE,
    SC_SIZE,
    SCENARIO_FIELDS,
    FloatArray,
    IntArray,
    StopParams,
)
from railstop.onboard.ato import ATO_CORRECTED_LAW, ATO_LAW, ato_params
from railstop.onboard.driver import RS_SIZE
from railstop.onboard.tasc_receiver import CONFIG_CODES, receiver_params, receiver_window
from railstop.quantities import kmh_to_mps
from railstop.wayside.tasc_unit import (
    WP_BASE_DELAY,
    WP_CONTINUOUS,
    WP_CONTINUOUS_PERIOD,
    WP_DT,
    WP_EMERGENCY,
    WP_END_MARGIN,
    WP_FILL,
    WP_FIT_SAMPLES,
    WP_FORM,
    WP_GUARD_LIMIT,
    WP_HAS_DOPPLER,
    WP_ID_AFTER,
    WP_IDENTIFY,
    WP_INITIAL_DECEL,
    WP_INITIAL_DELAY,
    WP_JERK,
    WP_LAG,
    WP_MAX_DECEL,
    WP_MOD_CYCLE,
    WP_MOD_HOLD,
    WP_MODULATE,
    WP_SIZE,
    WP_SPEED_SAMPLES,
    WP_START_FLOOR,
    WP_STEP_SPACING,
    WP_STOP,
    SignalForm,
)

CONTROLLER_CODES: dict[str, int] = {
    **CONFIG_CODES,
    "ato": CTRL_ATO,
    "ato-corrected": CTRL_ATO_CORRECTED,
    DRIVER_ATS: CTRL_DRIVER_ATS,
    DRIVER_ATC1: CTRL_DRIVER_ATC1,
    DRIVER_ATC2: CTRL_DRIVER_ATC2,
    DRIVER_UNAIDED: CTRL_DRIVER_UNAIDED,
}
# Each driver controller's approach (config.platform Approach) and supervision (True: ATC).
DRIVER_MODES: dict[str, tuple[str, bool]] = {
    DRIVER_ATS: ("ats", False),
    DRIVER_ATC1: ("atc1", True),
    DRIVER_ATC2: ("atc2", True),
    DRIVER_UNAIDED: ("unaided", False),
}


@dataclass(frozen=True, slots=True, kw_only=True)
class KernelModel:
    """Everything the kernel needs of a station, vehicle, controller and form, as arrays."""

    kp: FloatArray
    table: FloatArray
    pwm_duty: FloatArray
    pwm_decel: FloatArray
    det_pos: FloatArray
    det_to_stop: FloatArray
    transponders: FloatArray
    wp: FloatArray
    rp: FloatArray
    ap: FloatArray
    lp: NDArray[np.void]  # the stop-control law's parameters (control.law LAW_PARAMS_DTYPE)
    ext: FloatArray
    quant: FloatArray
    carried: FloatArray
    window: int
    tach_window: int
    form: SignalForm
    controller: str
    # SPEC §2 positioning of ato-corrected (one empty circuit for the other controllers).
    fp: FloatArray
    tc_ids: IntArray
    tc_starts: FloatArray
    tc_sd: FloatArray
    db_ids: IntArray
    db_starts: FloatArray
    db_sd: FloatArray
    log_len: int
    # SPEC §3 manual driving (one-row placeholders for the other controllers).
    levels: FloatArray
    rs: FloatArray
    code_pos: FloatArray
    code_lim: FloatArray
    lamp_table: FloatArray

    @classmethod
    def create(
        cls,
        *,
        station: Station,
        vehicle: Vehicle,
        controller: str,
        form: SignalForm | None,
        dt_s: float,
        max_time_s: float,
        track: Track | None = None,
        driver: DriverFile | None = None,
        platform: PlatformFile | None = None,
        incapacitated: bool = False,
        signal_open: bool = False,
    ) -> KernelModel:
        """``driver``, ``platform``: the driver controllers' data (None: the embedded defaults);
        ``incapacitated``: their driver never brakes (the supervision check of SPEC §3);
        ``signal_open``: the station's signal-open switch is on (SPEC §3): the train runs through."""
        if controller not in known_controllers():
            raise SimulationError(
                f"unknown controller {controller!r}; choose one of: {', '.join(known_controllers())}"
            )
        tasc = station.tasc
        form = SignalForm(tasc.signal_form if form is None else form)
        radar = tasc.doppler
        if radar is not None and abs(radar.sample_period_s - dt_s) > 1e-12:
            raise SimulationError(
                f"station {station.name}: tasc.doppler.sample_period_s = "
                f"{radar.sample_period_s} must equal the simulation step {dt_s} s"
            )
        try:
            medium = media_preset(tasc.medium)
        except RailstopError as exc:
            raise SimulationError(f"station {station.name}: tasc.medium: {exc}") from None
        brake = vehicle.brake
        n_bytes = frame_bytes(form, tasc.safety_category)
        kp = np.zeros(KP_SIZE)
        kp[KP_DT] = dt_s
        kp[KP_STEPS] = round(max_time_s / dt_s)
        kp[KP_CONTROLLER] = controller_code(controller)
        kp[KP_STOP] = station.stop_point_m
        kp[KP_TARE] = vehicle.tare_mass_kg
        kp[KP_CRUSH] = vehicle.crush_payload_kg
        kp[KP_ROTATING] = vehicle.rotating_mass_factor
        kp[KP_DAVIS_A] = vehicle.davis_a_n
        kp[KP_DAVIS_B] = vehicle.davis_b_n_per_mps
        kp[KP_DAVIS_C] = vehicle.davis_c_n_per_mps2
        kp[KP_LENGTH] = vehicle.length_m
        kp[KP_SLIDE_SLIP] = vehicle.slide_slip_ratio
        kp[KP_JERK] = brake.jerk_limit_mps3
        kp[KP_EMERGENCY] = brake.emergency_decel_mps2
        kp[KP_HAS_DOPPLER] = radar is not None
        kp[KP_DOPPLER_REACH] = station.stop_point_m + (radar.beyond_stop_m if radar is not None else 0.0)
        kp[KP_DOPPLER_RANGE] = radar.range_m if radar is not None else 0.0
        kp[KP_REPEAT] = tasc.repeat_period_s
        kp[KP_CYCLE] = medium.cycle_s
        kp[KP_AIRTIME] = float(airtime_s(medium, n_bytes))
        kp[KP_REORDER_DELAY] = medium.reorder_delay_s
        kp[KP_FRAME_BITS] = 8.0 * n_bytes
        kp[KP_MAX_AGE] = tasc.max_telegram_age_s
        # A frame older than the maximum age is refused, so no more than this many are in the air.
        kp[KP_IN_FLIGHT] = int(np.ceil(tasc.max_telegram_age_s / tasc.repeat_period_s)) + 2
        quant, carried, quant_age = _quantization(form)
        kp[KP_QUANT_AGE] = quant_age
        kp[KP_INITIAL_NOTCH] = tasc.initial_brake_notch
        det_to_stop = np.asarray(tasc.detectors_before_stop_m, dtype=np.float64)
        wp, window = _wayside_params(station, vehicle, form, dt_s, controller)
        rcfg = controller if controller in CONFIG_CODES else "tasc-brake-controller"
        fp, positioning = _positioning(controller, track, vehicle, dt_s)
        if signal_open and controller not in DRIVER_MODES:
            raise SimulationError(
                f"the signal-open switch is a manually driven line's (SPEC §3): a driver controller, "
                f"not {controller}"
            )
        manual: dict[str, Any] = _manual_arrays(
            kp, controller, station, vehicle, driver, platform, incapacitated, signal_open
        )
        return cls(
            **manual,
            kp=kp,
            table=np.concatenate(([0.0], np.asarray(brake.notch_decel_mps2, dtype=np.float64))),
            pwm_duty=np.asarray(brake.pwm_duty, dtype=np.float64),
            pwm_decel=np.asarray(brake.pwm_decel_mps2, dtype=np.float64),
            det_pos=station.stop_point_m - det_to_stop,
            det_to_stop=det_to_stop,
            transponders=np.asarray(station.ato_transponders_m(), dtype=np.float64),
            wp=wp,
            rp=receiver_params(rcfg, int(form), vehicle, station, dt_s),
            ap=ato_params(vehicle, station.stop_point_m, dt_s),
            lp=law_params(vehicle, dt_s),
            ext=external_params(vehicle, station.stop_point_m),
            quant=quant,
            carried=carried,
            window=window,
            tach_window=receiver_window(dt_s),
            form=form,
            controller=controller,
            fp=fp,
            **positioning,
        )

    def with_driver_fixes(self) -> KernelModel:
        """This model for a run whose driver positions the train (the line, SPEC §2): an
        ``ato-corrected`` run then takes its fixes from the driver's chain (``SteppedStop.fix``)
        instead of running its own (``model.fixes``); one position chain per train (issue 35).
        Another controller's model is returned as it is (its stop takes no fixes)."""
        if not is_corrected(self.controller):
            return self
        fp = self.fp.copy()
        fp[FP_DRIVER_FIXES] = 1.0
        return replace(self, fp=fp)


def _wayside_params(
    station: Station, vehicle: Vehicle, form: SignalForm, dt_s: float, controller: str
) -> tuple[FloatArray, int]:
    """The wayside unit's parameters (tasc_unit WP_*) and its radar buffer's length in samples;
    ``controller``: the train's (its onboard configuration is in the wayside's database)."""
    tasc, radar, brake = station.tasc, station.tasc.doppler, vehicle.brake
    wp = np.zeros(WP_SIZE)
    wp[WP_FORM] = int(form)
    wp[WP_HAS_DOPPLER] = radar is not None
    wp[WP_CONTINUOUS] = tasc.update == "continuous"
    wp[WP_CONTINUOUS_PERIOD] = tasc.continuous_period_s
    wp[WP_DT] = dt_s
    wp[WP_SPEED_SAMPLES] = max(round(radar.speed_window_s / dt_s), 2) if radar is not None else 2
    # Equivalent dead time until a new command acts (SPEC §1: "allowing for the brake's
    # dead time and lag"): radio latency + dead time + tau.
    wp[WP_BASE_DELAY] = tasc.assumed_link_latency_s + brake.dead_time_s + brake.time_constant_s
    wp[WP_JERK] = brake.jerk_limit_mps3
    wp[WP_MAX_DECEL] = brake.full_service_mps2
    wp[WP_START_FLOOR] = start_floor_mps2(brake.full_service_mps2, int(form), radar is not None)
    wp[WP_EMERGENCY] = brake.emergency_decel_mps2
    wp[WP_LAG] = brake.time_constant_s
    # Issue 13 item 6 (beyond SPEC §1): identify the brake response from the radar, a little
    # less than the radar buffer's length after the first braking command.
    # Forms 6 and 7 (stop model 19: form 7 too): with forms 1-5 the train plans its own commands
    # (the wayside's history is not what the brakes were asked for); with form 7 the brakes follow
    # the wayside's notch modulation about the command the history holds, and the identified dead
    # time and lag time the modulator's notches ([interpretation]: the response model does not
    # hold the notches' steps, only their mean; measured, forms_standard --forms 7: silent misses
    # off the patches of tasc-brake-controller 9 -> 4); form 8 moves one notch per 0.3 s, a ramp
    # the model does not hold either, and identified it missed more (3-4 -> 5-6 on the PWM and
    # step trains), so it keeps the nominal response.
    identified_forms = (SignalForm.REQUIRED_DECELERATION, SignalForm.BRAKE_COMMAND)
    wp[WP_IDENTIFY] = radar is not None and tasc.identify_brake_response and form in identified_forms
    wp[WP_ID_AFTER] = ID_AFTER_S
    wp[WP_FILL] = radar is not None and tasc.fill_missed_detectors
    wp[WP_FIT_SAMPLES] = max(round(radar.fit_window_s / dt_s), 2) if radar is not None else 2
    wp[WP_STOP] = station.stop_point_m
    wp[WP_END_MARGIN] = station.platform_end - station.stop_point_m
    wp[WP_GUARD_LIMIT] = tasc.overrun_guard_decel_fraction * brake.full_service_mps2
    # Forms 7, 8: the wayside modulates the notches as the train's brake controller would
    # (its cycle and minimum hold, brake data of the wayside's database, SPEC §1 claim 8).
    wp[WP_MODULATE] = form in (SignalForm.BRAKE_COMMAND, SignalForm.INCREASE_DECREASE)
    wp[WP_MOD_CYCLE] = brake.controller_cycle_s
    wp[WP_MOD_HOLD] = brake.controller_min_hold_s
    wp[WP_INITIAL_DECEL] = ([0.0, *brake.notch_decel_mps2])[tasc.initial_brake_notch]
    wp[WP_INITIAL_DELAY] = brake.dead_time_s + brake.time_constant_s
    wp[WP_STEP_SPACING] = brake.controller_min_hold_s
    if form == SignalForm.INCREASE_DECREASE:
        # One notch per step telegram: the braking builds up no faster than a notch's
        # deceleration per step spacing, which the plan treats as a jerk limit.
        notch_step = brake.full_service_mps2 / len(brake.notch_decel_mps2)
        wp[WP_JERK] = min(brake.jerk_limit_mps3, notch_step / wp[WP_STEP_SPACING])
        if controller == TASC_BRAKE_CONTROLLER:
            # Stop model 20: configuration 1 passes each step to the train's brake controller,
            # which takes it at its next cycle (tasc_receiver.receiver_step_output_1), on average
            # half a cycle after it arrives; configuration 2's switching unit takes it at once.
            # The wayside's modulator and plan time the steps by the delay until a step acts, so
            # they allow for that wait ([interpretation]: the wayside knows the train's brake
            # data and configuration, SPEC §1 claim 8, not the phase of its cycle, so the mean).
            # Measured, forms_standard --forms 8: tasc-brake-controller's stop errors spread
            # like tasc-step's with it (sd 0.061 m), more without (0.068 m).
            wp[WP_BASE_DELAY] += 0.5 * brake.controller_cycle_s
    # The radar buffer holds the deceleration fit's samples, and those of the identification.
    window = int(wp[WP_FIT_SAMPLES])
    if wp[WP_IDENTIFY] > 0.0:
        window = max(window, round((ID_AFTER_S + ID_BEFORE_S) / dt_s) + 1)
    return wp, window


def _positioning(
    controller: str, track: Track | None, vehicle: Vehicle, dt_s: float
) -> tuple[FloatArray, dict[str, Any]]:
    """SPEC §2 positioning of ``ato-corrected`` (FP_* and the line's circuits and balises); one
    empty circuit for the other controllers."""
    fp = np.zeros(FP_SIZE)
    no_ints = np.zeros(1, dtype=np.int64)
    no_floats = np.zeros(1)
    positioning: dict[str, Any] = {
        "tc_ids": no_ints,
        "tc_starts": no_floats,
        "tc_sd": no_floats,
        "db_ids": no_ints,
        "db_starts": no_floats,
        "db_sd": no_floats,
        "log_len": 1,
    }
    if is_corrected(controller):
        fl = FixesLine.create(track=track, vehicle=vehicle, dt_s=dt_s)
        fp[FP_DELAY_MEAN] = fl.delay_mean_s
        fp[FP_DELAY_SPREAD] = fl.delay_spread_s
        fp[FP_FIX_VAR] = fl.fix_var_m2
        fp[FP_LEARN] = fl.learn
        fp[FP_SCALE_PRIOR_VAR] = fl.scale_prior_var
        fp[FP_DELAY_PRIOR_VAR] = fl.delay_prior_var_s2
        fp[FP_MAX_EXTRAPOLATION] = fl.max_extrapolation_s
        fp[FP_GATE_SIGMA2] = fl.gate_sigma2
        fp[FP_GNSS_COUNTS] = fl.gnss_counts_per_s
        positioning = {
            "tc_ids": fl.tc_ids,
            "tc_starts": fl.tc_starts_m,
            "tc_sd": fl.tc_sd_m,
            "db_ids": fl.db_ids,
            "db_starts": fl.db_starts_m,
            "db_sd": fl.db_sd_m,
            "log_len": fl.log_len,
        }
    return fp, positioning


def _manual_arrays(
    kp: FloatArray,
    controller: str,
    station: Station,
    vehicle: Vehicle,
    driver: DriverFile | None,
    platform: PlatformFile | None,
    incapacitated: bool,
    signal_open: bool,
) -> dict[str, FloatArray]:
    """The driver controllers' arrays (SPEC §3), and their kernel parameters set in ``kp``.
    ``signal_open``: the station's signal-open switch is on."""
    if controller not in DRIVER_MODES:
        return {
            "levels": np.zeros((1, LV_PARAMS + LV_WIDTH * len(LEVEL_PARAMETERS))),
            "rs": np.zeros(RS_SIZE),
            "code_pos": np.zeros(0),
            "code_lim": np.zeros(0),
            "lamp_table": np.zeros(4),
        }
    driver = default_driver() if driver is None else driver
    platform = default_platform() if platform is None else platform
    mode, atc = DRIVER_MODES[controller]
    approach = platform.approach
    home = platform.home_signal_m(station.stop_point_m)
    codes = getattr(approach, mode).codes
    if signal_open:
        # SPEC §3: the switch lets the train pass the station (out-of-service run, skip).
        # [interpretation] It clears the station's codes and darkens its lamps: the approach limit
        # holds through the station, the driver does not stop, and the run ends when the train's
        # rear has left the platform.
        codes = []
        kp[KP_PASS] = station.platform_end + vehicle.length_m
    kp[KP_HOME] = home
    kp[KP_APPROACH_LIMIT] = kmh_to_mps(approach.approach_limit_kmh)
    kp[KP_GRACE] = approach.grace_s
    kp[KP_ATC] = atc
    kp[KP_ATC_MARGIN] = kmh_to_mps(approach.atc_permitted_margin_kmh)
    kp[KP_INCAPACITATED] = incapacitated
    kp[KP_S2], kp[KP_S1] = sensor_positions(station.stop_point_m, platform.sensors.spacing_m)
    kp[KP_SENSOR_NOISE] = platform.sensors.noise_sd_m
    kp[KP_START_BEFORE_HOME] = START_BEFORE_HOME_M
    levels, rs = driver_arrays(driver)
    lamps = platform.lamps()
    return {
        "levels": levels,
        "rs": rs,
        "code_pos": np.array([home + c.after_home_m for c in codes], dtype=np.float64),
        "code_lim": np.array([kmh_to_mps(c.limit_kmh) for c in codes], dtype=np.float64),
        "lamp_table": np.array(
            [LAMP_CODES[lamps[(s2, s1)]] for s2 in (False, True) for s1 in (False, True)], dtype=np.float64
        ),
    }


def _quantization(form: SignalForm) -> tuple[FloatArray, FloatArray, float]:
    """Counts per unit of each telegram field on the wire (0: not fixed-point), carried flags, and
    form 4's passage-age resolution: the codec layouts decide (SPEC §5 telegrams)."""
    layout = layout_of(TASC_FORM_TYPES[int(form)])
    cpu = {f.name: float(f.counts_per_unit) for f in layout.fields if f.kind == "fixed"}
    carried_names = set(CARRIED[form])
    quant = np.zeros(TEL_SIZE)
    carried = np.zeros(TEL_SIZE)
    for j, name in enumerate(TEL_FIELDS):
        carried[j] = name in carried_names or name == "detector"
        quant[j] = cpu.get(name, 0.0)
    if form == SignalForm.SPEED:
        carried[TEL_PASSAGE] = 1.0
        quant[TEL_PASSAGE] = 0.0
    return quant, carried, cpu.get("passage_age_s", 1.0)


def scenario_arrays(scenario: Scenario) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """(sc, breakpoints, gradient values, elevations at breakpoints) of a scenario."""
    sc = np.empty((scenario.n, SC_SIZE))
    for j, name in enumerate(SCENARIO_FIELDS):
        sc[:, j] = getattr(scenario, name)
    g = scenario.gradient
    n = scenario.n
    values = np.ascontiguousarray(np.broadcast_to(g.values_permille, (n, g.values_permille.shape[1])))
    elev = np.ascontiguousarray(np.broadcast_to(g._elev_at_bp, (n, g._elev_at_bp.shape[1])))
    return sc, np.ascontiguousarray(g.breakpoints_m, dtype=np.float64), values, elev


def stop_params(model: KernelModel, breakpoints_m: FloatArray) -> StopParams:
    """The step's station/line record of ``model``, on a gradient with these breakpoints."""
    return StopParams(
        kp=model.kp,
        table=model.table,
        pwm_duty=model.pwm_duty,
        pwm_decel=model.pwm_decel,
        det_pos=model.det_pos,
        det_to_stop=model.det_to_stop,
        transponders=model.transponders,
        bp=breakpoints_m,
        wp=model.wp,
        rp=model.rp,
        ap=model.ap,
        ext=model.ext,
        quant=model.quant,
        carried=model.carried,
        fp=model.fp,
        tc_ids=model.tc_ids,
        tc_starts=model.tc_starts,
        tc_sd=model.tc_sd,
        db_ids=model.db_ids,
        db_starts=model.db_starts,
        db_sd=model.db_sd,
        levels=model.levels,
        rs=model.rs,
        code_pos=model.code_pos,
        code_lim=model.code_lim,
        lamp_table=model.lamp_table,
        lp=model.lp,
    )


def compiled_law(model: KernelModel) -> Any:
    """The compiled stop-control law of ``model``'s controller (the ATO's, or a loaded one's): the
    argument ``law`` of ``simulate_block`` and ``stop_step``."""
    return control_law_of(model.controller).compiled()


def controller_code(controller: str) -> int:
    """The kernel's code of a controller (a loaded law runs as the ATO it is positioned as)."""
    if controller in CONTROLLER_CODES:
        return CONTROLLER_CODES[controller]
    return CTRL_ATO_CORRECTED if is_corrected(controller) else CTRL_ATO


def control_law_of(controller: str) -> ControlLaw:
    """The onboard stop-control law of ``controller``: the ATO's for the built-in controllers (the
    TASC and driver controllers never call it), else the law loaded under that name."""
    law = loaded_law(controller)
    if law is not None:
        return law
    if controller not in CONTROLLERS:
        raise SimulationError(f"unknown controller {controller!r}: no law of that name is loaded")
    return ATO_CORRECTED_LAW if controller == "ato-corrected" else ATO_LAW
