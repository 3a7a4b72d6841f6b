"""The ``railstop`` command: the app assembled from the command modules of ``railstop.cli``.

One module per command group: ``stop`` (stop, compile), ``campaign`` (campaign, compare, certify,
report), ``demo``, ``check``, ``formats`` (and init), ``hazards``, ``doors`` (and dwell),
``telegram``, ``line``, ``zones``, ``platform``, ``office``, ``live``, ``importer`` (import railml),
``position`` (position-run);
``common`` and ``progress`` are what they share.

Start-up is kept short: the command modules import only what builds the command line
(typer, the consoles, the controller names its help quotes); every command
imports what it runs when it runs. ``stop --json --no-db`` thus loads the
simulation engine but not SQLAlchemy, matplotlib or pyarrow, and
``position-run`` (whose help quotes the whole-line simulation's defaults) is
built only when it is used.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Annotated, Any

import typer
from typer.core import TyperCommand

# The command modules named as modules: ``railstop.cli.stop`` stays the module, not its command.
from railstop.cli import campaign, check, demo, formats, hazards, stop
from railstop.cli.common import HELP_MARKUP, HelpGroup, command_group
from railstop.cli.doors import doors_app, dwell
from railstop.cli.importer import import_app
from railstop.cli.line import line_app
from railstop.cli.live import live_app
from railstop.cli.office import office_app
from railstop.cli.platform import platform_app
from railstop.cli.progress import run_program
from railstop.cli.telegram import telegram_app
from railstop.cli.zones import zones_app

if TYPE_CHECKING:
    from typer._click import Command, Context

_POSITION_RUN = "position-run"
# Listed by `railstop --help` with this line (the command's own docstring, kept equal by a test in
# tests/cli/test_cli_startup.py); built only when it is run or asked for its own help.
POSITION_RUN_HELP = (
    "One train over the whole line (a one-train line run): raw, corrected (SPEC §2) and calibrated "
    "position errors."
)
_UNBUILT: Command = TyperCommand(name=_POSITION_RUN, help=POSITION_RUN_HELP, short_help=POSITION_RUN_HELP)


def _position_run_command() -> Command:
    """``position-run`` as a click command: imports ``railstop.sim.position_run`` for its help."""
    from railstop.cli.position import position_run

    sub = typer.Typer(add_completion=False, rich_markup_mode=HELP_MARKUP)
    sub.command(name=_POSITION_RUN)(position_run)
    return typer.main.get_command(sub)


class _Group(HelpGroup):
    """The ``railstop`` group, with ``position-run`` built on first use (run or its own help; the
    group's help lists its placeholder, so ``railstop --help`` does not import the line model)."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        # A placeholder keeps the listing order (after `dwell`) and the "did you mean" suggestions.
        commands = dict(self.commands)
        self.commands = {}
        for name, command in commands.items():
            self.commands[name] = command
            if name == "dwell":
                self.commands[_POSITION_RUN] = _UNBUILT

    def resolve_command(self, ctx: Context, args: list[str]) -> tuple[str | None, Command | None, list[str]]:
        if args and self.commands.get(args[0]) is _UNBUILT:
            self.commands[args[0]] = _position_run_command()
        return super().resolve_command(ctx, args)


app = command_group(
    "railstop: precise station stopping for urban rail (ground TASC and its simulator).", cls=_Group
)


def _version(value: bool) -> None:
    if value:
        from railstop import __version__

        print(f"railstop {__version__}")
        raise typer.Exit(0)


@app.callback()
def _main_options(
    version: Annotated[
        bool, typer.Option("--version", callback=_version, is_eager=True, help="Print the version and exit.")
    ] = False,
) -> None:
    """railstop: precise station stopping for urban rail (ground TASC and its simulator)."""


# The listing order of `railstop --help`: the commands as registered here (position-run after
# dwell, see _Group), then the groups.
app.add_typer(doors_app, name="doors")
app.command()(dwell)
app.add_typer(telegram_app, name="telegram")
app.add_typer(line_app, name="line")
app.add_typer(zones_app, name="zones")
app.add_typer(platform_app, name="platform")
app.add_typer(office_app, name="office")
app.add_typer(live_app, name="live")
app.add_typer(import_app, name="import")
app.command()(formats.init)
app.command()(check.check)
app.command()(formats.formats)
app.command()(stop.stop)
app.command(name="compile")(stop.compile_model)
app.command()(demo.demo)
app.command()(campaign.campaign)
app.command()(campaign.compare)
app.command()(campaign.certify)
app.command()(campaign.report)
app.command()(hazards.hazards)


def main() -> None:
    run_program(app)
