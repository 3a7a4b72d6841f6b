"""``railstop demo``: a stop at every station with every controller, then the controllers compared."""

from __future__ import annotations

import os
import shutil
from pathlib import Path
from typing import Annotated

import typer

from railstop.cli.campaign import compare_controllers, report_command, summary_table
from railstop.cli.common import LineOpt, VehicleOpt, fail, out, styled
from railstop.cli.progress import Reporter, on_interrupt
from railstop.cli.stop import save_stop, write_plot
from railstop.controllers import CONTROLLERS
from railstop.errors import RailstopError


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
                save_stop(db, stop_record(result, line=ln, station=st, vehicle=veh))
                if label == "nominal":
                    write_plot(out_dir / f"{st.name}-{ctrl}.png".lower(), result, batch, st)
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
        rows = compare_controllers(
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
        summary_table(
            f"{demo_runs} stops per controller at {ln.stations[0].name} (standard disturbances, seed 1)", rows
        )
    )
    out.print(
        f"plots, campaigns and database written to {out_dir}/ (database: {db}); "
        f"`{report_command(compare_dir, line=line, vehicle=vehicle)}` writes the HTML report",
        highlight=False,
    )
