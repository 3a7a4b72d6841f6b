"""The ``railstop`` command."""

from __future__ import annotations

import json
import sys
from datetime import UTC, datetime
from pathlib import Path
from typing import Annotated, NoReturn

import typer
from rich.console import Console
from rich.table import Table

from railstop.config import load_line, load_vehicle
from railstop.config.schema import Station
from railstop.errors import RailstopError
from railstop.sim.engine import CONTROLLERS, BatchResult
from railstop.sim.single import StopResult, run_stop
from railstop.wayside.tasc_unit import FORM_NAMES, SignalForm

app = typer.Typer(
    add_completion=False,
    no_args_is_help=True,
    help="railstop: precise station stopping for urban rail (ground TASC and its simulator).",
)
# Wide enough for the demo table when the output is a file or a pipe.
out = Console(width=None if sys.stdout.isatty() else 140)
err = Console(stderr=True)

LineOpt = Annotated[Path | None, typer.Option("--line", help="Line TOML file (default: embedded line).")]
VehicleOpt = Annotated[
    Path | None, typer.Option("--vehicle", help="Vehicle TOML file (default: embedded EMU).")
]


def fail(message: str) -> NoReturn:
    err.print(f"[bold red]error:[/] {message}", highlight=False, soft_wrap=True)
    raise typer.Exit(2)


def _controller(name: str) -> str:
    if name not in CONTROLLERS:
        fail(f"--controller: unknown controller {name!r}; choose one of: {', '.join(CONTROLLERS)}")
    return name


@app.command()
def check(line: LineOpt = None, vehicle: VehicleOpt = None) -> None:
    """Validate a line file (and optionally a vehicle file)."""
    try:
        ln = load_line(line)
        veh = load_vehicle(vehicle)
    except RailstopError as exc:
        fail(str(exc))
    src = str(line) if line else "embedded default line"
    out.print(
        f"ok: {src}: line {ln.line.name!r}, {len(ln.stations)} stations "
        f"({', '.join(s.name for s in ln.stations)}); vehicle {veh.name!r}",
        highlight=False,
    )


@app.command()
def stop(
    station: Annotated[str | None, typer.Option(help="Station name (default: the line's first).")] = None,
    controller: Annotated[str, typer.Option(help=f"One of: {', '.join(CONTROLLERS)}.")] = "tasc-pwm",
    seed: Annotated[int, typer.Option(help="Random seed.")] = 1,
    load_factor: Annotated[
        float, typer.Option(min=0.0, max=1.0, help="0 = empty (AW0) .. 1 = crush (AW3).")
    ] = 0.0,
    brake_gain: Annotated[
        float, typer.Option(min=0.5, max=1.5, help="Actual / nominal braking deceleration.")
    ] = 1.0,
    form: Annotated[
        int | None,
        typer.Option(min=1, max=8, help="Signal form of claim 3 (default: the station's)."),
    ] = None,
    plot: Annotated[Path | None, typer.Option(help="Write a PNG plot of the stop here.")] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print one JSON object.")] = False,
    db: Annotated[Path, typer.Option(help="SQLite database file.")] = Path("railstop.db"),
    line: LineOpt = None,
    vehicle: VehicleOpt = None,
) -> None:
    """Run one detailed ground-TASC stop (nominal unless --load-factor/--brake-gain)."""
    try:
        ln = load_line(line)
        veh = load_vehicle(vehicle)
        st = ln.station(station)
        result, batch = run_stop(
            line=ln,
            station=st,
            vehicle=veh,
            controller=_controller(controller),
            seed=seed,
            load_factor=load_factor,
            brake_gain=brake_gain,
            form=None if form is None else SignalForm(form),
        )
        _save(db, result)
        if plot is not None:
            _plot(plot, result, batch, st)
    except RailstopError as exc:
        fail(str(exc))
    if as_json:
        print(json.dumps(result.summary()))
        return
    out.print(
        f"{result.controller} at {result.station}: stop error {result.stop_error_m:+.3f} m "
        f"({'overrun' if result.stop_error_m > 0 else 'short'}), "
        f"{result.stop_time_s} s from the first detector, max jerk {result.max_jerk_mps3:.2f} m/s³, "
        f"{result.notch_changes} notch changes, {result.commands} commands received "
        f"(form {result.form}: {FORM_NAMES[SignalForm(result.form)]})",
        highlight=False,
    )
    if plot is not None:
        out.print(f"plot: {plot}", highlight=False)


def _save(db: Path, result: StopResult) -> None:
    """SPEC §1 claims 8, 20: every computed command and its inputs go to the database."""
    from railstop.store import StopRecord, open_store

    record = StopRecord(
        run_key=result.run_key,
        station=result.station,
        controller=result.controller,
        seed=result.seed,
        line=result.line,
        parameters={
            "load_factor": result.load_factor,
            "brake_gain": result.brake_gain,
            "form": result.form,
        },
        commands=result.command_log,
        stop_error_m=result.stop_error_m,
        stop_time_s=result.stop_time_s,
        max_jerk_mps3=result.max_jerk_mps3,
        notch_changes=result.notch_changes,
        commands_received=result.commands,
        commands_sent=result.commands_sent,
        stopped=result.stopped,
        created_utc=datetime.now(UTC).isoformat(timespec="seconds"),
    )
    with open_store(db) as store:
        store.save_stop(record)


def _plot(path: Path, result: StopResult, batch: BatchResult, station: Station) -> None:
    from railstop.report.plot import plot_stop

    if batch.trace is None:
        raise RailstopError("no trace was recorded")
    try:
        plot_stop(
            batch.trace,
            run=0,
            station_name=station.name,
            stop_point_m=station.stop_point_m,
            detector_positions_m=station.detector_positions_m(),
            passage_times_s=list(batch.detector_passages_s[0]),
            commands=batch.commands,
            title=(
                f"{result.controller} at {station.name} (load {result.load_factor:g}, "
                f"brake gain {result.brake_gain:g}): stop error {result.stop_error_m:+.3f} m"
            ),
            path=path,
        )
    except OSError as exc:
        raise RailstopError(f"cannot write plot {path}: {exc.strerror}") from None


@app.command()
def demo(
    out_dir: Annotated[Path, typer.Option("--out", help="Folder for plots and database.")] = Path(
        "railstop-demo"
    ),
    line: LineOpt = None,
    vehicle: VehicleOpt = None,
) -> None:
    """Stop at every station of the line with every controller; print a table."""
    try:
        ln = load_line(line)
        veh = load_vehicle(vehicle)
        out_dir.mkdir(parents=True, exist_ok=True)
    except RailstopError as exc:
        fail(str(exc))
    except OSError as exc:
        fail(f"cannot create {out_dir}: {exc.strerror}")
    db = out_dir / "railstop.db"
    table = Table(title=f"Ground TASC stops on {ln.line.name} (error + = overrun; PSD tolerance ±0.35 m)")
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
    try:
        for st in ln.stations:
            for ctrl in CONTROLLERS:
                for label, lf, bg in cases:
                    result, batch = run_stop(
                        line=ln,
                        station=st,
                        vehicle=veh,
                        controller=ctrl,
                        seed=1,
                        load_factor=lf,
                        brake_gain=bg,
                    )
                    _save(db, result)
                    if label == "nominal":
                        _plot(out_dir / f"{st.name}-{ctrl}.png".lower(), result, batch, st)
                    err_m = result.stop_error_m
                    colour = "green" if abs(err_m) <= 0.10 else ("yellow" if abs(err_m) <= 0.35 else "red")
                    table.add_row(
                        st.name,
                        ctrl,
                        label,
                        f"[{colour}]{err_m:+.3f}[/]",
                        f"{result.stop_time_s}",
                        f"{result.max_jerk_mps3:.2f}",
                        str(result.notch_changes),
                        str(result.commands),
                    )
    except RailstopError as exc:
        fail(str(exc))
    out.print(table)
    out.print(f"plots and database written to {out_dir}/ (database: {db})", highlight=False)


def main() -> None:
    try:
        app()
    except KeyboardInterrupt:
        err.print("interrupted")
        sys.exit(130)


if __name__ == "__main__":
    main()
