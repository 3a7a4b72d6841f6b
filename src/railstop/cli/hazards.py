"""``railstop hazards``: the hazard log as a table, or written out as Markdown."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from railstop.cli.common import fail, out
from railstop.errors import RailstopError


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
