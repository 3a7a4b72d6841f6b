"""The ``railstop`` command.

Start-up is kept short: this module imports only what builds the command line
(typer, the consoles, the controller names its help quotes); every command
imports what it runs when it runs. ``stop --json --no-db`` thus loads the
simulation engine but not SQLAlchemy, matplotlib or pyarrow, and
``position-run`` (whose help quotes the whole-line simulation's defaults) is
built only when it is used.
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer
from typer.core import TyperCommand, TyperGroup

from railstop.cli_common import (
    DriverOpt,
    LineOpt,
    OperationOpt,
    PlatformOpt,
    SchedulerOpt,
    VehicleOpt,
    fail,
    load_manual_data,
    out,
    print_error,
    styled,
)
from railstop.cli_doors import doors_app, dwell
from railstop.cli_line import line_app
from railstop.cli_live import live_app
from railstop.cli_office import office_app
from railstop.cli_platform import platform_app
from railstop.cli_progress import Reporter, on_interrupt, run_program
from railstop.cli_telegram import telegram_app
from railstop.cli_zones import zones_app

# The --controller help lists the engine's controllers; running a stop needs the engine anyway.
from railstop.controllers import CONTROLLERS, DRIVER_CONTROLLERS
from railstop.errors import RailstopError

if TYPE_CHECKING:
    from rich.console import RenderableType
    from typer._click import Command, Context

    from railstop.config.driver import DriverFile
    from railstop.config.platform import PlatformFile
    from railstop.config.schema import Line, Station, Vehicle
    from railstop.sim.dwell import DwellEvent
    from railstop.sim.engine import BatchResult
    from railstop.sim.platform_dwell import PlatformDwellResult
    from railstop.sim.single import StopResult
    from railstop.store.db import StopRecord

_POSITION_RUN = "position-run"
_UNBUILT: Command = TyperCommand(name=_POSITION_RUN, hidden=True)


def _position_run_command() -> Command:
    """``position-run`` as a click command: imports ``railstop.sim.position_run`` for its help."""
    from railstop.cli_position import position_run

    sub = typer.Typer(add_completion=False)
    sub.command(name=_POSITION_RUN)(position_run)
    return typer.main.get_command(sub)


class _Group(TyperGroup):
    """The ``railstop`` group, with ``position-run`` built on first use (help, run or completion)."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        # A placeholder keeps the listing order (after `dwell`) and the "did you mean" suggestions.
        commands = dict(self.commands)
        self.commands = {}
        for name, command in commands.items():
            self.commands[name] = command
            if name == "dwell":
                self.commands[_POSITION_RUN] = _UNBUILT

    def get_command(self, ctx: Context, cmd_name: str) -> Command | None:
        if self.commands.get(cmd_name) is _UNBUILT:
            self.commands[cmd_name] = _position_run_command()
        return super().get_command(ctx, cmd_name)


app = typer.Typer(
    cls=_Group,
    add_completion=False,
    no_args_is_help=True,
    help="railstop: precise station stopping for urban rail (ground TASC and its simulator).",
)


def _version(value: bool) -> None:
    if value:
        from railstop import __version__

        print(f"railstop {__version__}")
        raise typer.Exit(0)


@app.callback()
def _main_options(
    version: Annotated[
        bool, typer.Option("--version", callback=_version, is_eager=True, help="Print the version and exit.")
    ] = False,
) -> None:
    """railstop: precise station stopping for urban rail (ground TASC and its simulator)."""


app.add_typer(doors_app, name="doors")
app.command()(dwell)
app.add_typer(telegram_app, name="telegram")
app.add_typer(line_app, name="line")
app.add_typer(zones_app, name="zones")
app.add_typer(platform_app, name="platform")
app.add_typer(office_app, name="office")
app.add_typer(live_app, name="live")

FormOpt = Annotated[
    int | None,
    typer.Option(min=1, max=8, help="Signal form of claim 3 (default: the station's)."),
]
ToleranceOpt = Annotated[
    float | None,
    typer.Option(
        "--tolerance-m",
        help="PSD tolerance to judge the stops by, 0 < m <= 2 (default: the station's psd_tolerance_m).",
    ),
]


def _tolerance(value: float | None) -> float | None:
    """--tolerance-m checked: a positive finite number of metres up to 2 (a stop further off than
    2 m is no 'precise stop'), or None for the station's own."""
    import math

    if value is not None and not (math.isfinite(value) and 0.0 < value <= 2.0):
        fail(f"--tolerance-m: must be more than 0 and at most 2 m (got {value})")
    return value


def _controller(name: str) -> str:
    if name not in CONTROLLERS:
        fail(f"--controller: unknown controller {name!r}; choose one of: {', '.join(CONTROLLERS)}")
    return name


@app.command()
def check(line: LineOpt = None, vehicle: VehicleOpt = None, operation: OperationOpt = None) -> None:
    """Validate a line file (and optionally a vehicle and an operation file)."""
    from railstop.config import load_line, load_vehicle
    from railstop.config.loader import line_source
    from railstop.config.operation import load_operation
    from railstop.config.plausibility import plausibility_problems

    try:
        ln = load_line(line)
        veh = load_vehicle(vehicle)
        op = load_operation(operation, ln)
    except RailstopError as exc:
        fail(str(exc))
    problems = plausibility_problems(ln, veh, line_source(line))
    if problems:  # every one, a line each
        for problem in problems[:-1]:
            print_error(str(problem))
        fail(str(problems[-1]))
    src = str(line) if line else "embedded default line"
    blocks = len(ln.signalling.blocks) if ln.signalling is not None else 0
    entry = (
        f"every {op.headway_s:g} s" if op.entries_s is None else f"at {len(op.entries_s)} timetabled times"
    )
    out.print(
        f"ok: {src}: line {ln.line.name!r}, {len(ln.stations)} stations "
        f"({', '.join(s.name for s in ln.stations)}), {len(ln.segments)} segments, {blocks} blocks; "
        f"vehicle {veh.name!r}; operation: {op.trains} trains {entry} ({op.controller})",
        highlight=False,
        soft_wrap=True,
    )


@app.command()
def stop(
    ctx: typer.Context,
    station: Annotated[str | None, typer.Option(help="Station name (default: the line's first).")] = None,
    controller: Annotated[str, typer.Option(help=f"One of: {', '.join(CONTROLLERS)}.")] = "tasc-pwm",
    seed: Annotated[int, typer.Option(help="Random seed.")] = 1,
    load_factor: Annotated[
        float, typer.Option(min=0.0, max=1.0, help="0 = empty (AW0) .. 1 = crush (AW3).")
    ] = 0.0,
    brake_gain: Annotated[
        float, typer.Option(min=0.5, max=1.5, help="Actual / nominal braking deceleration.")
    ] = 1.0,
    form: FormOpt = None,
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
    driver: DriverOpt = None,
    platform: PlatformOpt = None,
) -> None:
    """Run one detailed stop: nominal (with --load-factor/--brake-gain) or run --run of a campaign."""
    from railstop.config.disturbances import load_disturbances
    from railstop.config.plausibility import load_checked
    from railstop.controllers import ATO_CONTROLLERS
    from railstop.sim.single import run_stop, stop_record
    from railstop.streams import RUN_LIMIT, SEED_RANGE, seed_in_range
    from railstop.wayside.tasc_unit import FORM_NAMES, SignalForm

    if disturbances is not None and (load_factor != 0.0 or brake_gain != 1.0):
        fail("--load-factor and --brake-gain come from the draw when --disturbances is given")
    if run >= RUN_LIMIT:
        fail(f"--run: a campaign run number is below 2^63 (got {run})")
    if not seed_in_range(seed):
        fail(f"--seed: {SEED_RANGE} (got {seed})")
    if run != 0 and disturbances is None:
        fail(f"--run {run} replays a campaign run: give the campaign's --disturbances (and --seed)")
    source = ctx.get_parameter_source("db")
    if no_db and source is not None and source.name == "COMMANDLINE":
        fail("--db and --no-db exclude each other")
    try:
        ln, veh = load_checked(line, vehicle)
        st = ln.station(station)
        dist = None if disturbances is None else load_disturbances(disturbances)
        drv, plat = load_manual_data(driver, platform, [controller])
        result, batch = run_stop(
            line=ln,
            station=st,
            vehicle=veh,
            controller=_controller(controller),
            seed=seed,
            load_factor=load_factor,
            brake_gain=brake_gain,
            form=None if form is None else SignalForm(form),
            disturbances=dist,
            run=run,
            tolerance_m=_tolerance(tolerance_m),
            driver=drv,
            platform=plat,
        )
        dwell = _driver_dwell(result, batch, st, plat)
        if not no_db:
            _save(db, stop_record(result, line=ln, station=st, vehicle=veh))
            if dwell is not None:
                # SPEC §3: the lamp and PSD timeline of the stop and its dwell.
                from railstop.store import open_store

                with open_store(db) as store:
                    store.save_dwell(key=f"{result.run_key}|platform-dwell", station=st.name, events=dwell[1])
        if plot is not None:
            plot = _plot(plot, result, batch, st)
    except RailstopError as exc:
        fail(str(exc))
    if as_json:
        extra = {} if dwell is None else {"platform_dwell": _dwell_json(dwell[0])}
        print(json.dumps({**result.summary(), **extra}))
        if not result.stopped:
            raise typer.Exit(1)
        return
    what = (
        "onboard ATO, no TASC telegrams"
        if result.controller in ATO_CONTROLLERS
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
    if dwell is not None:
        from railstop.sim.platform_dwell import dwell_sentence

        saved = "" if no_db else f"; lamp and PSD timeline ({len(dwell[1])} events) saved to {db}"
        out.print(f"dwell: {dwell_sentence(dwell[0])}{saved}", highlight=False, soft_wrap=True)
    if plot is not None:
        out.print(f"plot: {plot}", highlight=False)


def _driver_dwell(
    result: StopResult, batch: BatchResult, station: Station, platform: PlatformFile | None
) -> tuple[PlatformDwellResult, list[DwellEvent]] | None:
    """SPEC §3: a driver stop that came to rest goes on into its dwell (None for the others)."""
    if result.driver_level is None or not result.stopped:
        return None
    from railstop.config.doors import load_doors
    from railstop.config.platform import default_platform
    from railstop.sim.platform_dwell import dwell_after_stop

    return dwell_after_stop(
        result, batch, station=station, platform=platform or default_platform(), doors=load_doors(None)
    )


def _dwell_json(dwell: PlatformDwellResult) -> dict[str, object]:
    summary = dwell.summary()
    summary.pop("timeline")
    return summary


def _save(db: Path, record: StopRecord) -> None:
    """SPEC §1 claims 8, 20: the stop's record (``railstop.sim.single.stop_record``) goes to the database."""
    from railstop.store import open_store

    with open_store(db) as store:
        store.save_stop(record)


def _plot(path: Path, result: StopResult, batch: BatchResult, station: Station) -> Path:
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
                f"brake gain {result.brake_gain:.2f}): stop error {result.stop_error_m:+.3f} m"
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


@app.command(name="compile")
def compile_model(
    as_json: Annotated[bool, typer.Option("--json", help="Print one JSON object.")] = False,
) -> None:
    """Compile the stop model (and the live TASC units' steps) once into the on-disk cache, so that later
    commands start at once."""
    import time

    from railstop.live.tasc import warm_up as warm_up_live
    from railstop.sim.kernel import warm_up

    t0 = time.perf_counter()
    info = warm_up()
    warm_up_live()  # the live TASC units' steps (the same compiled functions, other signatures)
    info["seconds"] = round(time.perf_counter() - t0, 2)
    if as_json:
        print(json.dumps(info))
        return
    what = "compiled the stop model" if info["compiled"] else "the stop model was already compiled; loaded it"
    out.print(f"{what} in {info['seconds']} s; cache: {info['cache_dir']}", highlight=False)


@app.command()
def demo(
    out_dir: Annotated[Path, typer.Option("--out", help="Folder for plots and database.")] = Path(
        "railstop-demo"
    ),
    demo_runs: Annotated[
        int, typer.Option("--runs", min=1, help="Campaign stops per controller for the closing comparison.")
    ] = 1000,
    line: LineOpt = None,
    vehicle: VehicleOpt = None,
) -> None:
    """Stop at every station with every controller, then compare the controllers on the standard set."""
    from rich.table import Table

    from railstop.config.plausibility import load_checked
    from railstop.sim.single import run_stop, stop_record

    try:
        ln, veh = load_checked(line, vehicle)
        out_dir.mkdir(parents=True, exist_ok=True)
    except RailstopError as exc:
        fail(str(exc))
    except OSError as exc:
        fail(f"cannot create {out_dir}: {exc.strerror}")
    db = out_dir / "railstop.db"
    tolerances = ", ".join(sorted({f"±{st.psd_tolerance_m:g} m" for st in ln.stations}))
    table = Table(
        title=f"Ground TASC stops on {ln.line.name} (error + = overrun; PSD tolerance {tolerances})"
    )
    for col in (
        "station",
        "controller",
        "case",
        "stop error m",
        "time s",
        "max jerk m/s³",
        "notch changes",
        "commands",
    ):
        table.add_column(
            col, no_wrap=True, justify="left" if col in ("station", "controller", "case") else "right"
        )
    cases = (("nominal", 0.0, 1.0), ("crush, brake 0.85", 1.0, 0.85))
    jobs = [(st, ctrl, case) for st in ln.stations for ctrl in CONTROLLERS for case in cases]
    try:
        with (
            Reporter(f"demo: stops on {ln.line.name}", unit="stops") as status,
            on_interrupt(lambda: f"the stops' plots and database rows so far are in {out_dir}"),
        ):
            status.update(0, len(jobs))
            for done, (st, ctrl, (label, lf, bg)) in enumerate(jobs, 1):
                result, batch = run_stop(
                    line=ln,
                    station=st,
                    vehicle=veh,
                    controller=ctrl,
                    seed=1,
                    load_factor=lf,
                    brake_gain=bg,
                )
                _save(db, stop_record(result, line=ln, station=st, vehicle=veh))
                if label == "nominal":
                    _plot(out_dir / f"{st.name}-{ctrl}.png".lower(), result, batch, st)
                err_m = result.stop_error_m
                colour = "green" if abs(err_m) <= 0.10 else ("yellow" if result.within_tolerance else "red")
                table.add_row(
                    st.name,
                    ctrl,
                    label,
                    styled(f"{err_m:+.3f}", colour),
                    f"{result.stop_time_s}",
                    f"{result.max_jerk_mps3:.2f}",
                    str(result.notch_changes),
                    str(result.commands),
                )
                status.update(done, len(jobs))
    except RailstopError as exc:
        fail(str(exc))
    out.print(table)
    # The campaign view: every controller on identical draws of the standard set.
    compare_dir = out_dir / "compare"
    shutil.rmtree(compare_dir, ignore_errors=True)  # the demo's own output: always fresh
    try:
        rows = _compare(
            ln=ln,
            veh=veh,
            station=ln.stations[0].name,
            runs=demo_runs,
            seed=1,
            disturbances="standard",
            workers=None,
            out_dir=compare_dir,
            resume=False,
            chunk_size=-(-demo_runs // (os.cpu_count() or 1)),
            db=db,
        )
    except RailstopError as exc:
        fail(str(exc))
    out.print(
        _summary_table(
            f"{demo_runs} stops per controller at {ln.stations[0].name} (standard disturbances, seed 1)", rows
        )
    )
    out.print(
        f"plots, campaigns and database written to {out_dir}/ (database: {db}); "
        f"`railstop report {compare_dir}` writes the HTML report",
        highlight=False,
    )


DisturbancesOpt = Annotated[
    str,
    typer.Option(
        help="Disturbance set: standard, wide, nominal, control-law, loss-95, outage-after-first "
        "or a TOML file."
    ),
]
WorkersOpt = Annotated[
    int | None, typer.Option(min=1, help="Worker threads in this process (default: the CPU count).")
]
ChunkOpt = Annotated[int, typer.Option(min=1, help="Runs per chunk (results do not depend on it).")]


def _run_one_campaign(
    *,
    ln: Line,
    veh: Vehicle,
    station: str,
    controller: str,
    runs: int,
    seed: int,
    disturbances: str,
    workers: int | None,
    out_dir: Path,
    resume: bool,
    chunk_size: int,
    db: Path,
    scheduler: str | None = None,
    tolerance_m: float | None = None,
    form: int | None = None,
    driver: DriverFile | None = None,
    platform: PlatformFile | None = None,
) -> dict[str, object]:
    from railstop.config.disturbances import load_disturbances
    from railstop.sim.campaign import RUNS_FILE, CampaignSpec, finished_chunks, run_campaign
    from railstop.store import open_store

    spec_controller = _controller(controller)
    spec = CampaignSpec(
        line=ln,
        vehicle=veh,
        station=ln.station(station).name,
        controller=spec_controller,
        runs=runs,
        seed=seed,
        disturbances=load_disturbances(disturbances),
        chunk_size=chunk_size,
        tolerance_m=tolerance_m,
        form=form,
        # Only a driver controller reads them: the other campaigns keep their identity.
        driver=driver if spec_controller in DRIVER_CONTROLLERS else None,
        platform=platform if spec_controller in DRIVER_CONTROLLERS else None,
    )
    n_workers = workers or os.cpu_count() or 1

    def kept() -> str:
        chunks, kept_runs = finished_chunks(spec, out_dir)
        return (
            f"{controller} at {spec.station}: {chunks} of {spec.chunks} chunks ({kept_runs:,} of "
            f"{spec.runs:,} runs) kept in {out_dir}; the same command with --resume finishes it"
        )

    with Reporter(f"{controller} at {spec.station}") as status, on_interrupt(kept):
        outcome = run_campaign(
            spec, out_dir, workers=n_workers, resume=resume, progress=status.update, scheduler=scheduler
        )
    summary = dict(outcome.summary)
    with open_store(db) as store:
        store.save_campaign(
            key=str(out_dir.resolve()),
            manifest=outcome.manifest,
            summary=summary,
            runs_file=str((out_dir / RUNS_FILE).resolve()),
        )
    return {
        "station": spec.station,
        "controller": controller,
        "form": outcome.manifest["form"],
        "seed": seed,
        "disturbances": spec.disturbances.name,
        "out": str(out_dir),
        **summary,
        "runs_simulated": outcome.runs_simulated,
        "elapsed_s": round(outcome.elapsed_s, 3),
    }


def _fmt(key: str, value: object) -> str:
    if value is None:
        return "-"
    if key.startswith(("within", "first_within")) or key in ("restopped", "aligned"):
        return f"{100.0 * float(value):.2f}%"  # type: ignore[arg-type]
    if key == "overrun_ci95_upper":
        return f"{float(value):.2e}"  # type: ignore[arg-type]
    if isinstance(value, float):
        if key == "runs_per_s":
            return f"{value:,.0f}"
        return (
            f"{value:.1f}"
            if key == "mean_stop_time_s"
            else f"{value:+.3f}"
            if key == "mean_m"
            else f"{value:.3f}"
        )
    return str(value)


def _summary_table(title: str, rows: list[dict[str, object]]) -> RenderableType:
    """The campaign summary: one line per controller when the terminal is wide enough, else one
    small metric/value table per controller side by side; a number is never cut off."""
    from rich.columns import Columns
    from rich.console import Group
    from rich.measure import Measurement
    from rich.table import Table

    tols = sorted({float(t) for r in rows if isinstance(t := r.get("tolerance_m"), (int, float))})
    tol = f"{tols[0]:g}" if len(tols) == 1 else "tol"
    # The station's PSD tolerance, and the fixed reference bands that differ from it.
    bands = [
        (f"within_{band:.2f}".replace(".", "_"), f"±{band:.2f}")
        for band in (0.30, 0.50)
        if not (len(tols) == 1 and abs(band - tols[0]) < 1e-9)
    ]
    cols = (
        ("controller", "controller"),
        ("runs", "runs"),
        ("within_tolerance", f"±{tol} PSD"),
        *bands,
        ("mean_m", "mean"),
        ("std_m", "std"),
        ("p99_abs_m", "p99|e|"),
        ("max_abs_m", "max|e|"),
        ("overruns", f">+{tol}"),
        ("overrun_ci95_upper", f"P>+{tol} ≤"),
        *(
            # SPEC §3 manual driving: the driver's own stop, the corrections, the alignment.
            (
                ("first_within_0_50", "1st ±0.50"),
                ("first_past_platform_end", "1st>end"),
                ("restopped", "re-stop"),
                ("aligned", "OK lit"),
            )
            if any("aligned" in r for r in rows)
            else ()
        ),
        ("emergency_brakes", "EB"),
        ("p99_max_jerk_mps3", "jerk99"),
        ("mean_stop_time_s", "time"),
        ("runs_per_s", "runs/s"),
    )
    caption = (
        (
            "1st ±0.50: driver's first stop within ±0.50 m; 1st>end: first stops past the platform end; "
            "re-stop: runs the driver corrected after an F / R lamp; OK lit: runs that ended aligned; "
            if any("aligned" in r for r in rows)
            else ""
        )
        + "within bands: share of runs; PSD: the station's tolerance; errors in m (+ = overrun); "
        f"P>+{tol} ≤: 95 % Clopper-Pearson upper bound on the overrun probability; EB: runs stopped by the "
        "emergency brake (supervision); jerk99: p99 of max jerk m/s³; "
        "time: mean stop time s"
    )
    table = Table(title=title, caption=caption)
    for key, label in cols:
        table.add_column(label, justify="left" if key == "controller" else "right", no_wrap=True)
    for row in rows:
        table.add_row(*(_fmt(k, row.get(k)) for k, _ in cols))
    natural = Measurement.get(out, out.options.update(max_width=100_000), table).maximum
    if natural <= out.width:
        return table
    blocks = []
    for row in rows:
        block = Table(title=str(row.get("controller")), show_header=False)
        block.add_column("metric", no_wrap=True)
        block.add_column("value", justify="right", no_wrap=True)
        for key, label in cols[1:]:
            block.add_row(label, _fmt(key, row.get(key)))
        blocks.append(block)
    return Group(title, Columns(blocks), caption)


@app.command()
def campaign(
    station: Annotated[str | None, typer.Option(help="Station name (default: the line's first).")] = None,
    controller: Annotated[str, typer.Option(help=f"One of: {', '.join(CONTROLLERS)}.")] = "tasc-pwm",
    runs: Annotated[int, typer.Option(min=1, help="Number of stops.")] = 10_000,
    seed: Annotated[int, typer.Option(help="Random seed.")] = 1,
    disturbances: DisturbancesOpt = "standard",
    workers: WorkersOpt = None,
    scheduler: SchedulerOpt = None,
    out_dir: Annotated[
        Path | None,
        typer.Option("--out", help="Campaign folder (default: campaign-STATION-CONTROLLER-sSEED)."),
    ] = None,
    resume: Annotated[bool, typer.Option(help="Continue an interrupted campaign in --out.")] = False,
    chunk_size: ChunkOpt = 10_000,
    as_json: Annotated[bool, typer.Option("--json", help="Print one JSON object.")] = False,
    db: Annotated[Path, typer.Option(help="SQLite database file (gets the summary).")] = Path("railstop.db"),
    tolerance_m: ToleranceOpt = None,
    form: FormOpt = None,
    line: LineOpt = None,
    vehicle: VehicleOpt = None,
    driver: DriverOpt = None,
    platform: PlatformOpt = None,
) -> None:
    """Monte Carlo campaign: many stops of one controller under a disturbance set."""
    from railstop.config.plausibility import load_checked

    try:
        ln, veh = load_checked(line, vehicle)
        drv, plat = load_manual_data(driver, platform, [controller])
        st = ln.station(station)
        target = out_dir or Path(f"campaign-{st.name}-{controller}-s{seed}".lower())
        row = _run_one_campaign(
            ln=ln,
            veh=veh,
            station=st.name,
            controller=controller,
            runs=runs,
            seed=seed,
            disturbances=disturbances,
            workers=workers,
            out_dir=target,
            resume=resume,
            chunk_size=chunk_size,
            db=db,
            scheduler=scheduler,
            tolerance_m=_tolerance(tolerance_m),
            form=form,
            driver=drv,
            platform=plat,
        )
    except RailstopError as exc:
        fail(str(exc))
    except OSError as exc:
        fail(f"{exc.filename or ''}: {exc.strerror}")
    if as_json:
        print(json.dumps(row))
        return
    out.print(
        _summary_table(
            f"{row['runs']} stops at {row['station']} ({row['disturbances']}, seed {seed}"
            f"{'' if form is None else f', form {form}'})",
            [row],
        )
    )
    out.print(f"per-run rows: {target}/runs.parquet; summary also in {db}", highlight=False)


def _compare(
    *,
    ln: Line,
    veh: Vehicle,
    station: str,
    runs: int,
    seed: int,
    disturbances: str,
    workers: int | None,
    scheduler: str | None = None,
    out_dir: Path,
    resume: bool,
    chunk_size: int,
    db: Path,
    tolerance_m: float | None = None,
    form: int | None = None,
    driver: DriverFile | None = None,
    platform: PlatformFile | None = None,
) -> list[dict[str, object]]:
    """Every controller on identical draws (same seed, same disturbance set); ``driver`` and
    ``platform`` go to the driver controllers."""
    return [
        _run_one_campaign(
            ln=ln,
            veh=veh,
            station=station,
            controller=ctrl,
            runs=runs,
            seed=seed,
            disturbances=disturbances,
            workers=workers,
            scheduler=scheduler,
            out_dir=out_dir / ctrl,
            resume=resume,
            chunk_size=chunk_size,
            db=db,
            tolerance_m=tolerance_m,
            form=form,
            driver=driver,
            platform=platform,
        )
        for ctrl in CONTROLLERS
    ]


@app.command()
def compare(
    station: Annotated[str | None, typer.Option(help="Station name (default: the line's first).")] = None,
    runs: Annotated[int, typer.Option(min=1, help="Stops per controller.")] = 10_000,
    seed: Annotated[int, typer.Option(help="Random seed.")] = 1,
    disturbances: DisturbancesOpt = "standard",
    workers: WorkersOpt = None,
    scheduler: SchedulerOpt = None,
    out_dir: Annotated[
        Path | None, typer.Option("--out", help="Folder (default: compare-STATION-sSEED); one campaign each.")
    ] = None,
    resume: Annotated[bool, typer.Option(help="Continue an interrupted comparison in --out.")] = False,
    chunk_size: ChunkOpt = 10_000,
    as_json: Annotated[bool, typer.Option("--json", help="Print one JSON object.")] = False,
    db: Annotated[Path, typer.Option(help="SQLite database file (gets the summaries).")] = Path(
        "railstop.db"
    ),
    tolerance_m: ToleranceOpt = None,
    form: FormOpt = None,
    line: LineOpt = None,
    vehicle: VehicleOpt = None,
    driver: DriverOpt = None,
    platform: PlatformOpt = None,
) -> None:
    """Run every controller on identical disturbance draws and print one table."""
    from railstop.config.plausibility import load_checked

    try:
        ln, veh = load_checked(line, vehicle)
        drv, plat = load_manual_data(driver, platform)
        st = ln.station(station)
        target = out_dir or Path(f"compare-{st.name}-s{seed}".lower())
        rows = _compare(
            ln=ln,
            veh=veh,
            station=st.name,
            runs=runs,
            seed=seed,
            disturbances=disturbances,
            workers=workers,
            scheduler=scheduler,
            out_dir=target,
            resume=resume,
            chunk_size=chunk_size,
            db=db,
            tolerance_m=_tolerance(tolerance_m),
            form=form,
            driver=drv,
            platform=plat,
        )
    except RailstopError as exc:
        fail(str(exc))
    except OSError as exc:
        fail(f"{exc.filename or ''}: {exc.strerror}")
    if as_json:
        print(
            json.dumps(
                {
                    "station": st.name,
                    "seed": seed,
                    "disturbances": rows[0]["disturbances"],
                    "controllers": rows,
                }
            )
        )
        return
    out.print(
        _summary_table(
            f"{runs} stops per controller at {st.name} ({rows[0]['disturbances']}, seed {seed}"
            f"{'' if form is None else f', form {form}'})",
            rows,
        )
    )
    out.print(f"campaigns in {target}/; `railstop report {target}` writes the HTML report", highlight=False)


@app.command()
def certify(
    station: Annotated[str | None, typer.Option(help="Station name (default: the line's first).")] = None,
    controller: Annotated[str, typer.Option(help=f"One of: {', '.join(CONTROLLERS)}.")] = "tasc-pwm",
    threshold_m: Annotated[
        float | None,
        typer.Option(
            "--threshold-m",
            help="A hit is a stop error above this (m, + = overrun; default: the station's PSD tolerance).",
        ),
    ] = None,
    target: Annotated[
        float, typer.Option(help="Probability to certify (the bound must be at most this).")
    ] = 1e-6,
    runs: Annotated[int, typer.Option(min=1, help="Estimation runs.")] = 1_000_000,
    method: Annotated[
        str, typer.Option(help="is: importance sampling (tuned proposal); mc: plain Monte Carlo.")
    ] = "is",
    tuning_runs: Annotated[int, typer.Option(min=100, help="Tuning runs per cross-entropy level.")] = 4_000,
    defensive: Annotated[
        float,
        typer.Option(help="Share of runs drawn from the set itself, in (0, 1] (weights <= 1/this)."),
    ] = 0.5,
    confidence: Annotated[float, typer.Option(help="Confidence of the bound and the interval.")] = 0.95,
    seed: Annotated[int, typer.Option(help="Random seed.")] = 1,
    disturbances: DisturbancesOpt = "standard",
    workers: WorkersOpt = None,
    scheduler: SchedulerOpt = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print one JSON object.")] = False,
    line: LineOpt = None,
    vehicle: VehicleOpt = None,
) -> None:
    """Bound P(stop error > threshold) by importance sampling: estimate, interval, bound."""
    from railstop.config.disturbances import load_disturbances
    from railstop.config.plausibility import load_checked
    from railstop.sim.certify import CertifyError, CertifySpec
    from railstop.sim.certify import certify as run_certify

    try:
        ln, veh = load_checked(line, vehicle)
        spec = CertifySpec(
            line=ln,
            vehicle=veh,
            station=ln.station(station).name,
            controller=_controller(controller),
            disturbances=load_disturbances(disturbances),
            threshold_m=ln.station(station).psd_tolerance_m if threshold_m is None else threshold_m,
            seed=seed,
        )
        label = f"certify {controller} at {spec.station}"
        with Reporter(label) as status, on_interrupt(lambda: "certify keeps no partial result"):

            def progress(stage: str, done: int, total: int) -> None:
                status.stage(f"{label}, {stage}")
                status.update(done, total)

            result = run_certify(
                spec,
                runs=runs,
                target=target,
                confidence=confidence,
                method=method,
                defensive=defensive,
                tuning_runs=tuning_runs,
                workers=workers or os.cpu_count() or 1,
                scheduler=scheduler,
                progress=progress,
            )
    except CertifyError as exc:
        fail(f"--{exc.setting.replace('_', '-')}: {exc.detail}")
    except RailstopError as exc:
        fail(str(exc))
    row = result.to_dict()
    if as_json:
        print(json.dumps(row))
        return
    _print_certificate(row)


def _print_certificate(row: dict[str, Any]) -> None:
    from rich.table import Table
    from rich.text import Text

    conf = f"{100 * row['confidence']:g} %"
    table = Table(
        title=f"P(stop error > {row['threshold_m']:g} m): {row['controller']} at {row['station']} "
        f"({row['disturbances']}, seed {row['seed']})"
    )
    table.add_column("", style="bold")
    table.add_column("value", justify="right")
    lo, hi = row["interval"]
    method = "importance sampling" if row["method"] == "is" else "plain Monte Carlo"
    for key, value in (
        ("method", method),
        ("estimation runs", f"{row['runs']:,}"),
        ("tuning runs", f"{row['tuning_runs']:,}"),
        ("hits", f"{row['hits']:,}"),
        ("effective sample size (hits)", f"{row['ess_hits']:.1f}"),
        ("largest weight's share", f"{row['max_weight_share']:.3f}"),
        ("weight bound", f"{row['weight_bound']:g}"),
        ("mean weight (should be 1)", f"{row['mean_weight']:.4f}"),
        ("estimate", f"{row['estimate']:.3e}"),
        (f"{conf} interval", f"{lo:.3e} .. {hi:.3e}"),
        (f"{conf} upper bound", f"{row['upper_bound']:.3e}"),
        ("target", f"{row['target']:.1e}"),
        ("wall time", f"{row['elapsed_s']:.1f} s ({row['runs_per_s']:,.0f} runs/s)"),
    ):
        table.add_row(key, value)
    out.print(table)
    verdict, sign = (
        (styled("certified", "green"), "<=") if row["certified"] else (styled("not certified", "red"), ">")
    )
    out.print(
        Text.assemble(verdict, f": upper bound {row['upper_bound']:.2e} {sign} target {row['target']:.1e}")
    )


@app.command()
def report(
    directory: Annotated[Path, typer.Argument(help="A campaign folder, or a folder of them (from compare).")],
    worst: Annotated[int, typer.Option(min=0, help="Speed profiles of the N worst runs per controller.")] = 5,
    tolerance_m: Annotated[
        float | None,
        typer.Option(
            "--tolerance-m",
            help="PSD tolerance to judge the runs by, 0 < m <= 2 (default: each campaign's station's).",
        ),
    ] = None,
    line: LineOpt = None,
    vehicle: VehicleOpt = None,
    driver: DriverOpt = None,
    platform: PlatformOpt = None,
) -> None:
    """Write a self-contained HTML report (histograms, CDF, what drives the misses, worst runs)."""
    from railstop.config import load_line, load_vehicle
    from railstop.report.campaign_report import write_report
    from railstop.sim.campaign import read_manifest, replay_profile

    try:
        ln = load_line(line)
        veh = load_vehicle(vehicle)
        drv, plat = load_manual_data(driver, platform)

        def replay(campaign_dir: Path, run: int) -> tuple[object, object]:
            manual = read_manifest(campaign_dir).get("manual_data_sha256") is not None
            return replay_profile(
                campaign_dir,
                run,
                ln,
                veh,
                driver=drv if manual else None,
                platform=plat if manual else None,
            )

        with Reporter(f"report {directory}", unit="figures") as status:
            path = write_report(
                directory,
                replay=replay,  # type: ignore[arg-type]
                worst=worst,
                tolerance_m=_tolerance(tolerance_m),
                progress=status.update,
            )
    except RailstopError as exc:
        fail(str(exc))
    except OSError as exc:
        fail(f"{exc.filename or directory}: {exc.strerror}")
    out.print(f"report: {path}", highlight=False)


@app.command()
def hazards(
    markdown: Annotated[
        Path | None,
        typer.Option("--markdown", help="Write the whole log as Markdown to this file (docs/safety/...)."),
    ] = None,
    directory: Annotated[
        Path | None,
        typer.Option("--dir", help="A folder of hazard TOML files to check (default: the embedded log)."),
    ] = None,
) -> None:
    """The hazard log: every hazard, its safety rule, the unit that enforces it and its tests."""
    from rich.table import Table

    from railstop.config.hazards import load_hazard_log
    from railstop.report.hazard_log import render_markdown

    try:
        entries = load_hazard_log(directory)
    except RailstopError as exc:
        fail(str(exc))
    if markdown is not None:
        text = render_markdown(entries)
        try:
            markdown.parent.mkdir(parents=True, exist_ok=True)
            markdown.write_text(text + "\n", encoding="utf-8")
        except OSError as exc:
            fail(f"--markdown: {exc.filename or markdown}: {exc.strerror}")
        out.print(f"hazard log: {len(entries)} hazards written to {markdown}", highlight=False)
        return
    table = Table(title=f"Hazard log ({len(entries)} hazards)", show_lines=False)
    for col in ("id", "hazard", "safe state", "unit", "tests"):
        table.add_column(col, overflow="fold")
    for e in entries:
        h = e.hazard
        table.add_row(h.id, h.title, h.safe_state, h.unit.removeprefix("railstop."), str(len(h.tests)))
    out.print(table)


def main() -> None:
    run_program(app)


if __name__ == "__main__":
    main()
