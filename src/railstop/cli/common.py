"""What every ``railstop`` sub-command shares: the consoles and the one-line error exit."""

from __future__ import annotations

import dataclasses
import functools
import inspect
import math
import os
import sys
import typing
from collections import Counter
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, NoReturn, TypeVar

import typer
from rich.console import Console
from rich.text import Text
from typer.core import TyperGroup

from railstop.errors import RailstopError

if TYPE_CHECKING:
    from typer._click import Context, HelpFormatter

    from railstop.config.driver import DriverFile
    from railstop.config.platform import PlatformFile
    from railstop.config.schema import Station
    from railstop.control.law import LawFile
    from railstop.verify.invariants import Invariant, Verification

# Markup is off: names, traces and messages come from user data and are printed literally
# (a station "[A]" stays "[A]"); styled output is built from rich Text objects (styled()).
# Wide enough for the demo table when the output is a file or a pipe (unless COLUMNS says).
out = Console(width=None if sys.stdout.isatty() or "COLUMNS" in os.environ else 160, markup=False)
err = Console(stderr=True, markup=False)


# Every command's --help is click's plain text: paragraphs wrapped to the terminal, nothing cut.
# Typer's rich panels cut a word longer than their column with an ellipsis (a controller's name, a
# file name at 80 columns) and keep the docstrings' line breaks; a help text must never lose a word.
HELP_MARKUP = None


class HelpGroup(TyperGroup):
    """A command group whose list of commands shows each one's first paragraph whole, wrapped
    (click would cut it at the terminal's width with "...")."""

    def format_commands(self, ctx: Context, formatter: HelpFormatter) -> None:
        for name in self.list_commands(ctx):
            cmd = self.get_command(ctx, name)
            if cmd is not None and not cmd.short_help and cmd.help:
                first = inspect.cleandoc(cmd.help).split("\n\n", 1)[0]
                cmd.short_help = " ".join(first.split())
        super().format_commands(ctx, formatter)


def command_group(help: str, cls: type[TyperGroup] = HelpGroup) -> typer.Typer:
    """A command group of ``railstop`` (the program itself, ``line``, ``live``, ...): plain help that
    never cuts a word, no shell-completion options, its help when called without a command."""
    return typer.Typer(
        rich_markup_mode=HELP_MARKUP, cls=cls, add_completion=False, no_args_is_help=True, help=help
    )


_Command = TypeVar("_Command", bound=Callable[..., Any])


def with_option_groups(command: _Command) -> _Command:
    """Let a command take *option groups*: a parameter annotated with a dataclass whose fields are
    typer options (an ``Annotated`` type and a default each) stands for those options, which the
    command line shows in its place; the command receives the dataclass built from them.

    One group is one definition of options that several commands share (the line's settings, a
    live process's set-up), and one argument for the command instead of one per option."""
    hints = typing.get_type_hints(command, include_extras=True)
    groups: dict[str, tuple[type, tuple[str, ...]]] = {}
    params: list[inspect.Parameter] = []
    for name, param in inspect.signature(command).parameters.items():
        hint = hints.get(name, param.annotation)
        if isinstance(hint, type) and dataclasses.is_dataclass(hint):
            fields = typing.get_type_hints(hint, include_extras=True)
            names = tuple(f.name for f in dataclasses.fields(hint))
            for f in dataclasses.fields(hint):
                if f.default is dataclasses.MISSING:
                    raise TypeError(f"option group {hint.__name__}: field {f.name} needs a default")
                params.append(
                    inspect.Parameter(f.name, inspect.Parameter.KEYWORD_ONLY, default=f.default,
                                      annotation=fields[f.name])
                )  # fmt: skip
            groups[name] = (hint, names)
        else:
            params.append(param.replace(kind=inspect.Parameter.KEYWORD_ONLY, annotation=hint))
    clash = [n for n, c in Counter(p.name for p in params).items() if c > 1]
    if clash:
        raise TypeError(f"{command.__name__}: option names given twice: {clash}")

    @functools.wraps(command)
    def run(**kwargs: Any) -> Any:
        for name, (group, names) in groups.items():
            kwargs[name] = group(**{n: kwargs.pop(n) for n in names})
        return command(**kwargs)

    run.__signature__ = inspect.Signature(params)  # type: ignore[attr-defined]
    run.__annotations__ = {p.name: p.annotation for p in params}
    return typing.cast("_Command", run)


def styled(text: str, style: str) -> Text:
    """``text`` in ``style`` (e.g. "bold red"), never parsed as markup."""
    return Text(text, style=style)


def print_error(message: str) -> None:
    """Print ``error: message`` on stderr, literally (brackets are not markup), on one line."""
    err.print(Text.assemble(styled("error:", "bold red"), " ", message), highlight=False, soft_wrap=True)


def fail(message: str) -> NoReturn:
    """Print ``error: message`` and exit with code 2."""
    print_error(message)
    raise typer.Exit(2)


def check_db_options(ctx: typer.Context, no_db: bool) -> None:
    """``--no-db`` with a ``--db`` given on the command line: refused (they exclude each other)."""
    source = ctx.get_parameter_source("db")
    if no_db and source is not None and source.name == "COMMANDLINE":
        fail("--db and --no-db exclude each other")


# Options several commands share (one definition, one help text).
LawOpt = Annotated[
    Path | None,
    typer.Option(
        "--law",
        help="A Python file of stop-control laws (docs/control-law.md): each becomes a controller.",
    ),
]
LineOpt = Annotated[Path | None, typer.Option("--line", help="Line TOML file (default: embedded line).")]
VehicleOpt = Annotated[
    Path | None, typer.Option("--vehicle", help="Vehicle TOML file (default: embedded EMU).")
]
DriverOpt = Annotated[
    Path | None,
    typer.Option("--driver", help="Driver TOML file for the driver-* controllers (default: embedded)."),
]
PlatformOpt = Annotated[
    Path | None,
    typer.Option(
        "--platform", help="Platform TOML file: stop sensors, lamps, camera, approach (default: embedded)."
    ),
]
SchedulerOpt = Annotated[
    str | None,
    typer.Option(help="Run the chunks on the Dask scheduler at this address (tcp://HOST:PORT)."),
]
OperationOpt = Annotated[
    Path | None,
    typer.Option("--operation", help="Operation TOML file: trains, headway, dwells (default: embedded)."),
]


def print_verification(
    *,
    title: str,
    invariants: Sequence[Invariant[Any]],
    result: Verification,
    notes: Sequence[str] = (),
) -> None:
    """What every ``... verify`` command prints: the invariants with their violations, the first
    counterexample of each with its trace, notes, and the totals line."""
    from rich.table import Table

    table = Table(title=title)
    table.add_column("invariant")
    table.add_column("what it checks")
    table.add_column("violations", justify="right")
    for inv in invariants:
        n = result.counts.get(inv.name, 0)
        table.add_row(inv.name, inv.text, styled(str(n), "bold red") if n else "0")
    out.print(table)
    for ex in result.examples:
        out.print(Text.assemble(styled(ex.invariant, "bold red"), f": {ex.message}; trace:"), highlight=False)
        for line in ex.trace:
            out.print(f"  {line}", highlight=False, soft_wrap=True)
    for note in notes:
        out.print(note, highlight=False, soft_wrap=True)
    out.print(
        f"states: {result.states}  transitions: {result.transitions}  violations: {result.violations}  "
        f"({result.elapsed_s:.1f} s)",
        highlight=False,
    )


def load_law(path: Path | None) -> LawFile | None:
    """Load the laws of ``--law`` (their names become controllers): the file as a campaign records
    it; bad input fails with one line naming the file (exit 2)."""
    if path is None:
        return None
    from railstop.control.law import LawFile  # numba: loaded only when a law is given

    try:
        law = LawFile.of(path)
        law.load()
    except RailstopError as exc:
        fail(f"--law: {exc}")
    return law


def load_manual_data(
    driver: Path | None, platform: Path | None, controllers: Sequence[str] = ()
) -> tuple[DriverFile | None, PlatformFile | None]:
    """The ``--driver`` / ``--platform`` files (None where not given). ``controllers``: the ones the
    command runs; the files are refused when none of them is a driver controller (they would
    change nothing, which a user would not expect)."""
    from railstop.config.driver import load_driver
    from railstop.config.platform import load_platform
    from railstop.controllers import DRIVER_CONTROLLERS

    if controllers and not any(c in DRIVER_CONTROLLERS for c in controllers):
        for option, value in (("--driver", driver), ("--platform", platform)):
            if value is not None:
                raise RailstopError(
                    f"{option}: only the driver controllers ({', '.join(DRIVER_CONTROLLERS)}) use it "
                    f"(got --controller {controllers[0]})"
                )
    return (
        None if driver is None else load_driver(driver)[0],
        None if platform is None else load_platform(platform)[0],
    )


def address_option(text: str, option: str) -> tuple[str, int]:
    """A ``HOST:PORT`` option as (host, port), or a RailstopError naming the option."""
    host, _, port = text.rpartition(":")
    if not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise RailstopError(f"{option}: HOST:PORT expected (got {text!r})")
    return host, int(port)


def stop_error_option(text: str | None) -> float | None:
    """``--stop-error-m`` (a stand this far from the stopping point, + = past it) as a finite
    number, None when not given; anything else exits with a one-line error."""
    if text is None:
        return None
    try:
        error_m = float(text)
    except ValueError:
        fail(f"--stop-error-m: not a number (got {text!r})")
    if not math.isfinite(error_m):
        fail(f"--stop-error-m: must be a finite number (got {text!r})")
    return error_m


def stand_on_platform(error_m: float, station: Station) -> None:
    """A stand the dwell can start from: the train at the platform, or a one-line error."""
    if abs(error_m) >= station.platform_length_m:
        fail(
            f"--stop-error-m: {error_m:+g} m puts the train off the {station.platform_length_m:g} m "
            f"platform of {station.name}"
        )


#: The simulators' (stop, campaign, line run) sender id at the office (the live processes use
#: 800-802); inside the office's default ``--senders 1-899``.
SIMULATOR_OFFICE_ID = 810

OfficeOpt = Annotated[
    str | None,
    typer.Option(
        "--office",
        metavar="HOST:PORT",
        help="Also send the records to a running management office (SPEC §1 claims 7, 20), with the "
        "links' key of RAILSTOP_OFFICE_KEY; the local records are written first.",
    ),
]


def office_target(office: str | None) -> tuple[str, tuple[str, int], bytes] | None:
    """``--office HOST:PORT`` checked before any work is done: (the option, its address, the links'
    key from RAILSTOP_OFFICE_KEY), or None without the option; a RailstopError (one line) for a bad
    address or a missing or bad key."""
    if office is None:
        return None
    from railstop.cli.office import master_key  # lazy: CLI start-up

    address = address_option(office, "--office")
    if not os.environ.get("RAILSTOP_OFFICE_KEY"):
        raise RailstopError(
            f"--office {office}: the office link's master key is needed: set RAILSTOP_OFFICE_KEY (hex, "
            "the office's key; never on the command line)"
        )
    return office, address, master_key(None)


def send_to_office(
    target: tuple[str, tuple[str, int], bytes], reports: list[tuple[str, dict[str, object]]]
) -> dict[str, object]:
    """Send ``reports`` ((kind, data) each) to the office of ``target`` (:func:`office_target`) over
    its authenticated link (``live.office.OfficeClient``: sent again until acknowledged) as sender
    :data:`SIMULATOR_OFFICE_ID`; the link's counts. A RailstopError (one line) when the office does
    not acknowledge every report in time: what was written locally stays."""
    import asyncio

    from railstop.link.udp import EpochClock
    from railstop.live.office import OfficeClient

    office, address, key = target
    timeout_s = 5.0 + 0.05 * len(reports)

    async def main() -> dict[str, object]:
        async with OfficeClient(
            own_id=SIMULATOR_OFFICE_ID, office=address, master_key=key, clock=EpochClock(0.0)
        ) as client:
            for kind, data in reports:
                client.report(kind, data)
            drained = await client.drain(timeout_s=timeout_s)
            return {**client.outbox.counts, "pending": client.pending, "drained": drained}

    try:
        counts = asyncio.run(main())
    except OSError as exc:
        raise RailstopError(f"--office {office}: {exc.strerror or exc}") from None
    if not counts["drained"]:
        raise RailstopError(
            f"--office {office}: {counts['pending']} of {len(reports)} reports not acknowledged within "
            f"{timeout_s:g} s (is the office serving there, with this key, taking sender "
            f"{SIMULATOR_OFFICE_ID} and these kinds?); the local records are kept"
        )
    return counts
