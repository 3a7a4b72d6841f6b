"""The single detailed stop: ``run_batch`` with n = 1 and recording on (DESIGN rule 1)."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from railstop.config.disturbances import DisturbanceSet
from railstop.config.driver import DriverFile, default_driver
from railstop.config.platform import LAMP_NAMES, PlatformFile, stop_tolerance
from railstop.config.scenario import Scenario
from railstop.config.schema import Line, Station, Vehicle
from railstop.control.supervision import eb_cause_name
from railstop.onboard.tasc_receiver import SWITCH_ONBOARD
from railstop.provenance import inputs_sha256, overrides_sha256, stamp
from railstop.quantities import KMH_PER_MPS
from railstop.sim.engine import BatchResult, run_batch
from railstop.streams import RunStreams
from railstop.wayside.tasc_unit import SignalForm

if TYPE_CHECKING:  # the store loads SQLAlchemy: only a stop that is saved needs it (--no-db)
    from railstop.store.db import StationRecord, StopRecord


@dataclass(frozen=True, slots=True, kw_only=True)
class StopResult:
    controller: str
    station: str
    line: str
    seed: int
    form: int
    load_factor: float
    brake_gain: float
    stop_error_m: float
    stop_time_s: float | None
    max_jerk_mps3: float
    notch_changes: int
    commands: int  # received by the train
    commands_sent: int
    stopped: bool
    slid: bool
    # DESIGN rule 10: why the emergency brake was applied (None: it was not), and when, from
    # the first detector (control.supervision.EB_CAUSES).
    emergency_brake: str | None = None
    emergency_brake_s: float | None = None
    # Config 2 (SPEC §1 claims 12-14): when the switching unit had changed the brake ECU's input
    # over to the onboard unit, from the first detector (None: no switching unit, or no change).
    switch_over_s: float | None = None
    # The wayside's robust loop (control.brake_ident, wayside_passage_1): the brake response it
    # identified from its radar (equivalent dead time and lag; None: not identified) and the
    # passages of missed detectors it filled in.
    brake_delay_identified_s: float | None = None
    brake_lag_identified_s: float | None = None
    detectors_filled: int = 0
    # SPEC §3 driver controllers: the error at the first standstill, the F / R corrections, the
    # lamp at the end (OK: the PSD may operate; None: no lamp) and the driver's skill level.
    first_stop_error_m: float | None = None
    restops: int = 0
    lamp: str | None = None
    driver_level: str | None = None
    # The SHA-256 of driver / platform data given in place of the embedded files (None: embedded).
    manual_data_sha256: str | None = None
    disturbances: str | None = None  # the set a campaign run was drawn from
    run: int = 0  # the run index within that campaign
    # SPEC §3 signal-open switch: the train ran through the station (stop_error_m is then where
    # its front was when the run ended, its rear past the platform) at this speed at the stopping
    # point (km/h; None: a stop).
    signal_open: bool = False
    passed_kmh: float | None = None
    psd_tolerance_m: float = 0.35  # the station's (Station.psd_tolerance_m) unless overridden
    within_tolerance: bool = False  # at rest with |stop error| <= psd_tolerance_m
    inputs_sha256: str = ""  # of the line, vehicle and disturbance data (railstop.provenance)
    # Braking-telegram frames on the air (safety layer): sent, delivered, rejected by reason.
    frames: dict[str, int] = field(default_factory=dict)
    command_log: list[dict[str, Any]] = field(default_factory=list, repr=False)

    def summary(self) -> dict[str, Any]:
        """The JSON object of ``railstop stop --json`` (without the command log)."""
        out = asdict(self)
        out.pop("command_log")
        return out

    @property
    def run_key(self) -> str:
        key = f"stop|{self.line}|{self.station}|{self.controller}|seed={self.seed}|form={self.form}"
        if self.manual_data_sha256 is not None:
            key += f"|manual-data={self.manual_data_sha256[:16]}"
        if self.disturbances is not None:
            return f"{key}|disturbances={self.disturbances}|run={self.run}"
        return f"{key}|load={self.load_factor:g}|gain={self.brake_gain:g}"


def _finite_or_none(x: float) -> float | None:
    return round(float(x), 3) if np.isfinite(x) else None


def _switch_over_s(batch: BatchResult) -> float | None:
    """When config 2's switching unit reached the onboard position, from the first detector."""
    trace, first = batch.trace, float(batch.detector_passages_s[0, 0])
    if trace is None or not np.isfinite(first):
        return None
    over = np.flatnonzero(trace.switch[:, 0] == SWITCH_ONBOARD)
    return round(float(trace.t_s[over[0], 0]) - first, 3) if over.size else None


def _passed_kmh(batch: BatchResult, station: Station) -> float | None:
    """A run through the station (signal-open switch): its speed at the stopping point (km/h;
    None when it never got there)."""
    trace = batch.trace
    if trace is None:
        return None
    x, v = trace.position_m[:, 0], trace.speed_mps[:, 0]
    ok = np.isfinite(x) & np.isfinite(v)
    x, v = x[ok], v[ok]
    if x.size == 0 or x[-1] < station.stop_point_m:
        return None
    return round(float(np.interp(station.stop_point_m, x, v)) * KMH_PER_MPS, 2)


def _manual_outcome(batch: BatchResult, driver: DriverFile | None) -> dict[str, Any]:
    """SPEC §3: what a driver controller's stop adds to the result (nothing for the others)."""
    level = int(batch.driver_level[0])
    if level < 0:
        return {}
    return {
        "first_stop_error_m": round(float(batch.first_stop_error_m[0]), 6),
        "restops": int(batch.restops[0]),
        "lamp": LAMP_NAMES.get(int(batch.lamp[0])),
        "driver_level": list((driver or default_driver()).levels)[level],
    }


def run_stop(
    *,
    line: Line,
    station: Station,
    vehicle: Vehicle,
    controller: str,
    seed: int,
    load_factor: float = 0.0,
    brake_gain: float = 1.0,
    form: SignalForm | None = None,
    disturbances: DisturbanceSet | None = None,
    run: int = 0,
    tolerance_m: float | None = None,
    driver: DriverFile | None = None,
    platform: PlatformFile | None = None,
    signal_open: bool = False,
) -> tuple[StopResult, BatchResult]:
    """One detailed stop.

    Without ``disturbances``: nominal (exact sensors, ideal link) with the load
    and brake gain given. With them: run ``run`` of the campaign of that seed,
    drawn and simulated by the very code the campaign uses. ``driver``, ``platform``: the
    driver controllers' data (None: the embedded files). ``signal_open``: the station's
    signal-open switch is on (SPEC §3, driver controllers): the train runs through.
    """
    if disturbances is None:
        scenario = Scenario.nominal(station, vehicle, load_factor=load_factor, brake_gain=brake_gain)
        batch = run_batch(
            station=station,
            vehicle=vehicle,
            scenario=scenario,
            controller=controller,
            streams=RunStreams.for_runs(seed, run, 1),
            form=form,
            record=True,
            track=line.track,
            driver=driver,
            platform=platform,
            signal_open=signal_open,
        )
    else:
        # Lazy (start-up): the campaign module brings pyarrow, which a nominal stop never needs.
        from railstop.sim.campaign import simulate_runs

        batch, drawn = simulate_runs(
            station=station,
            vehicle=vehicle,
            controller=controller,
            disturbances=disturbances,
            seed=seed,
            first_run=run,
            n=1,
            form=None if form is None else int(form),
            record=True,
            track=line.track,
            driver=driver,
            platform=platform,
            signal_open=signal_open,
        )
        load_factor = float(drawn["load_factor"][0])
        brake_gain = float(drawn["brake_gain"][0])
    stop_time = float(batch.stop_time_s[0])
    tol = stop_tolerance(station, controller, platform) if tolerance_m is None else tolerance_m
    error = round(float(batch.stop_error_m[0]), 6)
    manual = overrides_sha256(driver, platform)
    inputs = inputs_sha256(
        line.model_dump(mode="json"),
        vehicle.model_dump(mode="json"),
        None if disturbances is None else disturbances.to_dict(),
        *([] if manual is None else [manual]),
    )
    result = StopResult(
        manual_data_sha256=manual,
        switch_over_s=_switch_over_s(batch),
        brake_delay_identified_s=_finite_or_none(batch.brake_delay_identified_s[0]),
        brake_lag_identified_s=_finite_or_none(batch.brake_lag_identified_s[0]),
        detectors_filled=int(batch.detectors_filled[0]),
        **_manual_outcome(batch, driver),
        controller=controller,
        station=station.name,
        line=line.line.name,
        seed=seed,
        form=int(station.tasc.signal_form if form is None else form),
        load_factor=round(load_factor, 6),
        brake_gain=round(brake_gain, 6),
        stop_error_m=error,
        stop_time_s=round(stop_time, 3) if np.isfinite(stop_time) else None,
        max_jerk_mps3=round(float(batch.max_jerk_mps3[0]), 4),
        notch_changes=int(batch.notch_changes[0]),
        commands=int(batch.commands_received[0]),
        commands_sent=int(batch.commands_sent[0]),
        stopped=bool(batch.stopped[0]),
        slid=bool(batch.slid[0]),
        emergency_brake=eb_cause_name(int(batch.emergency_brake[0])),
        emergency_brake_s=(
            round(float(batch.emergency_brake_s[0]), 3) if np.isfinite(batch.emergency_brake_s[0]) else None
        ),
        disturbances=None if disturbances is None else disturbances.name,
        run=run,
        psd_tolerance_m=tol,
        within_tolerance=bool(batch.stopped[0]) and abs(error) <= tol,
        signal_open=signal_open,
        passed_kmh=_passed_kmh(batch, station) if signal_open else None,
        inputs_sha256=inputs,
        frames=dict(batch.link_frames),
        command_log=batch.commands,
    )
    return result, batch


def station_record(line: Line, station: Station) -> StationRecord:
    """The station as the database keeps it (SPEC §1 claim 8: stopping point, detector positions)."""
    from railstop.store.db import StationRecord  # lazy (start-up): SQLAlchemy only to write a record

    radar = station.tasc.doppler
    return StationRecord(
        line=line.line.name,
        name=station.name,
        stop_point_m=station.stop_point_m,
        platform_length_m=station.platform_length_m,
        psd_tolerance_m=station.psd_tolerance_m,
        signal_form=station.tasc.signal_form,
        detector_positions_m=station.detector_positions_m(),
        detectors_before_stop_m=list(station.tasc.detectors_before_stop_m),
        # SPEC §1 speed detection unit: the Doppler sensor beyond the stopping point (None: no radar).
        doppler_position_m=None if radar is None else station.stop_point_m + radar.beyond_stop_m,
        tasc=station.tasc.model_dump(mode="json"),
    )


def stop_record(result: StopResult, *, line: Line, station: Station, vehicle: Vehicle) -> StopRecord:
    """The database record of a stop ``run_stop`` made with this line, station and vehicle.

    SPEC §1 claim 8: the database unit keeps the stopping point, the detector positions and the
    braking data: the run's parameters hold them (with the station row's natural key, line and
    name), and the station row itself goes with the stop. Claim 20: the history of every
    computed command, with what went on the air (``BatchResult.commands``).
    """
    from railstop.store.db import StopRecord  # lazy (start-up): SQLAlchemy only to write a record

    st = station_record(line, station)
    brake = vehicle.brake
    parameters: dict[str, Any] = {
        "load_factor": result.load_factor,
        "brake_gain": result.brake_gain,
        "form": result.form,
        "disturbances": result.disturbances,
        "run": result.run,
        "psd_tolerance_m": result.psd_tolerance_m,
        **stamp(result.inputs_sha256),  # railstop version, when, the inputs' hash
        # SPEC §1 claim 8: the stopping point and the detector positions (chainages, m) ...
        "station_key": {"line": st.line, "name": st.name},
        "stop_point_m": st.stop_point_m,
        "detector_positions_m": st.detector_positions_m,
        "doppler_position_m": st.doppler_position_m,
        # ... and the braking data that decides the stop: the notch table B1..B7, full service,
        # the brake's dead time, time constant and jerk limit, the PWM map.
        "vehicle": vehicle.name,
        "brake": {**brake.model_dump(mode="json"), "full_service_mps2": brake.full_service_mps2},
    }
    return StopRecord(
        run_key=result.run_key,
        station=result.station,
        controller=result.controller,
        seed=result.seed,
        line=result.line,
        parameters=parameters,
        commands=result.command_log,  # SPEC §1 claim 20
        stop_error_m=result.stop_error_m,
        stop_time_s=result.stop_time_s,
        max_jerk_mps3=result.max_jerk_mps3,
        notch_changes=result.notch_changes,
        commands_received=result.commands,
        commands_sent=result.commands_sent,
        stopped=result.stopped,
        station_data=st,
    )
