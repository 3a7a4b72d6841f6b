"""``railstop stop`` and ``railstop compile``: one detailed stop, and the stop model compiled once.

The options and checks the stop shares with the campaign commands (``--form``, ``--tolerance-m``,
``--controller``) live here too.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from railstop.cli.common import (
    DriverOpt,
    LawOpt,
    LineOpt,
    OfficeOpt,
    PlatformOpt,
    VehicleOpt,
    check_db_options,
    fail,
    load_law,
    load_manual_data,
    office_target,
    out,
    send_to_office,
    with_option_groups,
)

# The --controller help lists the engine's controllers; running a stop needs the engine anyway.
from railstop.controllers import (
    ATO_CONTROLLERS,
    CONTROLLERS,
    TASC_CONTROLLERS,
    is_ato_like,
    known_controllers,
)
from railstop.errors import RailstopError

if TYPE_CHECKING:
    from railstop.config.platform import PlatformFile
    from railstop.config.schema import Station, Vehicle
    from railstop.sim.dwell import DwellEvent
    from railstop.sim.engine import BatchResult
    from railstop.sim.platform_dwell import PlatformDwellResult
    from railstop.sim.single import StopResult
    from railstop.store.db import StopRecord


@dataclass(frozen=True)
class ManualOptions:
    """The options of a manually driven train's stop (SPEC §3; an option group)."""

    driver: DriverOpt = None
    platform: PlatformOpt = None
    signal_open: Annotated[
        bool,
        typer.Option(
            "--signal-open",
            help="The station's signal-open switch is on (SPEC §3; driver controllers): the train runs "
            "through without stopping, no station code, no lamp, the doors inhibited.",
        ),
    ] = False


FormOpt = Annotated[
    int | None,
    typer.Option(min=1, max=8, help="Signal form of claim 3 (default: the station's)."),
]
DetectorsOnlyOpt = Annotated[
    bool,
    typer.Option(
        "--detectors-only",
        help="The station without its Doppler radar (SPEC §1 claim 6): speed and deceleration from "
        "the detectors' passage times, on its zone's detectors_only_before_stop_m.",
    ),
]
ToleranceOpt = Annotated[
    float | None,
    typer.Option(
        "--tolerance-m",
        help="PSD tolerance to judge the stops by, 0 < m <= 2 (default: the station's psd_tolerance_m).",
    ),
]


def checked_tolerance(value: float | None) -> float | None:
    """--tolerance-m checked: a positive finite number of metres up to 2 (a stop further off than
    2 m is no 'precise stop'), or None for the station's own."""
    import math

    if value is not None and not (math.isfinite(value) and 0.0 < value <= 2.0):
        fail(f"--tolerance-m: must be more than 0 and at most 2 m (got {value})")
    return value


def checked_form(form: int | None, controller: str) -> int | None:
    """--form checked against the controller: the signal form is that of the wayside TASC's
    telegrams (SPEC §1 claim 3); an onboard ATO, a law of --law or a driver receives none, and a
    result labelled with a form it never used would be a false label."""
    if form is not None and controller not in TASC_CONTROLLERS:
        fail(
            f"--form: the signal form of the wayside TASC's telegrams (claim 3); {controller} receives "
            f"none, so it takes no --form (got {form})"
        )
    return form


def checked_controller(name: str, option: str = "--controller") -> str:
    """``name`` if it is a built-in controller or a law loaded with ``--law``."""
    known = known_controllers()
    if name not in known:
        hint = " (a law of your own: give its file with --law)" if known == CONTROLLERS else ""
        fail(f"{option}: unknown controller {name!r}; choose one of: {', '.join(known)}{hint}")
    return name


@with_option_groups
def stop(
    *,
    ctx: typer.Context,
    station: Annotated[str | None, typer.Option(help="Station name (default: the line's first).")] = None,
    controller: Annotated[
        str, typer.Option(help=f"One of: {', '.join(CONTROLLERS)}, or a law of --law.")
    ] = "tasc-pwm",
    law: LawOpt = None,
    seed: Annotated[int, typer.Option(help="Random seed.")] = 1,
    load_factor: Annotated[
        float, typer.Option(min=0.0, max=1.0, help="0 = empty (AW0) .. 1 = crush (AW3).")
    ] = 0.0,
    brake_gain: Annotated[
        float, typer.Option(min=0.5, max=1.5, help="Actual / nominal braking deceleration.")
    ] = 1.0,
    form: FormOpt = None,
    detectors_only: DetectorsOnlyOpt = False,
    disturbances: Annotated[
        str | None,
        typer.Option(
            help="Replay a campaign run drawn from this set: standard, wide, nominal, control-law, "
            "loss-95, outage-after-first or a TOML file."
        ),
    ] = None,
    run: Annotated[int, typer.Option(min=0, help="The campaign run to replay (with --disturbances).")] = 0,
    tolerance_m: ToleranceOpt = None,
    plot: Annotated[Path | None, typer.Option(help="Write a PNG plot of the stop here.")] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print one JSON object.")] = False,
    db: Annotated[Path, typer.Option(help="SQLite database file.")] = Path("railstop.db"),
    no_db: Annotated[
        bool, typer.Option("--no-db", help="Write no database (the result is only printed).")
    ] = False,
    line: LineOpt = None,
    vehicle: VehicleOpt = None,
    manual: ManualOptions,
    office: OfficeOpt = None,
) -> None:
    """Run one detailed stop: nominal (with --load-factor/--brake-gain) or run --run of a campaign."""
    from railstop.config.disturbances import load_disturbances
    from railstop.config.loader import with_detectors_only
    from railstop.config.plausibility import load_checked
    from railstop.sim.single import run_stop, stop_record
    from railstop.streams import RUN_LIMIT, SEED_RANGE, seed_in_range
    from railstop.wayside.tasc_unit import SignalForm

    load_law(law)
    if disturbances is not None and (load_factor != 0.0 or brake_gain != 1.0):
        fail("--load-factor and --brake-gain come from the draw when --disturbances is given")
    if run >= RUN_LIMIT:
        fail(f"--run: a campaign run number is below 2^63 (got {run})")
    if not seed_in_range(seed):
        fail(f"--seed: {SEED_RANGE} (got {seed})")
    if run != 0 and disturbances is None:
        fail(f"--run {run} replays a campaign run: give the campaign's --disturbances (and --seed)")
    check_db_options(ctx, no_db)
    checked_form(form, controller)
    try:
        target = office_target(office)  # before the work: a bad --office fails at once
        ln, veh = load_checked(line, vehicle)
        if detectors_only:
            ln = with_detectors_only(ln, station)
        st = ln.station(station)
        dist = None if disturbances is None else load_disturbances(disturbances)
        drv, plat = load_manual_data(manual.driver, manual.platform, [controller])
        result, batch = run_stop(
            line=ln,
            station=st,
            vehicle=veh,
            controller=checked_controller(controller),
            seed=seed,
            load_factor=load_factor,
            brake_gain=brake_gain,
            form=None if form is None else SignalForm(form),
            disturbances=dist,
            run=run,
            tolerance_m=checked_tolerance(tolerance_m),
            driver=drv,
            platform=plat,
            signal_open=manual.signal_open,
        )
        dwell = _driver_dwell(result, batch, st, plat)
        if not no_db:
            save_stop(db, stop_record(result, line=ln, station=st, vehicle=veh))
            if dwell is not None:
                # SPEC §3: the lamp and PSD timeline of the stop and its dwell.
                from railstop.store import open_store

                with open_store(db) as store:
                    store.save_dwell(key=f"{result.run_key}|platform-dwell", station=st.name, events=dwell[1])
        if plot is not None:
            plot = write_plot(plot, result, batch, st)
        sent = None if target is None else send_to_office(target, stop_reports(result, st))
    except RailstopError as exc:
        fail(str(exc))
    if as_json:
        extra: dict[str, object] = {} if dwell is None else {"platform_dwell": _dwell_json(dwell[0])}
        if sent is not None:
            extra["office_link"] = sent
        print(json.dumps({**result.summary(), **extra}))
        if not (result.stopped or result.passed_kmh is not None):
            raise typer.Exit(1)
        return
    _print_stop(result, st, veh, dwell, plot, None if no_db else db)
    if sent is not None:
        out.print(f"office: {sent['submitted']} records sent to {office} (acknowledged)", highlight=False)


def stop_reports(result: StopResult, st: Station) -> list[tuple[str, dict[str, object]]]:
    """A detailed stop as the office stores it (SPEC §1 claims 7, 20): every command the wayside
    computed, with what went on the air, then the stop's result, as the live stations send them."""
    from railstop.link.tasc_link import office_command

    reports: list[tuple[str, dict[str, object]]] = [
        ("tasc-command", office_command(st.name, 0, rec)) for rec in result.command_log
    ]
    reports.append(
        (
            "stop-result",
            {
                "station": st.name,
                "train": 0,
                "controller": result.controller,
                "error_m": round(result.stop_error_m, 3),
                "within": bool(result.within_tolerance),
                "t_s": None if result.stop_time_s is None else round(result.stop_time_s, 2),
                "seed": result.seed,
                "run": result.run,
            },
        )
    )
    return reports


def _print_stop(
    result: StopResult,
    st: Station,
    veh: Vehicle,
    dwell: tuple[PlatformDwellResult, list[DwellEvent]] | None,
    plot: Path | None,
    db: Path | None,
) -> None:
    """The stop as the terminal shows it; exit code 1 when the train did not come to a stand.
    ``db``: where the stop was saved (None: nowhere)."""
    from railstop.wayside.tasc_unit import FORM_NAMES, SignalForm

    what = (
        f"onboard {'ATO' if result.controller in ATO_CONTROLLERS else 'law of --law'}, no TASC telegrams"
        if is_ato_like(result.controller)
        else f"{result.commands} commands received (form {result.form}: "
        f"{FORM_NAMES[SignalForm(result.form)]})"
    )
    if result.driver_level is not None:
        # SPEC §3: the driver's own stop, the lamps' corrections and whether the PSD may operate.
        lamp = result.lamp or "no lamp"
        what = (
            f"{result.driver_level} driver: first stop {result.first_stop_error_m:+.3f} m, "
            f"{result.restops} re-stop(s), lamp {lamp}"
            + ("" if result.lamp == "OK" else " (PSD held closed)")
        )
    if result.switch_over_s is not None:
        what += (
            f", ECU input switched over to the onboard unit {result.switch_over_s} s after the first detector"
        )
    drawn = (
        ""
        if result.disturbances is None
        else f"run {result.run} of {result.disturbances!r} seed {result.seed} "
        f"(load {result.load_factor:.0%}, brake gain {result.brake_gain:.3f}): "
    )
    if result.passed_kmh is not None:
        # SPEC §3 signal-open switch: the train ran through the station.
        out.print(
            f"{result.controller} at {result.station}: {drawn}signal-open switch on: the train ran "
            f"through without stopping, {result.passed_kmh:.1f} km/h at the stopping point, no station "
            f"code, {result.driver_level} driver",
            highlight=False,
            soft_wrap=True,
        )
        _print_dwell_and_plot("platform", dwell, plot, db)
        return
    if not result.stopped:
        # Fail safe: a train still moving at the end of the simulated time has no stop error.
        out.print(
            f"{result.controller} at {result.station}: {drawn}the train did NOT come to a stand "
            f"within the simulated time; its front was {result.stop_error_m:+.3f} m from the stopping "
            f"point when the simulation ended, {what}",
            highlight=False,
            soft_wrap=True,
        )
        if plot is not None:
            out.print(f"plot: {plot}", highlight=False)
        raise typer.Exit(1)
    verdict = "within" if result.within_tolerance else "OUTSIDE"
    if result.emergency_brake is not None:
        # DESIGN rule 10: say first that the supervision stopped the train, and why.
        what = (
            f"EMERGENCY BRAKE ({result.emergency_brake}) {result.emergency_brake_s} s after the first "
            f"detector; {what}"
        )
    out.print(
        f"{result.controller} at {result.station}: {drawn}stop error {result.stop_error_m:+.3f} m "
        f"({'overrun' if result.stop_error_m > 0 else 'short'}, {verdict} the PSD tolerance "
        f"±{result.psd_tolerance_m:g} m), "
        f"{result.stop_time_s} s from the first detector, max jerk {result.max_jerk_mps3:.2f} m/s³, "
        f"{result.notch_changes} notch changes, {what}",
        highlight=False,
        soft_wrap=True,
    )
    wayside = []
    if result.brake_delay_identified_s is not None:
        wayside.append(
            f"brake response identified from the Doppler: equivalent dead time "
            f"{result.brake_delay_identified_s:.2f} s (radio + dead time + lag; nominal "
            f"{st.tasc.assumed_link_latency_s + veh.brake.dead_time_s + veh.brake.time_constant_s:.2f} s), "
            f"lag {result.brake_lag_identified_s:.2f} s (nominal {veh.brake.time_constant_s:.2f} s)"
        )
    if result.detectors_filled:
        wayside.append(f"{result.detectors_filled} missed detector passage(s) filled in from the Doppler")
    if wayside:
        out.print("wayside: " + "; ".join(wayside), highlight=False, soft_wrap=True)
    _print_dwell_and_plot("dwell", dwell, plot, db)


def _print_dwell_and_plot(
    label: str, dwell: tuple[PlatformDwellResult, list[DwellEvent]] | None, plot: Path | None, db: Path | None
) -> None:
    """The lines after a driver's stop or run through: its dwell (``label``: what it is) and where
    its timeline and the plot went."""
    if dwell is not None:
        from railstop.sim.platform_dwell import dwell_sentence

        saved = "" if db is None else f"; lamp and PSD timeline ({len(dwell[1])} events) saved to {db}"
        out.print(f"{label}: {dwell_sentence(dwell[0])}{saved}", highlight=False, soft_wrap=True)
    if plot is not None:
        out.print(f"plot: {plot}", highlight=False)


def _driver_dwell(
    result: StopResult, batch: BatchResult, station: Station, platform: PlatformFile | None
) -> tuple[PlatformDwellResult, list[DwellEvent]] | None:
    """SPEC §3: a driver stop that came to rest goes on into its dwell, a run through the station
    (signal-open switch) into the platform as it passes (None for the others)."""
    if result.driver_level is None or not (result.stopped or result.passed_kmh is not None):
        return None
    from railstop.config.doors import load_doors
    from railstop.config.platform import default_platform
    from railstop.sim.platform_dwell import dwell_after_stop

    doors = load_doors(None).at_station(station, "the line file")  # the station's PSD tolerance
    return dwell_after_stop(
        result, batch, station=station, platform=platform or default_platform(), doors=doors
    )


def _dwell_json(dwell: PlatformDwellResult) -> dict[str, object]:
    summary = dwell.summary()
    summary.pop("timeline")
    return summary


def save_stop(db: Path, record: StopRecord) -> None:
    """SPEC §1 claims 8, 20: the stop's record (``railstop.sim.single.stop_record``) goes to the database."""
    from railstop.store import open_store

    with open_store(db) as store:
        store.save_stop(record)


def write_plot(path: Path, result: StopResult, batch: BatchResult, station: Station) -> Path:
    from railstop.provenance import footer, stamp
    from railstop.report.plot import plot_stop

    if batch.trace is None:
        raise RailstopError("no trace was recorded")
    try:
        return plot_stop(
            batch.trace,
            run=0,
            station_name=station.name,
            stop_point_m=station.stop_point_m,
            detector_positions_m=station.detector_positions_m(),
            passage_times_s=list(batch.detector_passages_s[0]),
            commands=batch.commands,
            title=(
                f"{result.controller} at {station.name} (load {result.load_factor:.0%}, "
                f"brake gain {result.brake_gain:.2f}): "
                + (
                    f"ran through at {result.passed_kmh:.1f} km/h (signal-open switch)"
                    if result.passed_kmh is not None
                    else f"stop error {result.stop_error_m:+.3f} m"
                )
            ),
            path=path,
            tolerance_m=result.psd_tolerance_m,
            footer=footer(
                stamp(result.inputs_sha256),
                seed=result.seed,
                disturbances=result.disturbances,
                run=result.run if result.disturbances is not None else None,
                form=result.form,
            ),
        )
    except OSError as exc:
        raise RailstopError(f"cannot write plot {path}: {exc.strerror}") from None


def compile_model(
    as_json: Annotated[bool, typer.Option("--json", help="Print one JSON object.")] = False,
) -> None:
    """Compile the stop model (and the live TASC units' and the line's steps) once into the on-disk cache,
    so that later commands start at once."""
    import time

    from railstop.live.tasc import warm_up as warm_up_live
    from railstop.model.run import warm_up
    from railstop.sim.line import warm_up as warm_up_line

    t0 = time.perf_counter()
    info = warm_up()
    warm_up_live()  # the live TASC units' steps (the same compiled functions, other signatures)
    warm_up_line()  # the line's position step and positioning units
    info["seconds"] = round(time.perf_counter() - t0, 2)
    if as_json:
        print(json.dumps(info))
        return
    what = "compiled the stop model" if info["compiled"] else "the stop model was already compiled; loaded it"
    out.print(f"{what} in {info['seconds']} s; cache: {info['cache_dir']}", highlight=False)
