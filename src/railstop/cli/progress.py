"""Progress and interruption of long commands (campaign, compare, certify, demo, report).

Progress goes to stderr, so ``--json`` output on stdout stays one object:

- on a terminal, a rich bar with the count, the rate and the time left;
- otherwise (a pipe, a log file, CI) one status line every ``RAILSTOP_STATUS_S``
  seconds (default 10; 0 turns them off), e.g. ``railstop: tasc-pwm at Riverside: 30,000/100,000
  runs (30 %), 4,210 runs/s, about 17 s left``, so a long job is never silent.

The rate and the time left are measured from the first update of this call:
the runs a ``--resume`` found finished do not count as speed.

Interruption: :func:`install_signal_handlers` turns SIGINT, SIGTERM and SIGHUP
into :class:`Terminated` (a ``KeyboardInterrupt``), so a ``kill`` unwinds like
Ctrl-C: pools stop, finished chunks stay, nothing is half-written. A command
says what an interruption keeps with :func:`on_interrupt`; :func:`run_program` prints
it in one line and exits with 128 + the signal number (130, 143, 129).
"""

from __future__ import annotations

import contextlib
import math
import os
import signal
import sys
import time
from collections.abc import Callable, Iterator
from types import FrameType
from typing import Any, NoReturn

import typer

from railstop.cli.common import err
from railstop.errors import RailstopError

DEFAULT_STATUS_S = 10.0


_received: list[int] = []  # the signal that interrupted this process, if any


class Terminated(KeyboardInterrupt):
    """The process got SIGINT (Ctrl-C), SIGTERM or SIGHUP; ``signum`` says which."""

    def __init__(self, signum: int) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


def _interrupt(signum: int, _frame: FrameType | None) -> None:
    if _received:  # a second signal: the clean-up hangs, or the user insists
        os._exit(128 + _received[0])
    _received.append(signum)
    raise Terminated(signum)


def install_signal_handlers() -> None:
    """SIGINT, SIGTERM and SIGHUP unwind the main thread as :class:`Terminated` (a second one
    ends the process at once), and the signal is remembered for :func:`run_program`'s message: Typer
    turns a ``KeyboardInterrupt`` into a silent exit 130, whatever the signal."""
    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        signal.signal(sig, _interrupt)


_notes: list[str] = []  # what the interrupted commands kept, outermost last


@contextlib.contextmanager
def on_interrupt(describe: Callable[[], str]) -> Iterator[None]:
    """If the block is interrupted, ``describe()`` (called then) says what the interruption kept."""
    try:
        yield
    except KeyboardInterrupt:
        with contextlib.suppress(Exception):  # a note is best effort; the exit code is not
            _notes.append(describe())
        raise


def interrupted_message(signum: int) -> str:
    """One line: what stopped the command and what it kept."""
    cause = "interrupted" if signum == signal.SIGINT else f"terminated ({signal.Signals(signum).name})"
    notes = list(_notes)
    _notes.clear()
    return f"{cause}: {'; '.join(notes)}" if notes else cause


def status_interval() -> float:
    try:
        value = float(os.environ.get("RAILSTOP_STATUS_S", DEFAULT_STATUS_S))
    except ValueError:
        return DEFAULT_STATUS_S
    if value == 0:  # status lines off
        return math.inf
    return value if math.isfinite(value) and value > 0 else DEFAULT_STATUS_S


def _duration(seconds: float) -> str:
    s = round(seconds)
    if s < 60:
        return f"{s} s"
    if s < 3600:
        return f"{s // 60} min {s % 60:02d} s"
    if s < 86400:
        return f"{s // 3600} h {s % 3600 // 60:02d} min"
    return f"{s // 86400} d {s % 86400 // 3600:02d} h"


class Reporter:
    """Progress of one job on stderr (see the module docstring); a context manager.

    ``update(done, total)`` with the counts in ``unit`` (e.g. ``runs``); the
    first call sets the baseline for the rate. ``enabled=False``: silent.
    """

    def __init__(self, label: str, *, unit: str = "runs", enabled: bool = True) -> None:
        self.label = label
        self.unit = unit
        self.enabled = enabled
        self.terminal = err.is_terminal
        self.every_s = status_interval()
        self._bar: Any = None
        self._task: Any = None
        self._base: tuple[float, int] | None = None
        self._last_line = time.monotonic()

    def __enter__(self) -> Reporter:
        if self.enabled and self.terminal:
            from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn

            self._bar = Progress(
                TextColumn("{task.description}", markup=False),  # the label is a value: literal
                BarColumn(),
                MofNCompleteColumn(),
                TextColumn("{task.fields[rate]}", markup=False),
                TextColumn("{task.fields[left]}", markup=False),
                console=err,
                transient=True,
            )
            self._bar.__enter__()
            self._task = self._bar.add_task(self.label, total=None, rate="", left="")
        return self

    def stage(self, label: str) -> None:
        """A new stage of the job (e.g. a tuning level, then the estimation): new label and baseline."""
        if label == self.label:
            return
        self.label = label
        self._base = None
        if self._bar is not None:
            self._bar.remove_task(self._task)
            self._task = self._bar.add_task(self.label, total=None, rate="", left="")

    def __exit__(self, *exc: object) -> None:
        if self._bar is not None:
            self._bar.__exit__(*exc)
            self._bar = None

    def rate_and_left(self, done: int, total: int) -> tuple[float | None, float | None]:
        """Units per second since the baseline, and the seconds left at that rate (None: unknown)."""
        now = time.monotonic()
        if self._base is None:
            self._base = (now, done)
            return None, None
        t0, d0 = self._base
        if now <= t0 or done <= d0:
            return None, None
        rate = (done - d0) / (now - t0)
        return rate, max(total - done, 0) / rate

    def update(self, done: int, total: int) -> None:
        if not self.enabled:
            return
        rate, left = self.rate_and_left(done, total)
        rate_text = (
            ""
            if rate is None
            else f"{rate:,.0f} {self.unit}/s"
            if rate >= 10
            else f"{rate:.2g} {self.unit}/s"
        )
        left_text = "" if left is None else f"about {_duration(left)} left"
        if self._bar is not None:
            self._bar.update(self._task, completed=done, total=total, rate=rate_text, left=left_text)
            return
        now = time.monotonic()
        if now - self._last_line < self.every_s:
            return
        self._last_line = now
        pct = f" ({100.0 * done / total:.0f} %)" if total else ""
        parts = [f"{done:,}/{total:,} {self.unit}{pct}", rate_text, left_text]
        line = f"railstop: {self.label}: {', '.join(p for p in parts if p)}"
        err.print(line, highlight=False, soft_wrap=True)


def _rejected_value(exc: BaseException) -> str | None:
    """The value the user typed, when Typer refused it through a pydantic check (its message
    says what was wrong but not what was given)."""
    cause = exc.__cause__
    errors = getattr(cause, "errors", None)
    if not callable(errors):
        return None
    try:
        first = errors()[0]
    except (IndexError, TypeError, ValueError):
        return None
    value = first.get("input") if isinstance(first, dict) else None
    return None if value is None else str(value)


def _click_exceptions() -> Any:
    import importlib

    try:  # recent Typer carries its own copy of click
        return importlib.import_module("typer._click.exceptions")
    except ImportError:
        return importlib.import_module("click.exceptions")


def empty_option(argv: list[str]) -> str | None:
    """The option given an empty value (``--out ""``, ``--out=``), or None. Every option of
    railstop takes a path, a name or a number: an empty one is never meant (a path "" would be
    the current folder, a name "" matches nothing), so it is refused as a class."""
    for i, arg in enumerate(argv):
        if arg == "--":
            return None
        if arg.startswith("--") and arg.endswith("=") and len(arg) > 3:
            return arg[:-1]
        if arg.strip() == "":
            before = argv[i - 1] if i > 0 else ""
            return before if before.startswith("-") and "=" not in before else f"argument {i + 1}"
    return None


def _tolerate_any_terminal_encoding() -> None:
    """A terminal or pipe that cannot show a character (ASCII, Latin-1: ``±``, ``‰``, ``§``)
    gets a replacement for it instead of a UnicodeEncodeError in the middle of a result: the
    class of "non-UTF-8 terminal" closed for every command at once."""
    for stream in (sys.stdout, sys.stderr):
        reconfigure = getattr(stream, "reconfigure", None)
        if reconfigure is not None:
            with contextlib.suppress(ValueError, OSError):
                reconfigure(errors="replace")


def run_program(app: Any) -> NoReturn:
    """Run the Typer ``app`` as the ``railstop`` program and exit.

    Every error is one line on stderr: a usage error (bad option value, unknown
    option or command) prints ``error: railstop CMD: message (see railstop CMD
    --help)`` with exit code 2 instead of Typer's framed box. An interruption
    prints what was kept (:func:`on_interrupt`) and exits with 128 + the signal.
    """
    exceptions = _click_exceptions()
    install_signal_handlers()
    _tolerate_any_terminal_encoding()
    empty = empty_option(sys.argv[1:])
    if empty is not None:  # before any command runs: `--out ""` would be the current folder
        err.print(f"error: {empty}: an empty value; give one", highlight=False, soft_wrap=True)
        sys.exit(2)
    code: Any = 0
    try:
        code = app(standalone_mode=False, prog_name="railstop")
    except exceptions.NoArgsIsHelpError as exc:  # `railstop` alone: the help
        print(exc.ctx.get_help() if exc.ctx is not None else exc.format_message())
        code = 0
    except exceptions.ClickException as exc:
        ctx = getattr(exc, "ctx", None)
        where = ctx.command_path if ctx is not None else "railstop"
        message = " ".join(exc.format_message().split())
        given = _rejected_value(exc)
        if given is not None and "(got " not in message:
            message = f"{message.rstrip('.')} (got {given})"
        hint = f" (see {where} --help)" if isinstance(exc, exceptions.UsageError) else ""
        err.print(f"error: {where}: {message}{hint}", highlight=False, soft_wrap=True)
        code = exc.exit_code
    except typer.Abort:
        code = 1
    except RailstopError as exc:  # one that escaped a command (an import-time check): one line too
        err.print(f"error: {exc}", highlight=False, soft_wrap=True)
        code = 2
    except KeyboardInterrupt:  # raised outside Typer's command call
        pass
    if _received:
        err.print(interrupted_message(_received[0]), highlight=False, soft_wrap=True)
        sys.exit(128 + _received[0])
    sys.exit(code if isinstance(code, int) else 0)
