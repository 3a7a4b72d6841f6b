"""The campaign commands: ``campaign``, ``compare``, ``certify`` and ``report`` (Monte Carlo over a
disturbance set, every controller on identical draws, a rare-event bound, the HTML report)."""

from __future__ import annotations

import json
import math
import os
import shlex
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

from railstop.cli.common import (
    DriverOpt,
    LawOpt,
    LineOpt,
    OfficeOpt,
    PlatformOpt,
    SchedulerOpt,
    VehicleOpt,
    fail,
    load_law,
    load_manual_data,
    office_target,
    out,
    send_to_office,
    styled,
    with_option_groups,
)
from railstop.cli.progress import Reporter, on_interrupt
from railstop.cli.stop import (
    DetectorsOnlyOpt,
    FormOpt,
    ToleranceOpt,
    checked_controller,
    checked_form,
    checked_tolerance,
)

# The --controller help lists the engine's controllers.
from railstop.controllers import CONTROLLERS, DRIVER_CONTROLLERS, known_controllers
from railstop.errors import RailstopError

if TYPE_CHECKING:
    from rich.console import RenderableType

    from railstop.config.disturbances import DisturbanceSet
    from railstop.config.driver import DriverFile
    from railstop.config.platform import PlatformFile
    from railstop.config.schema import Line, Station, Vehicle
    from railstop.control.law import LawFile


DisturbancesOpt = Annotated[
    str,
    typer.Option(
        help="Disturbance set: standard, wide, nominal, control-law, loss-95, outage-after-first "
        "or a TOML file."
    ),
]
# Runs per chunk by default: a chunk is the unit of resume; on a GPU it is one kernel launch, which
# needs hundreds of thousands of runs to fill the device.
CPU_CHUNK = 10_000
GPU_CHUNK = 500_000


def chunk_for(chunk_size: int | None, device: str) -> int:
    """``--chunk-size``, or the device's default."""
    if chunk_size is not None:
        return chunk_size
    return GPU_CHUNK if device == "gpu" else CPU_CHUNK


def checked_device(device: str, controllers: tuple[str, ...]) -> str:
    """``--device`` for ``controllers``: refused before any work if the device cannot run them."""
    from railstop.sim.campaign import check_device  # lazy: CLI start-up (pyarrow)

    loaded = [c for c in controllers if c not in CONTROLLERS]
    check_device(device, law_loaded=bool(loaded) and device == "gpu")
    return device


WorkersOpt = Annotated[
    int | None, typer.Option(min=1, help="Worker threads in this process (default: the CPU count).")
]
ChunkOpt = Annotated[
    int | None,
    typer.Option(
        min=1,
        help=f"Runs per chunk (results do not depend on it; default {CPU_CHUNK:,}, with --device gpu "
        f"{GPU_CHUNK:,}: one launch each).",
    ),
]
DeviceOpt = Annotated[
    str,
    typer.Option(
        help="Where the stop model runs: cpu, or gpu (an NVIDIA GPU through numba-cuda: pip install "
        "'railstop[gpu]'; results equal the CPU's within 1e-9 m, docs/gpu.md)."
    ),
]


@dataclass(frozen=True)
class ExecutionOptions:
    """Where and how a campaign's chunks run: threads, a Dask scheduler, the chunk size, the
    device (an option group of ``campaign`` and ``compare``; their results do not depend on it)."""

    workers: WorkersOpt = None
    scheduler: SchedulerOpt = None
    chunk_size: ChunkOpt = None
    device: DeviceOpt = "cpu"


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
    law: LawFile | None = None,
    device: str = "cpu",
) -> dict[str, object]:
    from railstop.config.disturbances import load_disturbances
    from railstop.sim.campaign import RUNS_FILE, CampaignSpec, finished_chunks, run_campaign
    from railstop.store import open_store

    spec_controller = checked_controller(controller)
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
        # Only a campaign of one of the file's laws records the file.
        law=law if law is not None and spec_controller not in CONTROLLERS else None,
        device=device,
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
        # Beside the figures, not in the stored summary: the set beyond the zone's layout.
        **_zone_envelope(ln.station(station), veh, spec.disturbances, out_dir / RUNS_FILE, summary),
    }


def _zone_envelope(
    st: Station, veh: Vehicle, dist: DisturbanceSet, runs_file: Path, summary: dict[str, Any]
) -> dict[str, object]:
    """``zone_note`` (:func:`~railstop.config.plausibility.envelope_note`) and, when there is one,
    how many of the campaign's runs drew beyond the zone's envelope and the share within the
    tolerance of those runs and of the others."""
    import numpy as np
    import pyarrow.parquet as pq

    from railstop.config.plausibility import beyond_envelope, envelope_note

    note = envelope_note(st, veh, dist)
    if note is None:
        return {"zone_note": None}
    cols = ["stop_error_m", "entry_speed_kmh", "approach_gradient_permille", "platform_gradient_permille"]
    t = pq.read_table(runs_file, columns=cols)
    c = {name: t.column(name).to_numpy(zero_copy_only=False).astype(np.float64) for name in cols}
    beyond = beyond_envelope(
        st, veh, c["entry_speed_kmh"], c["approach_gradient_permille"], c["platform_gradient_permille"]
    )
    within = np.abs(c["stop_error_m"]) <= float(summary["tolerance_m"])  # NaN (never stood): not

    def share(mask: Any) -> float | None:
        return round(float(within[mask].mean()), 6) if mask.any() else None

    return {
        "zone_note": note,
        "runs_beyond_zone": int(beyond.sum()),
        "within_tolerance_beyond_zone": share(beyond),
        "within_tolerance_inside_zone": share(~beyond),
    }


def print_zone_note(rows: list[dict[str, object]]) -> None:
    """The campaigns' note that the disturbance set reaches beyond the zone's layout (once), and
    per controller the runs beyond it and the shares within the tolerance."""
    noted = [r for r in rows if r.get("zone_note")]
    for note in dict.fromkeys(str(r["zone_note"]) for r in noted):
        out.print(f"note: {note} (the layout rule of `railstop check`; docs/tasc.md)", highlight=False)
    for r in noted:
        n, tol = int(r["runs_beyond_zone"]), r["tolerance_m"]  # type: ignore[call-overload]
        if n:
            out.print(
                f"  {r['controller']}: {n:,} of the {r['runs']:,} runs drew beyond the zone's envelope: "
                f"{_fmt('within', r['within_tolerance_beyond_zone'])} of them within ±{tol:g} m, "
                f"{_fmt('within', r['within_tolerance_inside_zone'])} of the others",
                highlight=False,
            )


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


def summary_table(title: str, rows: list[dict[str, object]]) -> RenderableType:
    """The campaign summary: one line per controller when the terminal is wide enough, else one
    small metric/value table per controller side by side; a number is never cut off."""
    from rich.columns import Columns
    from rich.console import Group
    from rich.measure import Measurement
    from rich.table import Table

    tols = sorted({float(t) for r in rows if isinstance(t := r.get("tolerance_m"), (int, float))})
    tol = f"{tols[0]:g}" if len(tols) == 1 else "tol"
    # The PSD tolerance each stop is judged by, and the fixed reference bands that differ from it
    # (all of them when the controllers' tolerances differ: a driver's is the platform's).
    from railstop.stats.summary import BANDS_M  # lazy: numpy and the data schemas (start-up)

    fixed = BANDS_M if len(tols) > 1 else (0.30, 0.50)
    bands = [
        (f"within_{band:.2f}".replace(".", "_"), f"±{band:.2f}")
        for band in fixed
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


@with_option_groups
def campaign(
    *,
    station: Annotated[str | None, typer.Option(help="Station name (default: the line's first).")] = None,
    controller: Annotated[
        str, typer.Option(help=f"One of: {', '.join(CONTROLLERS)}, or a law of --law.")
    ] = "tasc-pwm",
    law: LawOpt = None,
    runs: Annotated[int, typer.Option(min=1, help="Number of stops.")] = 10_000,
    seed: Annotated[int, typer.Option(help="Random seed.")] = 1,
    disturbances: DisturbancesOpt = "standard",
    execution: ExecutionOptions,
    out_dir: Annotated[
        Path | None,
        typer.Option("--out", help="Campaign folder (default: campaign-STATION-CONTROLLER-sSEED)."),
    ] = None,
    resume: Annotated[bool, typer.Option(help="Continue an interrupted campaign in --out.")] = False,
    as_json: Annotated[bool, typer.Option("--json", help="Print one JSON object.")] = False,
    db: Annotated[Path, typer.Option(help="SQLite database file (gets the summary).")] = Path("railstop.db"),
    tolerance_m: ToleranceOpt = None,
    form: FormOpt = None,
    detectors_only: DetectorsOnlyOpt = False,
    line: LineOpt = None,
    vehicle: VehicleOpt = None,
    driver: DriverOpt = None,
    platform: PlatformOpt = None,
    office: OfficeOpt = None,
) -> None:
    """Monte Carlo campaign: many stops of one controller under a disturbance set."""
    from railstop.config.loader import with_detectors_only
    from railstop.config.plausibility import load_checked

    law_file = load_law(law)
    try:
        office_to = office_target(office)  # before the work: a bad --office fails at once
        checked_device(execution.device, (controller,))
        ln, veh = load_checked(line, vehicle)
        if detectors_only:
            # The campaign's line carries the variant, so its identity (and a --resume) does too.
            ln = with_detectors_only(ln, station)
        drv, plat = load_manual_data(driver, platform, [controller])
        st = ln.station(station)
        target = out_dir or Path(f"campaign-{st.name}-{controller}-s{seed}".lower())
        if resume:
            from railstop.sim.campaign import MANIFEST  # lazy: CLI start-up (pyarrow)

            if not (target / MANIFEST).is_file():
                # --resume continues a campaign: a folder without one would silently start afresh.
                raise RailstopError(
                    f"{target}: --resume but no campaign there ({MANIFEST}); drop --resume to start one"
                )
        row = _run_one_campaign(
            ln=ln,
            veh=veh,
            station=st.name,
            controller=controller,
            runs=runs,
            seed=seed,
            disturbances=disturbances,
            workers=execution.workers,
            out_dir=target,
            resume=resume,
            chunk_size=chunk_for(execution.chunk_size, execution.device),
            db=db,
            scheduler=execution.scheduler,
            tolerance_m=checked_tolerance(tolerance_m),
            form=checked_form(form, controller),
            driver=drv,
            platform=plat,
            law=law_file,
            device=execution.device,
        )
        if office_to is not None:
            row["office_link"] = send_to_office(office_to, [("campaign-result", campaign_report(row))])
    except RailstopError as exc:
        fail(str(exc))
    except OSError as exc:
        fail(f"{exc.filename or ''}: {exc.strerror}")
    if as_json:
        print(json.dumps(row))
        return
    out.print(
        summary_table(
            f"{row['runs']} stops at {row['station']} ({row['disturbances']}, seed {seed}"
            f"{'' if form is None else f', form {form}'})",
            [row],
        )
    )
    print_zone_note([row])
    out.print(f"per-run rows: {target}/runs.parquet; summary also in {db}", highlight=False)
    if office is not None:
        out.print(f"summary sent to the office at {office} (acknowledged)", highlight=False)


def campaign_report(row: dict[str, Any]) -> dict[str, object]:
    """A campaign's summary as the office stores it (short names: a report is at most 255 bytes on
    its link): where, which controller and signal form, the draws, the share within the tolerance,
    the stop error's mean, standard deviation and p99, overruns and emergency brakes."""

    def r(v: object) -> object:
        return round(float(v), 4) if isinstance(v, int | float) and math.isfinite(float(v)) else None

    return {
        "station": row["station"],
        "controller": row["controller"],
        "form": row["form"],
        "dist": str(row["disturbances"])[:40],
        "seed": row["seed"],
        "runs": row["runs"],
        "tol": r(row["tolerance_m"]),
        "within": r(row["within_tolerance"]),
        "mean": r(row["mean_m"]),
        "std": r(row["std_m"]),
        "p99": r(row["p99_abs_m"]),
        "over": row["overruns"],
        "eb": row["emergency_brakes"],
    }


def compare_controllers(
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
    controllers: tuple[str, ...] = CONTROLLERS,
    law: LawFile | None = None,
    device: str = "cpu",
) -> list[dict[str, object]]:
    """The ``controllers`` (default: every built-in one) on identical draws (same seed, same
    disturbance set); ``driver`` and ``platform`` go to the driver controllers, ``law`` (the
    file) to its laws."""
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
            law=law,
            device=device,
        )
        for ctrl in controllers
    ]


def report_command(
    directory: Path,
    *,
    line: Path | None = None,
    vehicle: Path | None = None,
    driver: Path | None = None,
    platform: Path | None = None,
    law: Path | None = None,
    detectors_only: bool = False,
) -> str:
    """The ``railstop report`` command line for the campaigns in ``directory``, with the data
    options they ran on (the report replays their worst runs on the same data), so that it works
    as printed."""
    argv = ["railstop", "report", str(directory)]
    for option, value in (
        ("--line", line),
        ("--vehicle", vehicle),
        ("--driver", driver),
        ("--platform", platform),
        ("--law", law),
    ):
        if value is not None:
            argv += [option, str(value)]
    if detectors_only:
        argv.append("--detectors-only")
    return shlex.join(argv)


def checked_controllers(text: str | None) -> tuple[str, ...]:
    """``--controllers a,b,...`` (default: every built-in controller, then the laws of ``--law``)."""
    if text is None:
        return known_controllers()
    names = tuple(dict.fromkeys(n.strip() for n in text.split(",") if n.strip()))
    if not names:
        fail(f"--controllers: name at least one controller (got {text!r})")
    return tuple(checked_controller(name, "--controllers") for name in names)


@with_option_groups
def compare(
    *,
    station: Annotated[str | None, typer.Option(help="Station name (default: the line's first).")] = None,
    runs: Annotated[int, typer.Option(min=1, help="Stops per controller.")] = 10_000,
    seed: Annotated[int, typer.Option(help="Random seed.")] = 1,
    disturbances: DisturbancesOpt = "standard",
    execution: ExecutionOptions,
    out_dir: Annotated[
        Path | None, typer.Option("--out", help="Folder (default: compare-STATION-sSEED); one campaign each.")
    ] = None,
    resume: Annotated[bool, typer.Option(help="Continue an interrupted comparison in --out.")] = False,
    as_json: Annotated[bool, typer.Option("--json", help="Print one JSON object.")] = False,
    db: Annotated[Path, typer.Option(help="SQLite database file (gets the summaries).")] = Path(
        "railstop.db"
    ),
    tolerance_m: ToleranceOpt = None,
    form: FormOpt = None,
    detectors_only: DetectorsOnlyOpt = False,
    line: LineOpt = None,
    vehicle: VehicleOpt = None,
    driver: DriverOpt = None,
    platform: PlatformOpt = None,
    controllers: Annotated[
        str | None,
        typer.Option(
            help="Comma-separated controllers to compare (default: every one, and the laws of --law)."
        ),
    ] = None,
    law: LawOpt = None,
) -> None:
    """Run every controller (or --controllers) on identical disturbance draws and print one table."""
    from railstop.config.loader import with_detectors_only
    from railstop.config.plausibility import load_checked

    law_file = load_law(law)
    names = checked_controllers(controllers)
    try:
        checked_device(execution.device, names)
        ln, veh = load_checked(line, vehicle)
        if detectors_only:
            ln = with_detectors_only(ln, station)  # SPEC §1 claim 6, as campaign --detectors-only
        drv, plat = load_manual_data(driver, platform, names)
        st = ln.station(station)
        target = out_dir or Path(f"compare-{st.name}-s{seed}".lower())
        rows = compare_controllers(
            ln=ln,
            veh=veh,
            station=st.name,
            runs=runs,
            seed=seed,
            disturbances=disturbances,
            workers=execution.workers,
            scheduler=execution.scheduler,
            out_dir=target,
            resume=resume,
            chunk_size=chunk_for(execution.chunk_size, execution.device),
            db=db,
            tolerance_m=checked_tolerance(tolerance_m),
            form=form,
            driver=drv,
            platform=plat,
            controllers=names,
            law=law_file,
            device=execution.device,
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
        summary_table(
            f"{runs} stops per controller at {st.name} ({rows[0]['disturbances']}, seed {seed}"
            f"{'' if form is None else f', form {form}'})",
            rows,
        )
    )
    print_zone_note(rows)
    command = report_command(
        target,
        line=line,
        vehicle=vehicle,
        driver=driver,
        platform=platform,
        law=law,
        detectors_only=detectors_only,
    )
    out.print(f"campaigns in {target}/; `{command}` writes the HTML report", highlight=False)


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
        str,
        typer.Option(
            help="is: importance sampling (tuned proposal); mc: plain Monte Carlo; stratified: plain "
            "Monte Carlo in strata of the low-adhesion patch, whose probability is exact."
        ),
    ] = "is",
    hazard: Annotated[
        str,
        typer.Option(
            help="overrun: stop error > --threshold-m; platform-end: the front past the platform's end."
        ),
    ] = "overrun",
    device: DeviceOpt = "cpu",
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
    """Bound P(stop error > threshold) or P(front past the platform end): estimate and bound."""
    from railstop.config.disturbances import load_disturbances
    from railstop.config.plausibility import load_checked
    from railstop.sim.certify import CertifyError, CertifySpec, check_setting
    from railstop.sim.certify import certify as run_certify
    from railstop.sim.strata import HAZARDS, stratified_certify

    try:
        check_setting("hazard", hazard, hazard in HAZARDS, f"must be one of {', '.join(HAZARDS)}")
        check_setting("method", method, method in ("is", "mc", "stratified"), "must be is, mc or stratified")
        if device != "cpu" and method != "stratified":
            raise CertifyError("device", f"{device} runs --method stratified only (got --method {method})")
        if hazard == "platform-end" and threshold_m is not None:
            raise CertifyError("threshold_m", "the platform end sets the threshold; drop --threshold-m")
        checked_device(device, (controller,))
        ln, veh = load_checked(line, vehicle)
        st = ln.station(station)
        if hazard == "platform-end":
            # The front past the platform's end: a stop error beyond the end's distance past the
            # stopping point.
            threshold = st.platform_end - st.stop_point_m
        else:
            threshold = st.psd_tolerance_m if threshold_m is None else threshold_m
        spec = CertifySpec(
            line=ln,
            vehicle=veh,
            station=st.name,
            controller=checked_controller(controller),
            disturbances=load_disturbances(disturbances),
            threshold_m=threshold,
            seed=seed,
        )
        label = f"certify {controller} at {spec.station}"
        with Reporter(label) as status, on_interrupt(lambda: "certify keeps no partial result"):

            def progress(stage: str, done: int, total: int) -> None:
                status.stage(f"{label}, {stage}")
                status.update(done, total)

            common: dict[str, Any] = {
                "runs": runs,
                "target": target,
                "confidence": confidence,
                "workers": workers or os.cpu_count() or 1,
                "scheduler": scheduler,
                "progress": progress,
            }
            if method == "stratified":
                row = stratified_certify(spec, hazard=hazard, device=device, **common).to_dict()
            else:
                row = run_certify(
                    spec, method=method, defensive=defensive, tuning_runs=tuning_runs, **common
                ).to_dict()
                row["hazard"] = hazard
    except CertifyError as exc:
        fail(f"--{exc.setting.replace('_', '-')}: {exc.detail}")
    except RailstopError as exc:
        fail(str(exc))
    if as_json:
        print(json.dumps(row))
        return
    if method == "stratified":
        _print_strata(row)
    else:
        _print_certificate(row)


def _print_certificate(row: dict[str, Any]) -> None:
    from rich.table import Table
    from rich.text import Text

    conf = f"{100 * row['confidence']:g} %"
    table = Table(
        title=f"{_hazard_label(row)}: {row['controller']} at {row['station']} "
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


def _hazard_label(row: dict[str, Any]) -> str:
    if row.get("hazard") == "platform-end":
        return f"P(front past the platform end, stop error > {row['threshold_m']:.2f} m)"
    return f"P(stop error > {row['threshold_m']:g} m)"


def _print_strata(row: dict[str, Any]) -> None:
    from rich.table import Table
    from rich.text import Text

    conf = f"{100 * row['confidence']:g} %"
    table = Table(
        title=f"{_hazard_label(row)}: {row['controller']} at {row['station']} ({row['disturbances']}, "
        f"seed {row['seed']}, stratified, {row['device']})"
    )
    for col, justify in (("stratum", "left"), ("probability", "right"), ("runs", "right")):
        table.add_column(col, justify=justify)  # type: ignore[arg-type]
    for col in ("hits", "never stood", "largest error m", "bound (its share of δ)"):
        table.add_column(col, justify="right")
    for s in row["strata"]:
        table.add_row(
            s["stratum"],
            f"{s['weight']:g}",
            f"{s['runs']:,}",
            f"{s['hits']:,}",
            f"{s['not_stopped']:,}",
            f"{s['max_error_m']:+.3f}",
            f"{s['upper_bound']:.3e}",
        )
    out.print(table)
    out.print(
        f"estimate {row['estimate']:.3e}; {conf} upper bound {row['upper_bound']:.3e} (the strata's bounds "
        f"weighted by their exact probabilities); {row['runs']:,} runs in {row['elapsed_s']:.1f} s "
        f"({row['runs_per_s']:,.0f} runs/s)",
        highlight=False,
    )
    verdict, sign = (
        (styled("certified", "green"), "<=") if row["certified"] else (styled("not certified", "red"), ">")
    )
    out.print(
        Text.assemble(verdict, f": upper bound {row['upper_bound']:.2e} {sign} target {row['target']:.1e}")
    )


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
    law: LawOpt = None,
    detectors_only: Annotated[
        bool,
        typer.Option(
            "--detectors-only",
            help="The campaigns were run with --detectors-only (their station without its Doppler "
            "radar, SPEC §1 claim 6): replay their worst runs on that variant of the line.",
        ),
    ] = False,
    csv: Annotated[
        bool, typer.Option("--csv", help="Also write each campaign's runs as runs.csv beside runs.parquet.")
    ] = False,
    controllers: Annotated[
        str | None,
        typer.Option(
            "--controllers", help="Only these controllers' campaigns, comma-separated (default: all)."
        ),
    ] = None,
) -> None:
    """Write a self-contained HTML report (histograms, CDF, what drives the misses, worst runs)."""
    from railstop.config import load_line, load_vehicle
    from railstop.config.loader import with_detectors_only
    from railstop.report.campaign_report import export_csv, find_campaigns, write_report
    from railstop.sim.campaign import MANIFEST, law_of_manifest, read_manifest, replay_profile

    try:
        ln = load_line(line)
        veh = load_vehicle(vehicle)
        drv, plat = load_manual_data(driver, platform)
        chosen = None if controllers is None else [n.strip() for n in controllers.split(",") if n.strip()]
        if worst > 0:
            # A campaign of a loaded law replays its worst runs by that law's file: refused before
            # the first figure when it is missing (one line, nothing half drawn).
            for campaign_dir in find_campaigns(directory):
                manifest = read_manifest(campaign_dir)
                if chosen is None or manifest.get("controller") in chosen:
                    given = law if "law" in manifest else None
                    law_of_manifest(manifest, given, str(campaign_dir / MANIFEST))

        def replay(campaign_dir: Path, run: int) -> tuple[object, object]:
            manifest = read_manifest(campaign_dir)
            manual = manifest.get("manual_data_sha256") is not None
            # As campaign / compare --detectors-only: the line with the campaign's station's variant.
            line_run = with_detectors_only(ln, str(manifest.get("station"))) if detectors_only else ln
            return replay_profile(
                campaign_dir,
                run,
                line_run,
                veh,
                driver=drv if manual else None,
                platform=plat if manual else None,
                law=law if "law" in manifest else None,
            )

        with Reporter(f"report {directory}", unit="figures") as status:
            path = write_report(
                directory,
                replay=replay,  # type: ignore[arg-type]
                worst=worst,
                tolerance_m=checked_tolerance(tolerance_m),
                progress=status.update,
                controllers=chosen,
            )
        tables = export_csv(directory) if csv else []
    except RailstopError as exc:
        fail(str(exc))
    except OSError as exc:
        fail(f"{exc.filename or directory}: {exc.strerror}")
    out.print(f"report: {path}", highlight=False)
    for table in tables:
        out.print(f"runs as CSV: {table}", highlight=False)
