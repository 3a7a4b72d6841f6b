"""``railstop position-run``: one train over the whole line with SPEC §2 position correction."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated, Any

import typer

from railstop.cli_common import fail, out
from railstop.config import load_line, load_vehicle
from railstop.config.disturbances import load_disturbances
from railstop.errors import RailstopError
from railstop.sim.position_run import PositionRunSettings, disturbance_overrides, run_position

_DEFAULTS = PositionRunSettings()


def position_run(
    line: Annotated[
        Path | None, typer.Option("--line", help="Line TOML file (default: embedded line).")
    ] = None,
    vehicle: Annotated[
        Path | None, typer.Option("--vehicle", help="Vehicle TOML file (default: embedded EMU).")
    ] = None,
    seed: Annotated[int, typer.Option(help="Random seed.")] = 1,
    run: Annotated[
        int, typer.Option(help="Run index of the random streams (and of the disturbance draw).")
    ] = 0,
    disturbances: Annotated[
        str | None,
        typer.Option(
            help="Take wheel_diameter_mm, odometer_diameter_error_pct and low_adhesion_* from this set "
            "(standard, nominal or a TOML file), drawn for --run; explicit options win."
        ),
    ] = None,
    diameter_error_pct: Annotated[
        float | None,
        typer.Option(
            help=f"Odometer's assumed wheel diameter = actual x (1 + error/100) "
            f"[default: {_DEFAULTS.diameter_error_pct:g}]."
        ),
    ] = None,
    wheel_diameter_mm: Annotated[
        float | None, typer.Option(help="Actual wheel diameter [default: the vehicle's].")
    ] = None,
    slides: Annotated[
        int | None,
        typer.Option(help=f"Braking zones with a low-adhesion patch (slide) [default: {_DEFAULTS.slides}]."),
    ] = None,
    slips: Annotated[
        int | None,
        typer.Option(help=f"Traction zones with a low-adhesion patch (slip) [default: {_DEFAULTS.slips}]."),
    ] = None,
    low_mu: Annotated[
        float | None, typer.Option(help=f"Adhesion in a patch [default: {_DEFAULTS.low_mu:g}].")
    ] = None,
    no_gnss: Annotated[
        bool,
        typer.Option("--no-gnss", help="No GNSS time at all: every clock free-runs from its last setting."),
    ] = False,
    no_repeaters: Annotated[
        bool, typer.Option("--no-repeaters", help="No satellite-signal repeaters: every tunnel is a shadow.")
    ] = False,
    no_learning: Annotated[
        bool, typer.Option("--no-learning", help="Switch the learner off (calibrated = corrected).")
    ] = False,
    holdover_h: Annotated[
        float | None,
        typer.Option(help="Hours since a clock without time source was set [default: the line's data]."),
    ] = None,
    plot: Annotated[
        Path | None, typer.Option(help="Write a PNG of the errors against chainage here.")
    ] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print one JSON object.")] = False,
) -> None:
    """Drive one train over the whole line: raw, corrected (SPEC §2) and calibrated position errors."""
    try:
        ln = load_line(line)
        veh = load_vehicle(vehicle)
        values: dict[str, Any] = {}
        if disturbances is not None:
            values.update(disturbance_overrides(load_disturbances(disturbances), ln, veh, seed=seed, run=run))
        explicit = {
            "diameter_error_pct": diameter_error_pct,
            "wheel_diameter_m": None if wheel_diameter_mm is None else wheel_diameter_mm * 1e-3,
            "slides": slides,
            "slips": slips,
            "low_mu": low_mu,
            "holdover_s": None if holdover_h is None else holdover_h * 3600.0,
        }
        for key, value in explicit.items():
            if value is not None:
                values[key] = value
                # A count given on the command line replaces the set's per-zone chance.
                if key in ("slides", "slips"):
                    values.pop(f"{key[:-1]}_probability", None)
        settings = PositionRunSettings(
            seed=seed,
            run=run,
            gnss=not no_gnss,
            repeaters=not no_repeaters,
            learn=not no_learning,
            **values,
        )
        result = run_position(ln, veh, settings)
        summary = result.summary()
        if plot is not None:
            from railstop.report.position_plot import plot_position_run

            plot = plot_position_run(result, plot)
    except RailstopError as exc:
        fail(str(exc))
    if as_json:
        print(json.dumps(summary))
        return
    s = summary
    out.print(
        f"position-run over {s['line']!r}: {s['distance_m']:.0f} m in {s['duration_s']:.0f} s, "
        f"{s['corrections']} corrections ({s['rejected']} rejected); odometer scale error "
        f"{s['true_scale_error_pct']:+.2f} %, {s['slide_patches']} slide / {s['slip_patches']} slip patches; "
        f"{'GNSS time' if s['gnss'] else 'no GNSS'}, {'repeaters' if s['repeaters'] else 'no repeaters'}",
        highlight=False,
        soft_wrap=True,
    )
    out.print(
        f"  raw odometer          : max |error| {s['raw_max_abs_m']:7.2f} m (end {s['raw_final_m']:+.2f} m)\n"
        f"  corrected (SPEC §2)   : p99 |error| {s['corrected_p99_abs_m']:7.2f} m, "
        f"max {s['corrected_max_abs_m']:.2f} m\n"
        f"  + learned calibration : p99 |error| {s['calibrated_p99_abs_m']:7.2f} m, max "
        f"{s['calibrated_max_abs_m']:.2f} m (learned scale error {s['learned_scale_error_pct']:+.3f} %, "
        f"delay {s['learned_delay_s']:.3f} s)",
        highlight=False,
        soft_wrap=True,
    )
    if plot is not None:
        out.print(f"plot: {plot}", highlight=False)
