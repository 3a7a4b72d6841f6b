"""``railstop platform verify|dwell``: the platform of a manually driven line (SPEC §3): its
interlock checked exhaustively, and a dwell with its lamp and PSD timeline."""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from railstop.cli.common import (
    DriverOpt,
    LineOpt,
    PlatformOpt,
    VehicleOpt,
    command_group,
    fail,
    load_manual_data,
    out,
    print_verification,
    stand_on_platform,
    stop_error_option,
)
from railstop.cli.doors import DoorsOpt
from railstop.errors import RailstopError

if TYPE_CHECKING:
    from railstop.sim.single import StopResult

platform_app = command_group(
    "The platform of a manually driven line (SPEC §3): stop sensors, lamps, PSD relay."
)


@platform_app.command("verify")
def verify_cmd(
    max_dropouts: Annotated[
        int | None,
        typer.Option(
            "--max-dropouts",
            min=0,
            max=10,
            help="Scans in a row a sensor may miss (default: one fewer than the debounce).",
        ),
    ] = None,
    max_misreads: Annotated[
        int | None,
        typer.Option(
            "--max-misreads",
            min=0,
            max=10,
            help="Camera frames in a row it may misread (default: one fewer than the PSD control confirms).",
        ),
    ] = None,
    lost_limit: Annotated[
        int | None,
        typer.Option(
            "--lost-limit",
            min=1,
            max=100,
            help="Unreadable frames in a row that make the camera lost (default: the platform data's; "
            "the search grows with it).",
        ),
    ] = None,
    platform: Annotated[
        Path | None, typer.Option("--platform", help="Platform TOML file (default: embedded).")
    ] = None,
    doors: DoorsOpt = None,
) -> None:
    """Every reachable state of the real platform unit and PSD control under every event; exit 1 on
    a violation."""
    import math

    from railstop.config.doors import load_doors
    from railstop.config.platform import load_platform
    from railstop.verify.platform import INVARIANTS, verify
    from railstop.wayside.platform import PlatformUnit, PsdFollower

    try:
        data, source = load_platform(platform)
        k = data.sensors.debounce_scans
        drops = k - 1 if max_dropouts is None else max_dropouts
        confirm = data.camera.confirm_frames
        misreads = confirm - 1 if max_misreads is None else max_misreads
        lost = data.camera.lost_limit_frames if lost_limit is None else lost_limit
        lock = data.camera.lock_frames
        # The world's doors lock within the door data's lock time: frames that span it.
        lock_s = load_doors(doors).timing.train_door_lock_s
        door_lock = math.ceil(lock_s / data.camera.frame_period_s - 1e-9)
        result = verify(
            lambda: PlatformUnit(lamp_table=data.lamps(), debounce_scans=k),
            follower_factory=lambda: PsdFollower(
                confirm_frames=confirm, lost_limit_frames=lost, lock_frames=lock
            ),
            max_dropouts=drops,
            max_misreads=misreads,
            lock_frames=door_lock,
        )
    except RailstopError as exc:
        fail(str(exc))
    out.print(
        f"platform verify ({source}): the real platform unit (debounce {k} scans, up to {drops} "
        f"missed scans in a row per sensor; train stops short / in the window / past, starts, the "
        f"PSD, the signal-open switch: {result.unit_states} states) and PSD control (confirms "
        f"{confirm} frames, counts the doors locked after {lock} more, camera lost after {lost} "
        f"unreadable ones; up to {misreads} misread frames in a row, the doors locked within "
        f"{door_lock} frames of shutting; the relay, the train doors opening, closing, reopening, "
        f"locking, camera frames, the PSD following the control: {result.control_states} states)",
        highlight=False,
        soft_wrap=True,
    )
    print_verification(title="invariants", invariants=INVARIANTS, result=result)
    if result.violations:
        raise typer.Exit(1)


def _stop_source(stop: StopResult, controller: str, seed: int) -> tuple[str, str]:
    """What the dwell of a simulated driver stop starts from, and its plot's time axis."""
    if stop.passed_kmh is not None:
        return (
            f"{stop.driver_level} driver's {controller} run through the station (seed {seed}, "
            f"signal-open switch): {stop.passed_kmh:.1f} km/h at the stopping point",
            "time since the front was 30 m before the stopping point (s)",
        )
    return (
        f"{stop.driver_level} driver's {controller} stop (seed {seed}): first stand "
        f"{stop.first_stop_error_m:+.3f} m, {stop.restops} re-stop(s), final stand "
        f"{stop.stop_error_m:+.3f} m",
        "time since the train passed 300 m before the home signal (s)",
    )


@platform_app.command("dwell")
def dwell_cmd(
    station: Annotated[str | None, typer.Option(help="Station name (default: the line's first).")] = None,
    controller: Annotated[
        str, typer.Option(help="The driver controller whose stop ends in the dwell.")
    ] = "driver-ats",
    seed: Annotated[int, typer.Option(help="Random seed (the stop's; the dwell's sensors, camera).")] = 1,
    stop_error_m: Annotated[
        str | None,
        typer.Option(
            "--stop-error-m",
            help="Start from a stand this far from the stopping point (+ = past it) instead of a "
            "simulated driver stop.",
        ),
    ] = None,
    no_psd: Annotated[
        bool, typer.Option("--no-psd", help="A station without PSD (the same lamps; SPEC §3).")
    ] = False,
    signal_open: Annotated[
        bool, typer.Option("--signal-open", help="The signal-open switch is on: the train passes.")
    ] = False,
    camera_lost_s: Annotated[
        float | None,
        typer.Option(
            "--camera-lost-s", min=0.0, help="Camera frames from this time into the dwell on are unreadable."
        ),
    ] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print one JSON object.")] = False,
    plot: Annotated[Path | None, typer.Option(help="Write a PNG of the lamp and PSD timeline here.")] = None,
    db: Annotated[Path, typer.Option(help="SQLite database file (gets the timeline).")] = Path("railstop.db"),
    line: LineOpt = None,
    vehicle: VehicleOpt = None,
    doors: DoorsOpt = None,
    driver: DriverOpt = None,
    platform: PlatformOpt = None,
) -> None:
    """A manually driven train's stand, lamps, doors, PSD and departure (SPEC §3); saves the timeline."""
    from rich.table import Table

    from railstop.config import load_line, load_vehicle
    from railstop.config.doors import load_doors
    from railstop.config.loader import line_source
    from railstop.config.platform import default_platform
    from railstop.controllers import DRIVER_CONTROLLERS
    from railstop.provenance import overrides_sha256
    from railstop.sim.platform_dwell import dwell_after_stop, dwell_sentence, run_platform_dwell
    from railstop.store import open_store
    from railstop.streams import SEED_RANGE, seed_in_range

    if controller not in DRIVER_CONTROLLERS:
        names = ", ".join(DRIVER_CONTROLLERS)
        fail(f"--controller: one of the driver controllers {names} (got {controller!r})")
    if not seed_in_range(seed):
        fail(f"--seed: {SEED_RANGE} (got {seed})")
    error_m = stop_error_option(stop_error_m)
    try:
        ln = load_line(line)
        st = ln.station(station)
        cfg = load_doors(doors).at_station(st, line_source(line))
        drv, plat = load_manual_data(driver, platform)
        data = plat or default_platform()
        variant = (
            f"|psd={not no_psd}|signal_open={signal_open}|camera_lost={camera_lost_s}"
            f"|doors={cfg.fingerprint()}|manual-data={overrides_sha256(drv, plat)}"
        )
        if error_m is None:
            from railstop.sim.single import run_stop

            stop, batch = run_stop(
                line=ln,
                station=st,
                vehicle=load_vehicle(vehicle),
                controller=controller,
                seed=seed,
                driver=drv,
                platform=plat,
                signal_open=signal_open,
            )
            if not stop.stopped and stop.passed_kmh is None:
                fail(f"the simulated {controller} stop at {st.name} did not come to rest")
            result, timeline = dwell_after_stop(
                stop,
                batch,
                station=st,
                platform=data,
                doors=cfg,
                psd=not no_psd,
                signal_open=signal_open,
                camera_lost_from_s=camera_lost_s,
            )
            source, xlabel = _stop_source(stop, controller, seed)
            key = f"{stop.run_key}|platform-dwell{variant}"
        else:
            stand_on_platform(error_m, st)
            result = run_platform_dwell(
                platform=data,
                doors=cfg,
                station=st.name,
                stop_error_m=error_m,
                seed=seed,
                psd=not no_psd,
                signal_open=signal_open,
                camera_lost_from_s=camera_lost_s,
            )
            timeline = list(result.timeline)
            source = f"a stand {error_m:+.3f} m from the stopping point (given)"
            key = f"platform-dwell|{ln.line.name}|{st.name}|{error_m!r}|seed={seed}{variant}"
            xlabel = "time since the train stopped (s)"
        with open_store(db) as store:
            store.save_dwell(key=key, station=st.name, events=timeline)
        if plot is not None:
            from railstop.provenance import footer, inputs_sha256, stamp
            from railstop.report.dwell_plot import plot_platform_dwell

            inputs = inputs_sha256(
                ln.model_dump(mode="json"), cfg.fingerprint(), data.model_dump(mode="json")
            )
            title = (
                f"{st.name}: {source}\n{result.outcome}"
                + ("" if result.psd else ", station without PSD")
                + ("" if camera_lost_s is None else f", camera lost from {camera_lost_s:g} s into the dwell")
            )
            plot = plot_platform_dwell(
                timeline, plot, title=title, xlabel=xlabel, footer=footer(stamp(inputs), seed=seed)
            )
    except RailstopError as exc:
        fail(str(exc))
    if as_json:
        summary = result.summary()
        summary["timeline"] = [{"t_s": e.t_s, "signal": e.signal, "value": e.value} for e in timeline]
        print(json.dumps({**summary, "source": source, "dwell_key": key}))
        return
    table = Table(title=f"Lamp and PSD timeline at {st.name}")
    table.add_column("t (s)", justify="right")
    table.add_column("signal")
    table.add_column("value")
    for e in timeline:
        table.add_row(f"{e.t_s:.3f}", e.signal, str(e.value))
    out.print(table)
    out.print(f"{source}: {dwell_sentence(result)}", highlight=False, soft_wrap=True)
    out.print(f"timeline ({len(timeline)} events) saved to {db}", highlight=False)
    if plot is not None:
        out.print(f"plot: {plot}", highlight=False)
