"""``railstop formats`` (the reference of every data file) and ``railstop init`` (a starter set)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from railstop.cli.common import fail, out

# The starter set of `railstop init`: (file written, embedded source, what to change first).
STARTER: tuple[tuple[str, str, str], ...] = (
    (
        "line.toml",
        "line.toml",
        "Your line and its stations. For a station of your own change first, in its [[stations]]\n"
        "# entry: name, stop_point_m (chainage of the stopping point), platform_length_m,\n"
        "# psd_tolerance_m (how far off a stop may be for the platform screen doors to open), and\n"
        "# in [stations.tasc] the detectors_before_stop_m (metres before the stopping point,\n"
        "# farthest first) and entry_speed_kmh. The track circuits, segments and blocks must\n"
        "# still cover the line: `railstop check` names any that do not.",
    ),
    (
        "vehicle.toml",
        "vehicle.toml",
        "Your train: cars, length_m, masses, running resistance (Davis), wheel diameter, the brake\n"
        "# chain's notch decelerations B1..B7, dead time and time constant, traction, positioning.",
    ),
    (
        "operation.toml",
        "operation/default.toml",
        "The service for `railstop line run`: trains, headway, entry, controller and dwells. Its\n"
        "# [[stations]] dwells name stations of the line file: rename them with your stations.",
    ),
    (
        "doors.toml",
        "doors.toml",
        "The door / platform screen door interlock (railstop doors, dwell): timings, the stop\n"
        "# confirmation, the door link. Its psd_tolerance_m must be the line's for the station.",
    ),
    (
        "platform.toml",
        "platform.toml",
        "The manual stop with platform stop sensors, lamps and PSD (railstop platform ...).",
    ),
    (
        "driver.toml",
        "driver.toml",
        "The human driver of the manual stop (railstop platform ..., --controller driver).",
    ),
    (
        "disturbances.toml",
        "disturbances/standard.toml",
        "The random draws of a stop campaign (railstop campaign --disturbances this-file).",
    ),
)

_KIND_HELP = "One file kind to show (line, vehicle, operation, doors, platform, driver, faults, media)."


def formats(
    kind: Annotated[str | None, typer.Argument(help=_KIND_HELP, show_default=False)] = None,
    markdown: Annotated[
        Path | None,
        typer.Option("--markdown", help="Write the whole reference as Markdown (docs/file-formats.md)."),
    ] = None,
) -> None:
    """The reference of every data file: each key's type, unit, default, range and meaning."""
    from rich.table import Table

    from railstop.report.file_formats import file_formats, render_markdown, tables

    all_formats = file_formats()
    if markdown is not None:
        text = render_markdown(all_formats)
        try:
            markdown.parent.mkdir(parents=True, exist_ok=True)
            markdown.write_text(text, encoding="utf-8")
        except OSError as exc:
            fail(f"--markdown: {exc.filename or markdown}: {exc.strerror}")
        out.print(f"file formats: {len(all_formats) + 2} files written to {markdown}", highlight=False)
        return
    if kind is None:
        overview = Table(title="Data files (railstop formats KIND shows one)")
        for col in ("kind", "option", "embedded default", "tables", "keys"):
            overview.add_column(col, overflow="fold")
        for fmt in all_formats:
            ts = list(tables(fmt.model, fmt.root))
            overview.add_row(
                fmt.name, fmt.option, fmt.embedded or "-", str(len(ts)), str(sum(len(t.keys) for t in ts))
            )
        overview.add_row("disturbances", "--disturbances", "railstop/data/disturbances/", "1", "-")
        overview.add_row("operators", "--operators", "-", "1", "2")
        out.print(overview)
        return
    chosen = next((f for f in all_formats if f.name == kind.lower()), None)
    if chosen is None:
        fail(f"formats: no file kind {kind!r}; choose one of: {', '.join(f.name for f in all_formats)}")
    for t in tables(chosen.model, chosen.root):
        table = Table(title=f"{chosen.title}: [{t.header}]" if t.header else f"{chosen.title}: top level")
        for col in ("key", "type", "unit", "default", "range", "meaning"):
            table.add_column(col, overflow="fold")
        for k in t.keys:
            table.add_row(k.key, k.type, k.unit, k.default, k.range, k.meaning)
        out.print(table)


def init(
    directory: Annotated[Path, typer.Argument(help="The folder to write the starter files into.")],
) -> None:
    """Write a starter set of data files for a station of your own: commented copies of the
    embedded defaults (line, vehicle, operation, doors, platform, driver, disturbances), each
    saying what to change first. Nothing that exists is overwritten."""
    from importlib import resources

    if directory.exists() and not directory.is_dir():
        fail(f"{directory}: exists and is not a folder")
    taken = [name for name, _, _ in STARTER if (directory / name).exists()]
    if taken:
        fail(f"{directory / taken[0]}: exists; railstop init never overwrites a file (choose another folder)")
    try:
        directory.mkdir(parents=True, exist_ok=True)
        for name, source, what in STARTER:
            text = resources.files("railstop.data").joinpath(source).read_text(encoding="utf-8")
            kind = name.removesuffix(".toml")
            shown = "" if kind == "disturbances" else f" (`railstop formats {kind}`)"
            header = (
                f"# railstop {kind} file, from the embedded railstop/data/{source}.\n# {what}\n"
                f"# Every key: docs/file-formats.md{shown}.\n\n"
            )
            with (directory / name).open("x", encoding="utf-8") as fh:  # never over a file
                fh.write(header + text)
    except OSError as exc:
        fail(f"{exc.filename or directory}: {exc.strerror}")
    out.print(f"wrote {len(STARTER)} files to {directory}:", highlight=False)
    for name, _, _ in STARTER:
        out.print(f"  {directory / name}", highlight=False)
    d = directory
    out.print(
        "next: edit them, then\n"
        f"  railstop check --line {d / 'line.toml'} --vehicle {d / 'vehicle.toml'} "
        f"--operation {d / 'operation.toml'}\n"
        f"  railstop campaign --line {d / 'line.toml'} --vehicle {d / 'vehicle.toml'} --runs 1000 "
        f"--disturbances {d / 'disturbances.toml'}",
        highlight=False,
        soft_wrap=True,
    )
