"""``railstop line run``: many trains on the line, one clock (issue 14)."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

from railstop.cli.common import (
    LawOpt,
    LineOpt,
    OfficeOpt,
    OperationOpt,
    SchedulerOpt,
    VehicleOpt,
    command_group,
    fail,
    load_law,
    office_target,
    send_to_office,
    with_option_groups,
)
from railstop.cli.common import out as console
from railstop.errors import ConfigError, RailstopError

if TYPE_CHECKING:
    from railstop.config.operation import Operation
    from railstop.config.schema import Line
    from railstop.sim.line import LineResult, LineSettings

TrainsOpt = Annotated[int | None, typer.Option(min=1, max=200, help="Trains (default: the operation's).")]
DoorLinkLossOpt = Annotated[
    float | None,
    typer.Option(
        min=0.0,
        max=1.0,
        help="The platform door link's loss per frame, both ways (default: the medium's; 1 = dead link).",
    ),
]
OdometerErrorOpt = Annotated[
    float | None,
    typer.Option(
        min=-20.0,
        max=20.0,
        help="Every train's odometer diameter error, % (default: each train's draw of the set).",
    ),
]
SlideOpt = Annotated[
    float,
    typer.Option(
        min=0.0,
        max=1.0,
        help="Chance per train and station of a low-adhesion patch where the ATO brakes (slides).",
    ),
]
CalibrationOpt = Annotated[
    str,
    typer.Option(
        help="Onboard positioning at entry: carried (the scale and delay of earlier trips) or cold."
    ),
]
SignallingOpt = Annotated[
    str,
    typer.Option(
        help="fixed-block (signals over the blocks), cbtc (SPEC §4 moving block, minimal protection "
        "zones) or cbtc-conventional (the same, zones of whole blocks)."
    ),
]
FaultsOpt = Annotated[
    Path | None,
    typer.Option(
        help="Faults TOML: [[radio_outage]] train, start_s, duration_s; [random_outages]; [[zc_restart]] at_s"
    ),
]
RegulationOpt = Annotated[
    bool,
    typer.Option(
        help="With cbtc: the ATS holds a train at its platform (or the entry) rather than let it stand "
        "before the next platform while that is occupied (beyond SPEC §4)."
    ),
]
HeadwayOpt = Annotated[
    float | None,
    typer.Option(min=30.0, max=3600.0, help="Seconds between entries (default: the operation's)."),
]


@dataclass(frozen=True)
class LineOptions:
    """The options of ``line run`` and ``line campaign`` that set the line's door link, positioning,
    slides, signalling and faults (an option group: one definition for both commands)."""

    door_link_loss: DoorLinkLossOpt = None
    odometer_error_pct: OdometerErrorOpt = None
    slide_probability: SlideOpt = 0.0
    calibration: CalibrationOpt = "carried"
    signalling: SignallingOpt = "fixed-block"
    faults: FaultsOpt = None
    regulation: RegulationOpt = False

    def line_settings(self) -> LineSettings:
        """These options and the faults file as the run's settings."""
        from railstop.config.faults import load_faults
        from railstop.sim.line import LineSettings

        fault_data = load_faults(self.faults)
        return LineSettings(
            door_link_loss=self.door_link_loss,
            odometer_error_pct=self.odometer_error_pct,
            slide_probability=self.slide_probability,
            calibration=self.calibration,
            signalling=self.signalling,
            outages=tuple(fault_data.outages()),
            random_outages=fault_data.random_outages,
            zc_restarts=tuple(fault_data.restarts()),
            radio_changes=fault_data.radio.changes(),
            regulation=self.regulation,
        )


def _line_with_blocks(path: Path | None) -> Line:
    """The line file, refused (naming the file) where it has no ``[signalling]``: the trains of a
    line run need its blocks, the fixed signals' and (with CBTC) the zones' (its stations alone
    suffice to ``check``, ``stop`` and ``campaign``)."""
    from railstop.config import load_line
    from railstop.config.loader import line_source

    ln = load_line(path)
    if ln.signalling is None:
        raise ConfigError(
            line_source(path), "signalling", "the line has no [signalling]: a line run needs its blocks"
        )
    return ln


def _per_hour(tph: object) -> str:
    """The throughput as the text says it: none under an hour of simulated time (the summary's
    ``trains_per_hour`` is null then, rather than an hour's rate guessed from less)."""
    return "trains/h: the run is under an hour" if tph is None else f"{tph} trains/h"


def _figure(value: object, unit: str, none: str) -> str:
    """A figure of the summary with its unit, or what its absence means (the JSON's null)."""
    return none if value is None else f"{value} {unit}"


def _cbtc_text(cbtc: dict[str, Any] | None) -> str:
    """The CBTC run's safety counts (SPEC §4), where the line ran under CBTC."""
    if not cbtc:
        return ""
    causes = cbtc.get("onboard_eb_causes") or {}
    why = f" ({', '.join(f'{k} {v}' for k, v in sorted(causes.items()))})" if causes else ""
    return (
        f"CBTC ({cbtc['mode']} zones): {cbtc['lost_trains']} lost trains, {cbtc['zones']} protection zones, "
        f"{cbtc['onboard_emergency_brakes']} onboard emergency brakes{why}, "
        f"{cbtc['authority_overlaps']} authority overlaps, {cbtc['collisions']} collisions; "
    )


def _regulation_text(cbtc: dict[str, object] | None) -> str:
    """The regulation's holds, where it is on (``--regulation``)."""
    if not cbtc or "regulation_holds" not in cbtc:
        return ""
    return f"the ATS held trains {cbtc['regulation_holds']} times, {cbtc['regulation_hold_s']} s in all; "


def _link_text(link: dict[str, int]) -> str:
    return f"{link['frames']:,} frames, {link['lost']:,} lost, {link['rejected']:,} refused"


line_app = command_group(
    "The line with many trains: fixed-block signalling, station stops by ground TASC, dwells."
)


@line_app.command("run")
@with_option_groups
def run_cmd(
    *,
    trains: TrainsOpt = None,
    headway_s: HeadwayOpt = None,
    duration_s: Annotated[float, typer.Option(min=1.0, max=86400.0, help="Simulated time (s).")] = 3600.0,
    seed: Annotated[int, typer.Option(help="Random seed of the disturbance draws.")] = 1,
    disturbances: Annotated[
        str, typer.Option(help="Disturbance set of every station stop: a built-in set or a TOML file.")
    ] = "nominal",
    settings: LineOptions,
    plot: Annotated[Path | None, typer.Option(help="Write the time-distance diagram (PNG).")] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print one JSON object.")] = False,
    line: LineOpt = None,
    vehicle: VehicleOpt = None,
    operation: OperationOpt = None,
    law: LawOpt = None,
    office: OfficeOpt = None,
) -> None:
    """Run the trains of the operation over the line: entries, running under the fixed-block
    signals, a station stop by ground TASC at every station, dwells; print the summary. With
    ``--law``, the operation file's ``controller`` may name one of the file's laws."""
    from railstop.config import load_vehicle
    from railstop.config.disturbances import load_disturbances
    from railstop.provenance import footer, inputs_sha256, stamp
    from railstop.sim.line import LineSimulation
    from railstop.streams import SEED_RANGE, seed_in_range

    if not seed_in_range(seed):
        fail(f"--seed: {SEED_RANGE} (got {seed})")
    load_law(law)
    try:
        target = office_target(office)  # before the work: a bad --office fails at once
        ln = _line_with_blocks(line)
        veh = load_vehicle(vehicle)
        op = _operation(operation, ln, trains, headway_s)
        dist = load_disturbances(disturbances)
        sim = LineSimulation(
            line=ln,
            vehicle=veh,
            operation=op,
            disturbances=dist,
            seed=seed,
            settings=settings.line_settings(),
        )
        result = sim.run(duration_s)
        summary = result.summary()
        if plot is not None:
            from railstop.report.line_plot import plot_line

            prov = stamp(inputs_sha256(ln.model_dump(), veh.model_dump(), op.model_dump()))
            tph = summary["trains_per_hour"]
            title = (
                f"{ln.line.name}: {summary['exited']} of {op.trains} trains through"
                + (f" ({tph} trains/h)" if tph is not None else "")
                + f", {summary['stops']} stops by {op.controller} ({disturbances}), "
                f"{summary['dwell_faults']} dwell faults, {settings.signalling}"
                + (", regulated" if settings.regulation else "")
                + (f", {summary['cbtc']['lost_trains']} lost trains" if summary["cbtc"] else "")
            )
            plot = plot_line(result, plot, title=title, footer=footer(prov, seed=seed))
        if target is not None:
            summary["office_link"] = send_to_office(target, line_reports(result, op.controller))
    except RailstopError as exc:
        fail(str(exc))
    if as_json:
        print(json.dumps(summary))
        return
    console.print(
        f"{ln.line.name}: {summary['entered']} of {summary['trains']} trains entered, "
        f"{summary['exited']} left "
        f"the line in {duration_s:g} s ({_per_hour(summary['trains_per_hour'])}, mean delay "
        f"{_figure(summary['mean_delay_s'], 's', 'none: no train left the line')}, least separation "
        f"{_figure(summary['min_separation_m'], 'm', 'none: never two trains on the line')}); "
        f"{summary['stops']} station stops by {op.controller}, {summary['stops_within_tolerance']} within "
        f"the PSD tolerance, p99 |error| {summary['stop_error_p99_m']} m, {summary['emergency_brakes']} "
        f"emergency brakes; mean dwell {summary['mean_dwell_s']} s, {summary['dwell_faults']} dwell faults; "
        f"door link {_link_text(summary['door_link'])}; "
        f"occupancy telegrams {_link_text(summary['occupancy_link'])}; "
        f"onboard position p99 |error| {summary['position_error_p99_m']} m "
        f"({summary['position_calibration']} calibration, {summary['slide_events']} slides, "
        f"{summary['slip_events']} slips); "
        + _cbtc_text(summary["cbtc"])
        + _regulation_text(summary["cbtc"])
        + f"simulated {summary['sim_to_wall']}x faster than real time",
        highlight=False,
        soft_wrap=True,
    )
    if plot is not None:
        console.print(f"plot: {plot}", highlight=False)
    if office is not None:
        n = summary["office_link"]["submitted"]
        console.print(f"office: {n} stop and dwell results sent to {office} (acknowledged)", highlight=False)


def line_reports(result: LineResult, controller: str) -> list[tuple[str, dict[str, object]]]:
    """A line run's stops and dwells as the office stores them (SPEC §1 claim 7), with the live
    processes' names: each stop's result, each dwell's."""
    reports: list[tuple[str, dict[str, object]]] = []
    for s in result.stops:
        reports.append(
            (
                "stop-result",
                {
                    "station": s.station,
                    "train": s.train,
                    "controller": controller,
                    "error_m": round(s.error_m, 3),
                    "within": bool(s.within_tolerance),
                    "t_s": round(s.arrive_s, 2),
                    "eb": s.emergency_brake,
                },
            )
        )
    for d in result.dwells:
        reports.append(
            (
                "dwell-result",
                {
                    "station": d.station,
                    "train": d.train,
                    "outcome": d.outcome,
                    "psc_requests": d.psc_attempts,
                    "corrections": d.corrections,
                    "dwell_s": d.dwell_s,
                },
            )
        )
    return reports


@line_app.command("campaign")
@with_option_groups
def campaign_cmd(
    *,
    runs: Annotated[int, typer.Option(min=1, max=100_000, help="Line runs (run r has seed S + r).")] = 10,
    seed: Annotated[int, typer.Option(help="Seed S of the first run.")] = 1,
    trains: TrainsOpt = None,
    headway_s: HeadwayOpt = None,
    duration_s: Annotated[
        float, typer.Option(min=1.0, max=86400.0, help="Simulated time per run (s).")
    ] = 3600.0,
    disturbances: Annotated[
        str, typer.Option(help="Disturbance set of every station stop: a built-in set or a TOML file.")
    ] = "standard",
    settings: LineOptions,
    workers: Annotated[int, typer.Option(min=1, max=256, help="Processes (default: 1).")] = 1,
    scheduler: SchedulerOpt = None,
    out: Annotated[Path, typer.Option(help="Campaign folder.")] = Path("line-campaign"),
    resume: Annotated[bool, typer.Option(help="Continue an interrupted campaign in --out.")] = False,
    as_json: Annotated[bool, typer.Option("--json", help="Print the summary as JSON.")] = False,
    line: LineOpt = None,
    vehicle: VehicleOpt = None,
    operation: OperationOpt = None,
    law: LawOpt = None,
) -> None:
    """Many line runs over disturbance draws: per station stop accuracy and dwell, trains per
    hour, delays, emergency brakes, the onboard position's error. With ``--law``, the operation
    file's ``controller`` may name one of the file's laws."""
    from rich.table import Table

    from railstop.config import load_vehicle
    from railstop.config.disturbances import load_disturbances
    from railstop.sim.line_campaign import LineCampaignSpec, run_line_campaign
    from railstop.streams import SEED_RANGE, seed_in_range

    if not (seed_in_range(seed) and seed_in_range(seed + runs - 1)):
        fail(f"--seed: {SEED_RANGE} for every run's seed S + r (got S = {seed}, {runs} runs)")
    law_file = load_law(law)
    try:
        ln = _line_with_blocks(line)
        veh = load_vehicle(vehicle)
        op = _operation(operation, ln, trains, headway_s)
        spec = LineCampaignSpec(
            line=ln,
            vehicle=veh,
            operation=op,
            disturbances=load_disturbances(disturbances),
            runs=runs,
            seed=seed,
            duration_s=duration_s,
            settings=settings.line_settings(),
            law=law_file,
        )
        summary = run_line_campaign(spec, out, workers=workers, resume=resume, scheduler=scheduler)
    except RailstopError as exc:
        fail(str(exc))
    if as_json:
        print(json.dumps(summary))
        return
    table = Table(
        title=f"{summary['runs']} line runs, {op.trains} trains every {op.headway_s:g} s ({disturbances})"
    )
    for col in ("station", "stops", "within tolerance", "p99 |error| m", "mean dwell s", "EB"):
        table.add_column(col, justify="left" if col == "station" else "right")
    for name, st in summary["stations"].items():
        share = st["within_tolerance"]
        table.add_row(
            name,
            f"{st['stops']:,}",
            "-" if share is None else f"{100 * share:.2f}%",
            str(st["p99_abs_error_m"]),
            str(st["mean_dwell_s"]),
            str(st["emergency_brakes"]),
        )
    console.print(table)
    console.print(
        f"{_per_hour(summary['trains_per_hour_mean'])} (mean over runs), mean delay "
        f"{_figure(summary['mean_delay_s_mean'], 's', 'none: no train left the line')}, "
        f"{summary['dwell_faults']} dwell faults, door link {_link_text(summary['door_link'])}, "
        f"occupancy telegrams {_link_text(summary['occupancy_link'])}, "
        f"{summary['skipped_stops']} skipped stops, least separation "
        f"{_figure(summary['min_separation_m'], 'm', 'none: never two trains on the line')}, "
        f"onboard position p99 {summary['position_error_p99_m_mean']} m "
        f"(worst run {summary['position_error_p99_m_worst']} m); runs and summary in {out}",
        highlight=False,
        soft_wrap=True,
    )


def _operation(path: Path | None, line: Line, trains: int | None, headway_s: float | None) -> Operation:
    """The operation file, with --trains and --headway-s over it (not over a timetable)."""
    from railstop.config.operation import load_operation

    op = load_operation(path, line)
    changes: dict[str, object] = {}
    for name, value, flag in (("trains", trains, "--trains"), ("headway_s", headway_s, "--headway-s")):
        if value is None:
            continue
        if op.entries_s is not None:
            raise RailstopError(f"{flag}: the operation file has a timetable (entries_s); edit it instead")
        changes[name] = value
    return op.model_validate({**op.model_dump(), **changes}) if changes else op
