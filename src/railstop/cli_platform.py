"""``railstop platform verify``: the platform interlock of SPEC §3, checked exhaustively."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from railstop.cli_common import fail, out, print_verification
from railstop.errors import RailstopError

platform_app = typer.Typer(
    add_completion=False,
    no_args_is_help=True,
    help="The platform of a manually driven line (SPEC §3): stop sensors, lamps, PSD relay.",
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
    platform: Annotated[
        Path | None, typer.Option("--platform", help="Platform TOML file (default: embedded).")
    ] = None,
) -> None:
    """Every reachable state of the real platform unit under every event; exit 1 on a violation."""
    from railstop.config.platform import load_platform
    from railstop.sim.platform_verify import INVARIANTS, verify
    from railstop.wayside.platform import PlatformUnit

    try:
        data, source = load_platform(platform)
        k = data.sensors.debounce_scans
        drops = k - 1 if max_dropouts is None else max_dropouts
        result = verify(lambda: PlatformUnit(lamp_table=data.lamps(), debounce_scans=k), max_dropouts=drops)
    except RailstopError as exc:
        fail(str(exc))
    out.print(
        f"platform verify ({source}): the real platform unit, debounce {k} scans, up to {drops} "
        "missed scans in a row per sensor; train stops short / in the window / past, starts, doors, "
        "PSD following the doors, the signal-open switch",
        highlight=False,
        soft_wrap=True,
    )
    print_verification(title="invariants", invariants=INVARIANTS, result=result)
    if result.violations:
        raise typer.Exit(1)
