"""``railstop position-run``: one train over the whole line with SPEC §2 position correction."""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, NoReturn, TypeVar

import typer

from railstop.cli.common import LineOpt, OperationOpt, VehicleOpt, fail, out
from railstop.config import load_line, load_vehicle
from railstop.config.disturbances import DisturbanceSet, load_disturbances
from railstop.config.operation import Operation, load_operation
from railstop.config.schema import Line, Vehicle
from railstop.errors import RailstopError
from railstop.sim.position_run import (
    SETTING_LIMITS,
    PositionRunResult,
    PositionRunSettings,
    SettingError,
    check_streams,
    disturbance_overrides,
    run_position,
)

_DEFAULTS = PositionRunSettings()


@dataclass(frozen=True, slots=True)
class _Number:
    """A numeric option: the setting it gives (as ``value × scale``), in which unit, whole or not."""

    setting: str
    whole: bool = False
    scale: float = 1.0
    unit: str = ""


# Numbers are taken as text and parsed here, so that every refusal quotes the value as typed and
# states the rule in the option's own unit (mm, h), not in the simulation's (m, s).
_NUMBERS: dict[str, _Number] = {
    "--seed": _Number("seed", whole=True),
    "--run": _Number("run", whole=True),
    "--diameter-error-pct": _Number("diameter_error_pct", unit="%"),
    "--wheel-diameter-mm": _Number("wheel_diameter_m", scale=1e-3, unit="mm"),
    "--slides": _Number("slides", whole=True),
    "--slips": _Number("slips", whole=True),
    "--low-mu": _Number("low_mu"),
    "--holdover-h": _Number("holdover_s", scale=3600.0, unit="h"),
}
_OPTION_OF = {spec.setting: option for option, spec in _NUMBERS.items()}
_EXACT_FLOAT_INT = 2**53


def _shown(text: str) -> str:
    """The value as typed: bare when it reads as a number, quoted otherwise."""
    try:
        float(text)
    except ValueError:
        return repr(text)
    return text.strip()


def _number(option: str, text: str) -> int | float:
    """The setting's value of ``text`` (``value × scale``); a bad one is a one-line exit."""
    spec = _NUMBERS[option]
    try:
        value: float = float(text)
    except ValueError:
        fail(f"{option}: not a number (got {text!r})")
    number: int | float = value
    if spec.whole:
        try:
            number = int(text)
        except ValueError:
            if math.isnan(value):
                fail(f"{option}: not a number (got {_shown(text)})")
            if math.isinf(value):
                fail(f"{option}: not finite (got {_shown(text)})")
            if not value.is_integer() or abs(value) > _EXACT_FLOAT_INT:
                fail(f"{option}: not a whole number (got {_shown(text)})")
            number = int(value)  # e.g. 1e3
    setting = number if spec.scale == 1.0 else number * spec.scale
    limit = SETTING_LIMITS.get(spec.setting)
    problem = None if limit is None else limit.problem(setting, scale=spec.scale, unit=spec.unit)
    if problem is not None:
        fail(f"{option}: {problem} (got {_shown(text)})")
    return setting


_VEHICLES = "the vehicle's"
_LINE_DATA = "the line's data"


def _rule(option: str) -> str:
    """The range of ``option`` in its own unit, for its help."""
    spec = _NUMBERS[option]
    return SETTING_LIMITS[spec.setting].rule(scale=spec.scale, unit=spec.unit)


def _default(value: object) -> str:
    """A help text's default; the bracket is escaped (the help is rich markup)."""
    return f"\\[default: {value}]"


def position_run(
    line: LineOpt = None,
    vehicle: VehicleOpt = None,
    operation: OperationOpt = None,
    seed: Annotated[str, typer.Option(metavar="<int>", help="Random seed.")] = "1",
    run: Annotated[
        str,
        typer.Option(
            metavar="<int>",
            help="Run index of the random streams (and of the disturbance draw).",
        ),
    ] = "0",
    disturbances: Annotated[
        str | None,
        typer.Option(
            help="Take wheel_diameter_mm, odometer_diameter_error_pct and low_adhesion_* from this set "
            "(standard, wide, nominal, control-law, loss-95, outage-after-first or a TOML file), "
            "drawn for --run; explicit options win."
        ),
    ] = None,
    diameter_error_pct: Annotated[
        str | None,
        typer.Option(
            metavar="<float>",
            help="Odometer's assumed wheel diameter = actual x (1 + error/100); "
            f"{_rule('--diameter-error-pct')}. {_default(f'{_DEFAULTS.diameter_error_pct:g}')}",
        ),
    ] = None,
    wheel_diameter_mm: Annotated[
        str | None,
        typer.Option(
            metavar="<float>",
            help=f"Actual wheel diameter; {_rule('--wheel-diameter-mm')}. {_default(_VEHICLES)}",
        ),
    ] = None,
    slides: Annotated[
        str | None,
        typer.Option(
            metavar="<int>",
            help=f"Stations with a low-adhesion patch where the train brakes for them (slide), at "
            f"most one per station. "
            f"{_default(_DEFAULTS.slides)}",
        ),
    ] = None,
    slips: Annotated[
        str | None,
        typer.Option(
            metavar="<int>",
            help=f"Stations with a low-adhesion patch where the train starts from them (slip), at "
            f"most one per station. "
            f"{_default(_DEFAULTS.slips)}",
        ),
    ] = None,
    low_mu: Annotated[
        str | None,
        typer.Option(
            metavar="<float>",
            help=f"Adhesion in a patch; {_rule('--low-mu')}. {_default(f'{_DEFAULTS.low_mu:g}')}",
        ),
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
        str | None,
        typer.Option(
            metavar="<float>",
            help=f"Hours since a clock without time source was set; {_rule('--holdover-h')}. "
            f"{_default(_LINE_DATA)}",
        ),
    ] = None,
    same_path: Annotated[
        bool,
        typer.Option(
            "--same-path",
            help="Also run the SPEC §2 chain with and without GNSS time and repeaters (a day's and a "
            "week's holdover) on this run's own path, so the table shows what each setting alone "
            "changes.",
        ),
    ] = False,
    plot: Annotated[
        Path | None, typer.Option(help="Write a PNG of the errors against chainage here.")
    ] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print one JSON object.")] = False,
) -> None:
    """One train over the whole line (a one-train line run): raw, corrected (SPEC §2) and calibrated
    position errors."""
    typed = {
        "--seed": seed,
        "--run": run,
        "--diameter-error-pct": diameter_error_pct,
        "--wheel-diameter-mm": wheel_diameter_mm,
        "--slides": slides,
        "--slips": slips,
        "--low-mu": low_mu,
        "--holdover-h": holdover_h,
    }
    given = {option: text for option, text in typed.items() if text is not None}
    explicit = {_NUMBERS[option].setting: _number(option, text) for option, text in given.items()}
    seed_n, run_n = int(explicit.pop("seed")), int(explicit.pop("run"))
    if plot is not None:
        _check_plot_path(plot)
    drawn: set[str] = set()
    try:
        check_streams(seed_n, run_n)
        ln = _load("--line", line, load_line)
        veh = _load("--vehicle", vehicle, load_vehicle)
        # The train's entry and dwells (its first train); the embedded one names the embedded
        # line's stations, so a line of one's own needs its own.
        op = _load("--operation", operation, lambda path: load_operation(path, ln))
        dist = None  # the station stops draw from the set given (default: the line's nominal)
        if disturbances is not None:
            dist = _load("--disturbances", disturbances, load_disturbances)
        values, drawn = _setting_values(dist, explicit, ln, veh, seed_n, run_n)
        settings = PositionRunSettings(
            seed=seed_n,
            run=run_n,
            gnss=not no_gnss,
            repeaters=not no_repeaters,
            learn=not no_learning,
            same_path=same_path,
            **values,
        )
        result = run_position(ln, veh, settings, operation=op, disturbances=dist)
        summary = result.summary()
        if plot is not None:
            plot = _write_plot(
                result, plot, ln, veh, op if operation is not None else None, settings, disturbances
            )
    except SettingError as exc:
        _fail_setting(exc, given, drawn, disturbances)
    except RailstopError as exc:
        fail(str(exc))
    if as_json:
        print(json.dumps(summary))
        return
    _print_summary(summary, plot)


def _setting_values(
    dist: DisturbanceSet | None,
    explicit: dict[str, Any],
    ln: Line,
    veh: Vehicle,
    seed: int,
    run: int,
) -> tuple[dict[str, Any], set[str]]:
    """The run's settings: those the disturbance set draws for the run, then the options given
    (which win); and the names the set drew."""
    values: dict[str, Any] = {}
    if dist is not None:
        values.update(disturbance_overrides(dist, ln, veh, seed=seed, run=run))
    drawn = set(values)
    for key, value in explicit.items():
        values[key] = value
        # A count given on the command line replaces the set's per-zone chance.
        if key in ("slides", "slips"):
            values.pop(f"{key[:-1]}_probability", None)
    return values, drawn


def _fail_setting(
    exc: SettingError, given: dict[str, str], drawn: set[str], disturbances: str | None
) -> NoReturn:
    """A refused setting as one line naming where it came from: the option given, the disturbance
    set's draw, or the default."""
    option = _OPTION_OF.get(exc.setting)
    if option is not None and option in given:
        fail(f"{option}: {exc.detail} (got {_shown(given[option])})")
    if exc.setting in drawn:
        fail(f"--disturbances: {disturbances}: {exc}")
    if option is not None:
        fail(f"{option}: {exc.detail} (got {exc.value!r}, the default)")
    fail(str(exc))


def _write_plot(
    result: PositionRunResult,
    plot: Path,
    ln: Line,
    veh: Vehicle,
    operation: Operation | None,
    settings: PositionRunSettings,
    disturbances: str | None,
) -> Path:
    """The run's PNG with its provenance footer (the inputs' hash, seed, run, disturbance set);
    ``operation``: the file given with --operation (None: the embedded one, as before)."""
    from dataclasses import asdict

    from railstop.provenance import footer, inputs_sha256, stamp
    from railstop.report.position_plot import plot_position_run

    parts: list[object] = [ln.model_dump(mode="json"), veh.model_dump(mode="json"), asdict(settings)]
    if operation is not None:
        parts.append(operation.model_dump(mode="json"))
    inputs = inputs_sha256(*parts)
    note = footer(stamp(inputs), seed=settings.seed, run=settings.run, disturbances=disturbances)
    try:
        return plot_position_run(result, plot, footer=note)
    except RailstopError as exc:
        fail(f"--plot: {exc}")


def _print_summary(s: dict[str, Any], plot: Path | None) -> None:
    """The run's errors as the terminal shows them."""
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
        f"delay {s['learned_delay_s']:.3f} s); after the first stop p99 "
        f"{s['calibrated_p99_abs_after_first_stop_m']} m",
        highlight=False,
        soft_wrap=True,
    )
    if "same_path" in s:
        out.print(
            "  on this run's path (the train driven as above):\n"
            f"    {'setting':30s} {'corrected p99 / max':>22s} {'calibrated p99 / max':>22s} "
            f"{'after stop 1':>13s}",
            highlight=False,
            soft_wrap=True,
        )
        for row in s["same_path"]:
            after = row["calibrated_p99_abs_after_first_stop_m"]
            cor, cal = "corrected", "calibrated"
            out.print(
                f"    {row['setting']:30s} {row[f'{cor}_p99_abs_m']:9.2f} / {row[f'{cor}_max_abs_m']:6.2f} m "
                f"{row[f'{cal}_p99_abs_m']:9.2f} / {row[f'{cal}_max_abs_m']:6.2f} m "
                f"{'–' if after is None else f'{after:.2f} m':>13s}",
                highlight=False,
                soft_wrap=True,
            )
    if plot is not None:
        out.print(f"plot: {plot}", highlight=False)


T = TypeVar("T")


def _load(option: str, source: Any, load: Callable[[Any], T]) -> T:
    """``load(source)``; a file given by ``option`` that cannot be used is one line naming the option."""
    try:
        return load(source)
    except RailstopError as exc:
        if source is None:
            raise
        fail(f"{option}: {exc}")


def _check_plot_path(plot: Path) -> None:
    """Refuse a plot file that cannot be written before the run, not after it."""
    from railstop.report.figures import figure_path

    try:
        target = figure_path(plot)
    except RailstopError as exc:
        fail(f"--plot: {exc}")
    if not target.parent.is_dir():
        fail(f"--plot: {target}: directory {str(target.parent)!r} does not exist")
