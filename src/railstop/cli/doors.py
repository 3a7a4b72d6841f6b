"""``railstop doors verify|table`` and ``railstop dwell``: train doors and PSD (SPEC §3, §5)."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Annotated

import typer

from railstop.cli.common import (
    check_db_options,
    command_group,
    fail,
    out,
    print_verification,
    stand_on_platform,
    stop_error_option,
    styled,
)
from railstop.errors import RailstopError

doors_app = command_group(
    "Train doors and platform screen doors (SPEC §5): the door action table and its exhaustive proof."
)

DoorsOpt = Annotated[
    Path | None, typer.Option("--doors", help="Door data TOML file (default: the embedded doors.toml).")
]


@doors_app.command("table")
def table_cmd(
    doors: DoorsOpt = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print the rows as JSON.")] = False,
) -> None:
    """Print the door action table (SPEC §5 Table 1) as the code uses it."""
    from rich.table import Table

    from railstop.config.doors import load_doors

    try:
        cfg = load_doors(doors)
    except RailstopError as exc:
        fail(str(exc))
    rows = cfg.actions.rows
    if as_json:
        print(
            json.dumps(
                [
                    {
                        "doa": r.doa,
                        "dmc": r.dmc,
                        "doc": r.doc,
                        "dcc": r.dcc,
                        "closed": r.closed.value,
                        "open": r.open.value,
                        "open_manual": (r.open_manual or r.open).value,
                    }
                    for r in rows
                ]
            )
        )
        return
    table = Table(title=f"Door action table (SPEC §5 Table 1) from {cfg.source}")
    for col in ("DOA", "DMC", "DOC", "DCC"):
        table.add_column(col, justify="center")
    table.add_column("door now closed →")
    table.add_column("door now open →")
    for r in rows:
        when_open = r.open.value
        if r.open_manual is not None and r.open_manual != r.open:
            when_open += f" ({r.open_manual.value} in manual mode)"
        closed = styled(r.closed.value, "bold green") if r.closed.value == "open" else r.closed.value
        table.add_row(str(r.doa), str(r.dmc), str(r.doc), str(r.dcc), closed, when_open)
    out.print(table)
    out.print(
        "[interpretation] reconstructed from a garbled source table: open only when DOA=1, DMC=0, DOC=1; "
        "close when DMC=1 and DCC=1; in manual mode the close button (DCC) closes on its own. The source's "
        "PSD opening for (0,1,1,0) contradicts DMC's priority and is taken as a transcription error: "
        "nothing ever opens with DMC=1 or DOA=0. The PSD follows the same table (PSD opens first, "
        "closes last).",
        highlight=False,
        soft_wrap=True,
        markup=False,
    )


@doors_app.command("verify")
def verify_cmd(
    doors: DoorsOpt = None,
    doors_per_side: Annotated[
        int,
        typer.Option(
            min=1,
            max=2,
            help="Door units per side in the model: 1 (270 states) or 2 (3,450 states, many times "
            "longer; also covers interactions between the doors of one side).",
        ),
    ] = 1,
    as_json: Annotated[bool, typer.Option("--json", help="Print one JSON object.")] = False,
) -> None:
    """Explore every reachable state of CPCS + WPCS + PSC under every input; exit 1 on a violation."""

    from railstop.config.doors import load_doors
    from railstop.sim.dwell import model_for
    from railstop.verify.doors import INVARIANTS, verify

    try:
        cfg = load_doors(doors)
        result = verify(model_for(cfg), doors_per_side=doors_per_side)
    except RailstopError as exc:
        fail(str(exc))
    if as_json:
        print(json.dumps({"doors": cfg.source, **result.summary()}))
    else:
        out.print(
            f"doors verify ({cfg.source}): {doors_per_side} door unit(s) per side, both platform sides; "
            f"{result.controls} input combinations (DOA-L/R, DMC-L/R, DOC, DCC x auto/manual x WPCS auto "
            f"or WCC-manual with panel open/close) under every event of every state",
            highlight=False,
            soft_wrap=True,
        )
        print_verification(title="invariants", invariants=INVARIANTS, result=result)
    if result.violations:
        raise typer.Exit(1)


def dwell(
    ctx: typer.Context,
    station: Annotated[str | None, typer.Option(help="Station name (default: the line's first).")] = None,
    stop_error_m: Annotated[
        str | None,
        typer.Option(
            "--stop-error-m",
            help="Where the train stopped, m from the stopping point (+ = overrun). "
            "Default: the result of a simulated stop (--controller, --seed).",
        ),
    ] = None,
    mode: Annotated[str, typer.Option(help="Driving mode: auto or manual.")] = "auto",
    obstruct_door: Annotated[
        int | None, typer.Option(help="Obstruct this train door (1 = front) while closing; cleared later.")
    ] = None,
    psd_fail: Annotated[
        int | None, typer.Option(help="This PSD unit (1 = front) fails to close; staff isolate it.")
    ] = None,
    controller: Annotated[str, typer.Option(help="Controller of the simulated stop.")] = "tasc-pwm",
    seed: Annotated[int, typer.Option(help="Seed of the simulated stop and of the door link.")] = 1,
    link_cut_s: Annotated[
        float | None,
        typer.Option(
            min=0.0,
            max=3600.0,
            help="The door link dies this long after the stop, for good (a fault; SPEC §5 fault path).",
        ),
    ] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print one JSON object.")] = False,
    plot: Annotated[Path | None, typer.Option(help="Write a PNG timeline of the dwell here.")] = None,
    db: Annotated[Path, typer.Option(help="SQLite database file (gets the timeline).")] = Path("railstop.db"),
    no_db: Annotated[
        bool, typer.Option("--no-db", help="Write no database (the timeline is only printed).")
    ] = False,
    line: Annotated[
        Path | None, typer.Option("--line", help="Line TOML file (default: embedded line).")
    ] = None,
    vehicle: Annotated[
        Path | None, typer.Option("--vehicle", help="Vehicle TOML file (for the simulated stop).")
    ] = None,
    doors: DoorsOpt = None,
) -> None:
    """Run a station dwell: arrival -> PSC -> open -> dwell -> close -> start enable (SPEC §5)."""
    from rich.table import Table

    from railstop.config import load_line, load_vehicle
    from railstop.config.doors import load_doors
    from railstop.config.loader import line_source
    from railstop.sim.dwell import MODES, run_dwell
    from railstop.streams import SEED_RANGE, seed_in_range

    if mode not in MODES:
        fail(f"--mode: must be one of {', '.join(MODES)} (got {mode!r})")
    if not seed_in_range(seed):
        fail(f"--seed: {SEED_RANGE} (got {seed})")
    check_db_options(ctx, no_db)
    error_m = stop_error_option(stop_error_m)
    try:
        ln = load_line(line)
        st = ln.station(station)
        cfg = load_doors(doors).at_station(st, line_source(line))
        cfg.check_vehicle(load_vehicle(vehicle), str(vehicle) if vehicle else "the embedded vehicle")
        for option, unit in (("--obstruct-door", obstruct_door), ("--psd-fail", psd_fail)):
            if unit is not None and not 1 <= unit <= cfg.doors_per_side:
                fail(f"{option}: door units are numbered 1..{cfg.doors_per_side} (got {unit})")
        source = "given"
        if error_m is None:
            from railstop.controllers import CONTROLLERS
            from railstop.sim.single import run_stop

            if controller not in CONTROLLERS:
                names = ", ".join(CONTROLLERS)
                fail(f"--controller: unknown controller {controller!r}; choose one of: {names}")
            stop, _ = run_stop(
                line=ln, station=st, vehicle=load_vehicle(vehicle), controller=controller, seed=seed
            )
            if not stop.stopped:
                fail(f"the simulated stop at {st.name} did not come to rest")
            error_m = float(stop.stop_error_m)
            source = f"simulated stop ({controller}, seed {seed})"
        stand_on_platform(error_m, st)
        from railstop.sim.dwell import make_door_link

        outage = None if link_cut_s is None else (link_cut_s, math.inf)
        result = run_dwell(
            doors=cfg,
            station=st.name,
            platform_side=st.platform_side,
            stop_error_m=error_m,
            mode=mode,
            obstruct_door=obstruct_door,
            psd_fail=psd_fail,
            link=make_door_link(cfg, seed=seed, outage=outage),
        )
        key = (
            f"{ln.line.name}|{st.name}|{mode}|{error_m!r}|obstruct={obstruct_door}|psd_fail={psd_fail}"
            f"|seed={seed}|link_cut={link_cut_s}|doors={cfg.fingerprint()}"
        )
        if not no_db:
            from railstop.store import open_store

            with open_store(db) as store:
                store.save_dwell(key=key, station=st.name, events=result.timeline)
        if plot is not None:
            from railstop.provenance import footer, inputs_sha256, stamp
            from railstop.report.dwell_plot import plot_dwell

            inputs = inputs_sha256(ln.model_dump(mode="json"), cfg.fingerprint(), source)
            plot = plot_dwell(result, plot, footer=footer(stamp(inputs), seed=seed, stop_error=source))
    except RailstopError as exc:
        fail(str(exc))
    if as_json:
        print(json.dumps({**result.summary(), "stop_error_source": source, "dwell_key": key}))
        return
    table = Table(title=f"Dwell at {st.name} ({mode} mode, platform side {st.platform_side})")
    table.add_column("t (s)", justify="right")
    table.add_column("signal")
    table.add_column("value")
    for e in result.timeline:
        table.add_row(f"{e.t_s:.3f}", e.signal, str(e.value))
    out.print(table)
    if result.start_enable_s is not None:
        end = f"start enable at {result.start_enable_s:g} s"
    elif result.fault:
        end = f"FAULT and emergency brake at {result.dwell_total_s:g} s"
    else:
        end = f"no start enable ({result.outcome}) at {result.dwell_total_s:g} s"
    out.print(
        f"stop error {result.stop_error_m:+.3f} m ({source}; tolerance ±{result.tolerance_m:g} m, "
        f"{'in' if result.in_tolerance else 'out of'} tolerance): {result.psc_attempts} PSC attempt(s), "
        f"{result.corrections} correction(s), {end}" + ("" if no_db else f"; timeline saved to {db}"),
        highlight=False,
        soft_wrap=True,
    )
    if result.link is not None:
        c = result.link
        refused = ", ".join(f"{n} {k}" for k, n in sorted(c.rejected.items())) or "none"
        out.print(
            f"door link: {c.commands_sent} door-command / {c.status_sent} psd-status frames sent, "
            f"{c.lost} lost on the medium, refused by the safety layer: {refused}",
            highlight=False,
            soft_wrap=True,
        )
    if plot is not None:
        out.print(f"plot: {plot}", highlight=False)
