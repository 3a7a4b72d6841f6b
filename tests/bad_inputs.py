"""The bad-input sweep: inputs every ``railstop`` command (and ``python -m railstop.link.udp``) must refuse
with exactly one ``error: ...`` line on stderr, exit code 2 and no traceback.

Project rule: "Bad input gets a clear error and loses nothing: one line naming the file, field and
value, exit code 2, never a traceback."

:data:`CASES` lists the cases; :func:`run_case` runs one in a folder (its files are created there and
it is the working directory, so paths in ``argv`` are relative to it) and returns an :class:`Outcome`.
``tests/e2e/test_bad_input_sweep.py`` runs each as a test, ``benchmarks/bad_input_sweep.py`` as a table.

Every case is quick when refused: a campaign or comparison is given ``--runs 2``, a certification
``--runs 100 --tuning-runs 100``, so that an input wrongly accepted costs seconds, not minutes.
"""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
import time
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

CLI = "railstop.cli"
UDP = "railstop.link.udp"
TIMEOUT_S = 120.0
ERROR_PREFIX = "error: "


@dataclass(frozen=True, slots=True)
class Case:
    """One bad input: ``argv`` after ``python -m MODULE``, the files and folders it needs, and
    the substrings its error line must contain."""

    id: str
    argv: tuple[str, ...]
    files: Mapping[str, str | bytes] = field(default_factory=dict)
    dirs: tuple[str, ...] = ()
    needles: tuple[str, ...] = ()
    module: str = CLI
    modes: Mapping[str, int] = field(default_factory=dict)  # file name -> permission bits (chmod)

    def command(self) -> list[str]:
        return [sys.executable, "-m", self.module, *self.argv]

    def shell(self) -> str:
        """The command as one would type it."""
        program = "railstop" if self.module == CLI else f"python -m {self.module}"
        return f"{program} {shlex.join(self.argv)}".rstrip()

    def materialise(self, where: Path) -> None:
        """Create the case's folders and files under ``where``."""
        for name in self.dirs:
            (where / name).mkdir(parents=True, exist_ok=True)
        for name, content in self.files.items():
            path = where / name
            path.parent.mkdir(parents=True, exist_ok=True)
            if isinstance(content, bytes):
                path.write_bytes(content)
            else:
                path.write_text(content, encoding="utf-8")
        for name, mode in self.modes.items():
            (where / name).chmod(mode)


@dataclass(frozen=True, slots=True)
class Outcome:
    """What a case did: its exit code (None: timed out), output and wall time."""

    case: Case
    returncode: int | None
    stdout: str
    stderr: str
    seconds: float

    @property
    def lines(self) -> list[str]:
        """The non-empty lines on stderr."""
        return [ln for ln in self.stderr.splitlines() if ln.strip()]

    @property
    def traceback(self) -> bool:
        return "Traceback" in self.stdout or "Traceback" in self.stderr

    def problems(self) -> list[str]:
        """Why the outcome breaks the rule; empty when it is one ``error:`` line with exit code 2."""
        found: list[str] = []
        if self.returncode is None:
            return [f"timed out after {TIMEOUT_S:g} s"]
        if self.traceback:
            found.append("traceback")
        if self.returncode != 2:
            found.append(f"exit code {self.returncode}")
        lines = self.lines
        if len(lines) != 1:
            found.append(f"{len(lines)} lines on stderr")
        elif not lines[0].startswith(ERROR_PREFIX):
            found.append(f"stderr does not start with {ERROR_PREFIX!r}")
        else:
            missing = [n for n in self.case.needles if n not in lines[0]]
            if missing:
                found.append(f"error line lacks {missing!r}")
        return found

    @property
    def verdict(self) -> str:
        """``ok`` (one line, exit 2), ``traceback`` or ``other``."""
        if not self.problems():
            return "ok"
        return "traceback" if self.traceback else "other"


def environment() -> dict[str, str]:
    """The environment of a case: no periodic status lines, no colour codes."""
    env = dict(os.environ)
    env["RAILSTOP_STATUS_S"] = "0"
    env["NO_COLOR"] = "1"
    env.pop("FORCE_COLOR", None)
    return env


def run_case(case: Case, where: Path, *, timeout_s: float = TIMEOUT_S, zygote: Any = None) -> Outcome:
    """Create the case's files in ``where`` and run it there: in a fresh interpreter, or in a
    process forked from ``zygote`` (``tests/zygote.py``: the same command, without paying its
    imports again)."""
    case.materialise(where)
    t0 = time.perf_counter()
    if zygote is not None:
        rc, out, err = zygote.run(case.module, case.argv, cwd=where, env=environment(), timeout_s=timeout_s)
        return Outcome(case, rc, out, err, time.perf_counter() - t0)
    try:
        p = subprocess.run(
            case.command(),
            cwd=where,
            env=environment(),
            capture_output=True,
            text=True,
            errors="replace",
            timeout=timeout_s,
            check=False,
        )
    except subprocess.TimeoutExpired as exc:
        out = exc.stdout.decode(errors="replace") if isinstance(exc.stdout, bytes) else exc.stdout or ""
        err = exc.stderr.decode(errors="replace") if isinstance(exc.stderr, bytes) else exc.stderr or ""
        return Outcome(case, None, out, err, time.perf_counter() - t0)
    return Outcome(case, p.returncode, p.stdout, p.stderr, time.perf_counter() - t0)


# --------------------------------------------------------------------------
# Data files: the embedded ones, each with one thing wrong.


def _data(name: str) -> str:
    return resources.files("railstop.data").joinpath(name).read_text(encoding="utf-8")


LINE = _data("line.toml")
VEHICLE = _data("vehicle.toml")
DOORS = _data("doors.toml")
STANDARD = resources.files("railstop.data.disturbances").joinpath("standard.toml").read_text(encoding="utf-8")


def edit(text: str, old: str, new: str) -> str:
    """``text`` with the first ``old`` replaced by ``new``; ``old`` must be there (a case that
    silently stopped editing anything would test a valid file)."""
    if old not in text:
        raise ValueError(f"bad_inputs: {old!r} is not in the data file")
    return text.replace(old, new, 1)


def edit_re(text: str, pattern: str, new: str) -> str:
    """``text`` with the first match of the regular expression ``pattern`` replaced by ``new``."""
    out, n = re.subn(pattern, new, text, count=1, flags=re.DOTALL | re.MULTILINE)
    if n != 1:
        raise ValueError(f"bad_inputs: {pattern!r} does not match the data file")
    return out


BINARY = bytes(range(256)) * 4  # NUL and every byte: not UTF-8
LATIN1 = '[line]\nname = "Gare de l\'Est é"\n'.encode("latin-1")  # not UTF-8
NUL_TOML = b'[line]\nname = "x\x00y"\n'  # UTF-8, but TOML refuses the control character
BAD_TOML = "[line\nname = 'unterminated\n"
HUGE = str(10**30)
TWO_63 = str(2**63)
TWO_64 = str(2**64)

CASES: list[Case] = []


def tag(value: str) -> str:
    """A short id part for an option value."""
    if not value:
        return "empty"
    if value in (TWO_63, TWO_64):
        return "2-63" if value == TWO_63 else "2-64"
    return value.replace("-", "minus-")[:12]


def add(
    id: str,
    *argv: str,
    files: Mapping[str, str | bytes] | None = None,
    dirs: Iterable[str] = (),
    needles: Iterable[str] = (),
    module: str = CLI,
    modes: Mapping[str, int] | None = None,
) -> None:
    files, modes = dict(files or {}), dict(modes or {})
    if any(argv[i : i + 2] == LIVE_KEY for i in range(len(argv))) and LIVE_KEY[1] not in files:
        # A case that names the live processes' key file gets it, valid and private (mode 0600):
        # the case then shows the refusal of its other input, not of the key.
        files[LIVE_KEY[1]] = LIVE_KEY_TEXT
        modes.setdefault(LIVE_KEY[1], 0o600)
    CASES.append(Case(id, tuple(argv), files, tuple(dirs), tuple(needles), module, modes))


# The links' master key of the live processes and the office: a key file (never --key-hex).
LIVE_KEY = ("--key-file", "live.key")
LIVE_KEY_TEXT = "00112233445566778899aabbccddeeff\n"


# --------------------------------------------------------------------------
# railstop itself: unknown commands and options

add("top-unknown-command", "nosuch", needles=("No such command",))
add("top-misspelt-command", "campain", needles=("Did you mean 'campaign'",))
add("top-empty-command", "")
add("top-bracket-command", "[bold]x", needles=("[bold]x",))
add("top-unknown-option", "--nosuch", needles=("--nosuch",))
add("top-version-with-value", "--version=yes", needles=("--version",))
add("doors-unknown-subcommand", "doors", "nosuch", needles=("nosuch",))
add("telegram-unknown-subcommand", "telegram", "nosuch", needles=("nosuch",))

# --------------------------------------------------------------------------
# railstop check: line and vehicle files

# (id, file content, needles): line files with one thing wrong.
LINE_CASES: list[tuple[str, str | bytes, tuple[str, ...]]] = [
    ("empty", "", ("line", "Field required")),
    ("binary", BINARY, ("not UTF-8",)),
    ("latin1", LATIN1, ("not UTF-8",)),
    ("nul", NUL_TOML, ("toml syntax",)),
    ("syntax", BAD_TOML, ("toml syntax",)),
    ("unknown-top-key", "colour = 'red'\n" + LINE, ("colour", "unknown key")),
    ("bracket-key", '"[bold]" = 1\n' + LINE, ("[bold]", "unknown key")),
    ("no-stations", edit_re(LINE, r"^\[\[stations\]\].*\Z", ""), ("stations",)),
    ("station-name-number", edit(LINE, 'name = "Riverside"', "name = 5"), ("stations[0].name", "5")),
    (
        "duplicate-bracket-names",
        edit(edit(LINE, 'name = "Riverside"', 'name = "[/]"'), 'name = "Hillcrest"', 'name = "[/]"'),
        ("stations", "[/]"),
    ),
    (
        "stop-point-nan",
        edit(LINE, "stop_point_m = 1200.0", "stop_point_m = nan"),
        ("stations[0].stop_point_m",),
    ),
    (
        "stop-point-huge",
        edit(LINE, "stop_point_m = 5600.0", f"stop_point_m = {HUGE}"),
        ("stations[3].stop_point_m", "Harbour"),
    ),
    ("platform-side", edit(LINE, 'platform_side = "R"', 'platform_side = "X"'), ("platform_side", "'X'")),
    (
        "one-detector",
        edit(LINE, "[330.0, 230.0, 140.0, 60.0, 6.0]", "[6.0]"),
        ("detectors_before_stop_m", "at least 2"),
    ),
    (
        # Only Museum (65 km/h) enters above 62 km/h: one problem, one line.
        "entry-speed-over-limit",
        edit(LINE, "speed_limit_kmh = 80.0", "speed_limit_kmh = 62.0"),
        ("stations[2].tasc.entry_speed_kmh", "65"),
    ),
    (
        "signal-form-2-63",
        edit(LINE, "entry_speed_kmh = 60.0", f"entry_speed_kmh = 60.0\nsignal_form = {TWO_63}"),
        ("signal_form", TWO_63),
    ),
    (
        "medium-unknown",
        edit(LINE, "entry_speed_kmh = 60.0", 'entry_speed_kmh = 60.0\nmedium = "pigeon"'),
        ("stations[0].tasc.medium", "pigeon"),
    ),
    ("circuit-id-huge", edit(LINE, "{ id = 101,", "{ id = 70000,"), ("circuits[0].id", "70000")),
    # A number written as a string is refused, not converted (the schemas are strict): a quoted
    # value is a typing error somewhere, and the data must say what it means.
    (
        "stop-point-string",
        edit(LINE, "stop_point_m = 1200.0", 'stop_point_m = "1200"'),
        ("stop_point_m", "'1200'"),
    ),
    ("circuit-id-string", edit(LINE, "{ id = 101,", '{ id = "101",'), ("circuits[0].id", "'101'")),
    (
        "doppler-flag-string",
        edit(LINE, "compensate = true", 'compensate = "yes"'),
        ("cbtc.compensate", "'yes'"),
    ),
    ("holdover-inf", edit(LINE, "holdover_s = 86400.0", "holdover_s = inf"), ("holdover_s",)),
]
for name, text, needles in LINE_CASES:
    add(
        f"check-line-{name}",
        "check",
        "--line",
        "bad.toml",
        files={"bad.toml": text},
        needles=("bad.toml", *needles),
    )
add("check-line-missing", "check", "--line", "missing.toml", needles=("missing.toml", "no such file"))
add("check-line-folder", "check", "--line", "adir", dirs=["adir"], needles=("adir",))
add("check-line-bracket-path", "check", "--line", "[bold]x.toml", needles=("[bold]x.toml",))

# (id, file content, needles): vehicle files with one thing wrong.
VEHICLE_CASES: list[tuple[str, str | bytes, tuple[str, ...]]] = [
    ("empty", "", ("vehicle", "Field required")),
    ("binary", BINARY, ("not UTF-8",)),
    ("unknown-key", edit(VEHICLE, "cars = 6", "cars = 6\ncolour = 'red'"), ("vehicle.colour", "unknown key")),
    ("cars-float", edit(VEHICLE, "cars = 6", "cars = 6.5"), ("vehicle.cars", "6.5")),
    (
        "six-notches",
        edit(
            VEHICLE,
            "[0.143, 0.286, 0.429, 0.571, 0.714, 0.857, 1.0]",
            "[0.143, 0.286, 0.429, 0.571, 0.714, 1.0]",
        ),
        ("notch_decel_mps2",),
    ),
    (
        "pulses-huge",
        edit(VEHICLE, "tachometer_pulses_per_rev = 100", f"tachometer_pulses_per_rev = {HUGE}"),
        ("tachometer_pulses_per_rev", HUGE),
    ),
    # Physically impossible vehicles (issue 38): each a value no train has.
    (
        "tare-1e308",
        edit(VEHICLE, "tare_mass_kg = 200000.0", "tare_mass_kg = 1e308"),
        ("vehicle.tare_mass_kg",),
    ),
    (
        "tare-per-car",
        edit(VEHICLE, "tare_mass_kg = 200000.0", "tare_mass_kg = 2000.0"),
        ("tare_mass_kg", "per car"),
    ),
    ("length-per-car", edit(VEHICLE, "length_m = 120.0", "length_m = 12.0"), ("length_m", "per car")),
    ("davis-a-1e12", edit(VEHICLE, "davis_a_n = 2900.0", "davis_a_n = 1e12"), ("vehicle.davis_a_n",)),
    (
        "b7-7e300",
        edit(VEHICLE, "0.714, 0.857, 1.0]", "0.714, 0.857, 7e300]"),
        ("vehicle.brake.notch_decel_mps2",),
    ),
    (
        "emergency-9g",
        edit(VEHICLE, "emergency_decel_mps2 = 1.3", "emergency_decel_mps2 = 90.0"),
        ("emergency_decel_mps2",),
    ),
    ("force-1e9", edit(VEHICLE, "max_force_n = 320000.0", "max_force_n = 1e9"), ("max_force_n",)),
    ("cars-string", edit(VEHICLE, "cars = 6", 'cars = "6"'), ("vehicle.cars", "'6'")),
]
for name, text, needles in VEHICLE_CASES:
    add(
        f"check-vehicle-{name}",
        "check",
        "--vehicle",
        "v.toml",
        files={"v.toml": text},
        needles=("v.toml", *needles),
    )
add(
    "stop-train-longer-than-platform",
    "stop",
    "--vehicle",
    "v.toml",
    files={"v.toml": edit(VEHICLE, "length_m = 120.0", "length_m = 200.0")},
    needles=("platform_length_m", "shorter than the train"),
)
add(
    "dwell-doors-for-another-train",
    "dwell",
    "--vehicle",
    "v.toml",
    "--stop-error-m",
    "0.1",
    files={
        "v.toml": edit(
            edit(
                edit(edit(VEHICLE, "cars = 6", "cars = 2"), "length_m = 120.0", "length_m = 40.0"),
                "tare_mass_kg = 200000.0",
                "tare_mass_kg = 66000.0",
            ),
            "crush_payload_kg = 110000.0",
            "crush_payload_kg = 36000.0",
        )
    },
    needles=("train.doors_per_side", "v.toml", "24"),
)
add("check-unknown-option", "check", "--lines", "x.toml", needles=("--lines",))
add("check-extra-argument", "check", "extra", needles=("extra",))

# --------------------------------------------------------------------------
# railstop doors table / verify: door data files

DOORS_CASES: list[tuple[str, str | bytes, tuple[str, ...]]] = [
    ("empty", "", ("action_table", "Field required")),
    ("binary", BINARY, ("not UTF-8",)),
    ("syntax", "[timing\n", ("toml syntax",)),
    (
        "unknown-timing-key",
        edit(DOORS, "dwell_s = 20.0", "dwell_s = 20.0\ndwel_s = 20.0"),
        ("timing.dwel_s",),
    ),
    ("bracket-key", '"[/]" = 1\n' + DOORS, ("[/]",)),
    ("dwell-string", edit(DOORS, "dwell_s = 20.0", 'dwell_s = "long"'), ("timing.dwell_s", "long")),
    ("dwell-zero", edit(DOORS, "dwell_s = 20.0", "dwell_s = 0.0"), ("timing.dwell_s",)),
    ("dwell-nan", edit(DOORS, "dwell_s = 20.0", "dwell_s = nan"), ("timing.dwell_s",)),
    ("psd-slower", edit(DOORS, "psd_open_s = 2.0", "psd_open_s = 5.0"), ("psd_open_s",)),
    (
        "fifteen-rows",
        edit_re(DOORS, r"^  \{ doa = 0, dmc = 0, doc = 0, dcc = 0,[^\n]*\n", ""),
        ("action_table", "15"),
    ),
    ("duplicate-row", edit(DOORS, "dcc = 1, closed", "dcc = 0, closed"), ("action_table", "repeats")),
    (
        "bad-action",
        edit(DOORS, 'closed = "keep-closed"', 'closed = "explode"'),
        ("action_table[0].closed", "explode"),
    ),
    (
        "doors-per-side-huge",
        edit(DOORS, "doors_per_side = 24", f"doors_per_side = {HUGE}"),
        ("doors_per_side",),
    ),
    (
        "tolerance-name",
        edit(DOORS, 'tolerance = "psd"', 'tolerance = "loose"'),
        ("stop_confirm.tolerance", "loose"),
    ),
]
for name, text, needles in DOORS_CASES:
    add(
        f"doors-table-{name}",
        "doors",
        "table",
        "--doors",
        "d.toml",
        files={"d.toml": text},
        needles=("d.toml", *needles),
    )
add(
    "doors-table-missing",
    "doors",
    "table",
    "--doors",
    "missing.toml",
    needles=("missing.toml", "no such file"),
)
add("doors-table-folder", "doors", "table", "--doors", "adir", dirs=["adir"], needles=("adir",))

for name, value in (("zero", "0"), ("three", "3"), ("huge", HUGE)):
    add(
        f"doors-verify-per-side-{name}",
        "doors",
        "verify",
        "--doors-per-side",
        value,
        needles=("--doors-per-side",),
    )
add(
    "doors-verify-psd-slower",
    "doors",
    "verify",
    "--doors",
    "d.toml",
    files={"d.toml": edit(DOORS, "psd_close_s = 2.5", "psd_close_s = 4.0")},
    needles=("d.toml", "psd_close_s"),
)

# --------------------------------------------------------------------------
# railstop dwell (a given --stop-error-m skips the simulated stop)

GIVEN = ("--stop-error-m", "0.1", "--db", "d.db")
for name, value in (
    ("nan", "nan"),
    ("minus-inf", "-inf"),
    ("text", "short"),
    ("off-platform", "-131"),
):
    add(
        f"dwell-stop-error-{name}",
        "dwell",
        "--stop-error-m",
        value,
        "--db",
        "d.db",
        needles=("--stop-error-m",),
    )
add("dwell-mode-unknown", "dwell", *GIVEN, "--mode", "sleepy", needles=("--mode", "'sleepy'"))
add("dwell-mode-bracket", "dwell", *GIVEN, "--mode", "[bold]", needles=("--mode", "'[bold]'"))
add("dwell-obstruct-door-beyond", "dwell", *GIVEN, "--obstruct-door", "25", needles=("--obstruct-door", "25"))
add("dwell-obstruct-door-zero", "dwell", *GIVEN, "--obstruct-door", "0", needles=("--obstruct-door", "0"))
# A value the command line refuses: the error line names the option, and (project rule) the value.
add(
    "dwell-obstruct-door-text",
    "dwell",
    *GIVEN,
    "--obstruct-door",
    "front",
    needles=("--obstruct-door", "front"),
)
add("dwell-psd-fail-beyond", "dwell", *GIVEN, "--psd-fail", HUGE, needles=("--psd-fail", HUGE))
add(
    "dwell-controller-unknown",
    "dwell",
    "--controller",
    "magic",
    "--db",
    "d.db",
    needles=("--controller", "magic"),
)
add("dwell-controller-bracket", "dwell", "--controller", "[red]x", "--db", "d.db", needles=("[red]x",))
add("dwell-seed-2-64", "dwell", "--seed", TWO_64, "--db", "d.db", needles=("--seed", TWO_64))
add("dwell-station-bracket", "dwell", *GIVEN, "--station", "[/]", needles=("'[/]'",))
add(
    "dwell-doors-one-door",
    "dwell",
    *GIVEN,
    "--doors",
    "d.toml",
    "--obstruct-door",
    "7",
    files={"d.toml": edit(DOORS, "doors_per_side = 24", "doors_per_side = 6")},
    needles=("--obstruct-door", "1..6"),
)
add("dwell-line-missing", "dwell", *GIVEN, "--line", "missing.toml", needles=("missing.toml",))
add(
    "dwell-vehicle-bad",
    "dwell",
    "--db",
    "d.db",
    "--vehicle",
    "v.toml",
    files={"v.toml": edit(VEHICLE, "cars = 6", "cars = 0")},
    needles=("v.toml", "vehicle.cars"),
)
add("dwell-db-folder", "dwell", "--stop-error-m", "0.1", "--db", "adir", dirs=["adir"], needles=("adir",))
add(
    "dwell-db-not-sqlite",
    "dwell",
    "--stop-error-m",
    "0.1",
    "--db",
    "notes.txt",
    files={"notes.txt": BINARY},
    needles=("notes.txt",),
)
add("dwell-plot-folder", "dwell", *GIVEN, "--plot", "adir", dirs=["adir"], needles=("adir", "folder"))

# --------------------------------------------------------------------------
# railstop position-run (9 s when accepted: every case here is refused before the run)

for option, value in (
    ("--diameter-error-pct", "nan"),
    ("--low-mu", "inf"),
    ("--seed", TWO_64),
    ("--run", "-1"),
):
    add(
        f"position-run{option[1:]}-{tag(value)}",
        "position-run",
        option,
        value,
        needles=(option,),
    )
add(
    "position-run-disturbances-unknown",
    "position-run",
    "--disturbances",
    "s.toml",
    files={"s.toml": "wheel_diametre_mm = {fixed = 800.0}\n"},
    needles=("s.toml", "wheel_diametre_mm"),
)
add(
    "position-run-vehicle-bad",
    "position-run",
    "--vehicle",
    "v.toml",
    files={"v.toml": edit(VEHICLE, "gate_sigma = 4.0", "gate_sigma = 0.0")},
    needles=("v.toml", "gate_sigma"),
)

# --------------------------------------------------------------------------
# railstop stop

NO_DB = "--no-db"
for name, value in (("unknown", "Nowhere"), ("bold", "[bold]"), ("close", "[/]")):
    add(f"stop-station-{name}", "stop", NO_DB, "--station", value, needles=(repr(value),))
add("stop-controller-unknown", "stop", NO_DB, "--controller", "magic", needles=("--controller", "'magic'"))
add("stop-controller-bracket", "stop", NO_DB, "--controller", "[red]x", needles=("--controller", "'[red]x'"))
# Values the command line refuses: the error line names the option, and (project rule) the value.
add("stop-load-factor-1.1", "stop", NO_DB, "--load-factor", "1.1", needles=("--load-factor", "1.1"))
for option, value in (
    ("--load-factor", "nan"),
    ("--load-factor", "x"),
    ("--brake-gain", ""),
    ("--form", "9"),
    ("--seed", "1.5"),
    ("--run", "-1"),
    ("--tolerance-m", "0"),
    ("--tolerance-m", "nan"),
):
    add(
        f"stop{option[1:]}-{tag(value)}",
        "stop",
        NO_DB,
        option,
        value,
        needles=(option,),
    )
# The random streams take 64-bit seeds (campaign, certify, dwell and position-run refuse others).
add("stop-seed-2-64", "stop", NO_DB, "--seed", TWO_64, needles=("--seed", TWO_64))
add("stop-seed-2-63-db", "stop", "--db", "s.db", "--seed", TWO_63, needles=("seed", TWO_63))
add("stop-run-2-63", "stop", NO_DB, "--disturbances", "standard", "--run", TWO_63, needles=("--run", TWO_63))
add("stop-run-without-set", "stop", NO_DB, "--run", "5", needles=("--run", "--disturbances"))
add(
    "stop-load-with-set",
    "stop",
    NO_DB,
    "--disturbances",
    "standard",
    "--load-factor",
    "0.5",
    needles=("--load-factor",),
)
add("stop-disturbances-unknown", "stop", NO_DB, "--disturbances", "stormy", needles=("stormy",))
# A campaign folder (or its manifest) given where a disturbance set is expected.
CAMPAIGN_JUNK = {"camp/campaign.json": b"\x00\xffnot a manifest", "camp/runs.parquet": BINARY}
add(
    "stop-run-campaign-folder",
    "stop",
    NO_DB,
    "--disturbances",
    "camp",
    "--run",
    "3",
    files=CAMPAIGN_JUNK,
    needles=("camp",),
)
add(
    "stop-run-campaign-manifest",
    "stop",
    NO_DB,
    "--disturbances",
    "camp/campaign.json",
    "--run",
    "3",
    files=CAMPAIGN_JUNK,
    needles=("camp/campaign.json",),
)
add("stop-db-and-no-db", "stop", NO_DB, "--db", "x.db", needles=("--db", "--no-db"))
add("stop-plot-extension", "stop", NO_DB, "--plot", "p.txt", needles=("p.txt",))
add(
    "stop-plot-unwritable",
    "stop",
    NO_DB,
    "--plot",
    "/proc/railstop-stop.png",
    needles=("/proc/railstop-stop.png",),
)
add(
    "stop-line-implausible",
    "stop",
    NO_DB,
    "--line",
    "l.toml",
    files={"l.toml": edit(LINE, "speed_limit_kmh = 80.0", "speed_limit_kmh = 62.0")},
    needles=("l.toml", "entry_speed_kmh"),
)
add("stop-vehicle-binary", "stop", NO_DB, "--vehicle", "v.bin", files={"v.bin": BINARY}, needles=("v.bin",))
add("stop-extra-argument", "stop", NO_DB, "Riverside", needles=("Riverside",))

# Disturbance set files (campaign, compare, certify, stop and position-run read them alike).
DIST_CASES: list[tuple[str, str | bytes, tuple[str, ...]]] = [
    ("binary", BINARY, ("not UTF-8",)),
    ("syntax", "brake_gain = {normal = [1.0, 0.07]", ("toml syntax",)),
    ("unknown-parameter", "brake_gian = {fixed = 1.0}\n", ("brake_gian", "brake_gain")),
    ("normal-no-clip", "brake_gain = {normal = [1.0, 0.07]}\n", ("brake_gain.normal", "clip")),
    ("uniform-reversed", "entry_speed_kmh = {uniform = [65.0, 45.0]}\n", ("entry_speed_kmh.uniform",)),
    ("fixed-nan", "load_factor = {fixed = nan}\n", ("load_factor.fixed",)),
    (
        "choice-out-of-range",
        "wheel_diameter_mm = {choice = [800.0, 2000.0]}\n",
        ("wheel_diameter_mm.choice", "2000"),
    ),
    ("probability-bool", "radio_loss_probability = true\n", ("radio_loss_probability",)),
    ("standard-plus-typo", STANDARD + "\nsensor_jiter_ms = {fixed = 1.0}\n", ("sensor_jiter_ms",)),
]
for name, text, needles in DIST_CASES:
    add(
        f"stop-disturbances-{name}",
        "stop",
        NO_DB,
        "--disturbances",
        "s.toml",
        "--run",
        "1",
        files={"s.toml": text},
        needles=("s.toml", *needles),
    )

# --------------------------------------------------------------------------
# railstop campaign and compare (always --runs 2: an accepted campaign stays short)

CAMP = ("campaign", "--runs", "2", "--out", "c", "--db", "c.db")
add("campaign-runs-zero", "campaign", "--out", "c", "--db", "c.db", "--runs", "0", needles=("--runs",))
add("campaign-runs-text", "campaign", "--out", "c", "--db", "c.db", "--runs", "many", needles=("--runs",))
add("campaign-runs-2-63", "campaign", "--out", "c", "--db", "c.db", "--runs", TWO_63, needles=("--runs",))
add("campaign-seed-2-63", *CAMP, "--seed", TWO_63, needles=("--seed",))
add("campaign-chunk-size-zero", *CAMP, "--chunk-size", "0", needles=("--chunk-size",))
add("campaign-workers-zero", *CAMP, "--workers", "0", needles=("--workers",))
add("campaign-station-bracket", *CAMP, "--station", "[bold]", needles=("'[bold]'",))
add(
    "campaign-disturbances-out-of-range",
    *CAMP,
    "--disturbances",
    "s.toml",
    files={"s.toml": "brake_gain = {uniform = [0.0, 1.0]}\n"},
    needles=("s.toml", "brake_gain.uniform"),
)
add(
    "campaign-out-is-file",
    "campaign",
    "--runs",
    "2",
    "--db",
    "c.db",
    "--out",
    "afile",
    files={"afile": "x"},
    needles=("afile",),
)
add(
    "campaign-resume-binary-manifest",
    *CAMP,
    "--resume",
    files={"c/campaign.json": BINARY},
    needles=("campaign.json",),
)
add("campaign-scheduler-refused", *CAMP, "--scheduler", "tcp://127.0.0.1:1", needles=("tcp://127.0.0.1:1",))
add("campaign-scheduler-empty", *CAMP, "--scheduler", "", needles=("--scheduler",))
add("campaign-unknown-option", *CAMP, "--run", "2", needles=("--run",))

CMP = ("compare", "--runs", "2", "--out", "cmp", "--db", "c.db")
add("compare-runs-zero", "compare", "--out", "cmp", "--db", "c.db", "--runs", "0", needles=("--runs",))
add("compare-seed-2-63", *CMP, "--seed", TWO_63, needles=("--seed",))
add("compare-station-unknown", *CMP, "--station", "Atlantis", needles=("Atlantis",))

# --------------------------------------------------------------------------
# railstop certify (always small --runs and --tuning-runs: an accepted one stays short)

CERT = ("certify", "--runs", "100", "--tuning-runs", "100", "--method", "mc")
for option, value in (
    ("--threshold-m", "nan"),
    ("--target", "0"),
    ("--target", "nan"),
    ("--defensive", "1.5"),
    ("--confidence", "1"),
    ("--seed", TWO_64),
):
    add(f"certify{option[1:]}-{tag(value)}", *CERT, option, value, needles=(option, value))
add(
    "certify-runs-zero",
    "certify",
    "--tuning-runs",
    "100",
    "--method",
    "mc",
    "--runs",
    "0",
    needles=("--runs",),
)
add(
    "certify-runs-2-63",
    "certify",
    "--tuning-runs",
    "100",
    "--method",
    "mc",
    "--runs",
    TWO_63,
    needles=("--runs",),
)
add("certify-tuning-runs-99", "certify", "--runs", "100", "--tuning-runs", "99", needles=("--tuning-runs",))
add(
    "certify-tuning-runs-2-63",
    "certify",
    "--runs",
    "100",
    "--tuning-runs",
    TWO_63,
    needles=("--tuning-runs",),
)
add("certify-method-unknown", "certify", "--runs", "100", "--method", "magic", needles=("--method", "magic"))
add("certify-station-unknown", *CERT, "--station", "Atlantis", needles=("Atlantis",))
add(
    "certify-disturbances-bad",
    *CERT,
    "--disturbances",
    "s.toml",
    files={"s.toml": "brake_gain = {normal = [1.0, 0.07]}\n"},
    needles=("s.toml", "brake_gain"),
)
add("certify-scheduler-garbage", *CERT, "--scheduler", "garbage", needles=("garbage",))

# --------------------------------------------------------------------------
# railstop report: garbage campaign folders

GOOD_MANIFEST = '{"kind": "railstop-campaign", "station": "Riverside", "controller": "tasc-pwm", "runs": 2}'
add("report-missing-folder", "report", "nowhere", needles=("nowhere",))
add("report-file", "report", "afile", files={"afile": "x"}, needles=("afile",))
add("report-empty-folder", "report", "empty", dirs=["empty"], needles=("empty",))
for name, manifest in (("binary", BINARY), ("array", "[1, 2]"), ("kind", '{"kind": "shopping-list"}')):
    add(
        f"report-manifest-{name}",
        "report",
        "c",
        files={"c/campaign.json": manifest, "c/runs.parquet": BINARY},
        needles=("campaign.json",),
    )
add(
    "report-runs-garbage",
    "report",
    "c",
    files={"c/campaign.json": GOOD_MANIFEST, "c/runs.parquet": BINARY},
    needles=("runs.parquet",),
)
add(
    "report-nested-garbage",
    "report",
    "cmp",
    files={"cmp/tasc-pwm/campaign.json": "{not json", "cmp/tasc-pwm/runs.parquet": BINARY},
    needles=("campaign.json",),
)
add("report-worst-negative", "report", "c", "--worst", "-1", dirs=["c"], needles=("--worst",))
add("report-no-folder", "report", needles=("directory",))

# --------------------------------------------------------------------------
# railstop demo and compile (an accepted demo runs for minutes: every case is refused up front)

add("demo-runs-zero", "demo", "--runs", "0", needles=("--runs",))
add("demo-out-is-file", "demo", "--runs", "1", "--out", "afile", files={"afile": "x"}, needles=("afile",))
add("demo-line-missing", "demo", "--runs", "1", "--line", "missing.toml", needles=("missing.toml",))
add("demo-unknown-option", "demo", "--station", "Riverside", needles=("--station",))
add("compile-unknown-option", "compile", "--force", needles=("--force",))
add("compile-extra-argument", "compile", "now", needles=("now",))

# --------------------------------------------------------------------------
# railstop telegram decode / encode / types

VALID_FRAME = "9600650202bcc697"  # tasc-required-decel: train 101, detector 2, 0.7 m/s²
for name, text, needle in (
    ("not-hex", "zz", "hex"),
    ("odd-digits", "960", "hex"),
    ("bracket", "[bold]", "[bold]"),
    ("empty", "", "empty"),
    ("bad-crc", VALID_FRAME[:-1] + "8", "crc"),
    ("unknown-type", "ff" + VALID_FRAME[2:], "unknown_type"),
    ("short", VALID_FRAME[:-2], "short"),
):
    add(f"telegram-decode-{name}", "telegram", "decode", text, needles=(needle,))
add("telegram-decode-no-frame", "telegram", "decode", needles=("HEX",))
add("telegram-decode-two-frames", "telegram", "decode", VALID_FRAME, VALID_FRAME, needles=(VALID_FRAME,))

ENC = ("telegram", "encode", "tasc-required-decel")
for name, fields, needle in (
    ("no-fields", (), "missing field"),
    ("unknown-field", ("train_id=1", "detector=2", "required_mps2=0.7", "colour=red"), "colour"),
    ("no-equals", ("train_id",), "FIELD=VALUE"),
    ("twice", ("train_id=1", "train_id=2"), "given twice"),
    ("id-float", ("train_id=1.5", "detector=2", "required_mps2=0.7"), "train_id"),
    ("id-range", ("train_id=70000", "detector=2", "required_mps2=0.7"), "70000"),
    ("detector-range", ("train_id=1", "detector=64", "required_mps2=0.7"), "detector"),
    ("decel-nan", ("train_id=1", "detector=2", "required_mps2=nan"), "required_mps2"),
    ("decel-empty", ("train_id=1", "detector=2", "required_mps2="), "required_mps2"),
):
    add(f"telegram-encode-{name}", *ENC, *fields, needles=(needle,))
add(
    "telegram-encode-unknown-type",
    "telegram",
    "encode",
    "tasc-teleport",
    "train_id=1",
    needles=("tasc-teleport",),
)
add(
    "telegram-encode-flag",
    "telegram",
    "encode",
    "psd-status",
    "train_id=1",
    "psc=maybe",
    "psd_closed_locked=1",
    "start_enable=0",
    "manual=0",
    "fault=0",
    "psd_open=0",
    needles=("psc", "maybe"),
)
add(
    "telegram-encode-gradient-nan",
    "telegram",
    "encode",
    "cbtc-command",
    "train_id=1",
    "authority_m=100",
    "gradient_permille=nan",
    "speed_limit_mps=20",
    "report_time_s=1",
    "delay_s=0.1",
    needles=("gradient_permille",),
)
add("telegram-types-unknown-option", "telegram", "types", "--json", needles=("--json",))

# --------------------------------------------------------------------------
# railstop live: the processes refuse bad options before they start

# The key: never on the command line, only from a private key file or the environment.
add(
    "live-zc-key-hex",
    "live", "zc", "--port", "0", "--new", "--key-hex", LIVE_KEY_TEXT.strip(),
    needles=("--key-hex", "command line", "--key-file", "RAILSTOP_OFFICE_KEY"),
)  # fmt: skip
add(
    "office-serve-key-hex",
    "office", "serve", "--port", "0", "--key-hex", LIVE_KEY_TEXT.strip(),
    needles=("--key-hex", "command line", "--key-file", "RAILSTOP_OFFICE_KEY"),
)  # fmt: skip
add(
    "live-trains-key-hex-beside-a-key-file",
    "live", "trains", *LIVE_KEY, "--key-hex", LIVE_KEY_TEXT.strip(),
    needles=("--key-hex", "--key-file"),
)  # fmt: skip
add(
    "live-zc-key-file-world-readable",
    "live", "zc", "--port", "0", "--new", "--key-file", "open.key",
    files={"open.key": LIVE_KEY_TEXT}, modes={"open.key": 0o644},
    needles=("--key-file", "open.key", "chmod 600"),
)  # fmt: skip
add(
    "live-plant-key-file-group-writable",
    "live", "plant", "--port", "0", "--key-file", "open.key",
    files={"open.key": LIVE_KEY_TEXT}, modes={"open.key": 0o620},
    needles=("--key-file", "open.key", "chmod 600"),
)  # fmt: skip
add(
    "office-serve-key-file-world-readable",
    "office", "serve", "--port", "0", "--key-file", "open.key",
    files={"open.key": LIVE_KEY_TEXT}, modes={"open.key": 0o604},
    needles=("--key-file", "open.key", "chmod 600"),
)  # fmt: skip
add(
    "live-stations-key-file-not-hex",
    "live", "stations", "--port", "0", "--key-file", "bad.key",
    files={"bad.key": "the key\n"}, modes={"bad.key": 0o600},
    needles=("--key-file", "bad.key", "hexadecimal"),
)  # fmt: skip
add(
    "office-serve-key-file-short",
    "office", "serve", "--port", "0", "--key-file", "short.key",
    files={"short.key": "0011223344556677\n"}, modes={"short.key": 0o600},
    needles=("--key-file", "short.key", "16 bytes"),
)  # fmt: skip
add(
    "live-zc-key-file-missing",
    "live", "zc", "--port", "0", "--new", "--key-file", "nosuch.key",
    needles=("--key-file", "nosuch.key", "no such file"),
)  # fmt: skip
add(
    "live-zc-key-file-a-folder",
    "live", "zc", "--port", "0", "--new", "--key-file", "keys",
    dirs=("keys",),
    needles=("--key-file", "keys", "not a regular file"),
)  # fmt: skip
add(
    "office-new-key-exists",
    "office", "new-key", "--out", "live.key",
    files={"live.key": LIVE_KEY_TEXT}, modes={"live.key": 0o600},
    needles=("--out", "live.key", "exists"),
)  # fmt: skip
add(
    "live-stations-controller",
    "live",
    "stations",
    *LIVE_KEY,
    "--controller",
    "ato",
    needles=("--controller", "ato"),
)
add(
    "live-trains-stations-address",
    "live",
    "trains",
    *LIVE_KEY,
    "--stations",
    "nonsense",
    needles=("--stations", "nonsense"),
)
add(
    "live-trains-disturbances",
    "live", "trains", *LIVE_KEY, "--stations", "127.0.0.1:9", "--disturbances", "nosuch",
    needles=("nosuch",),
)  # fmt: skip
add(
    "live-trains-controller",
    "live",
    "trains",
    *LIVE_KEY,
    "--stations",
    "127.0.0.1:9",
    "--controller",
    "driver-ats",
    needles=("--controller", "driver-ats"),
)
add(
    "live-trains-outage",
    "live",
    "trains",
    *LIVE_KEY,
    "--trains",
    "2",
    "--outage",
    "9:1:1",
    needles=("--outage", "9:1:1"),
)
add(
    "live-run-controller",
    "live",
    "run",
    "--controller",
    "foo",
    "--duration-s",
    "1",
    needles=("--controller", "foo"),
)

add(
    "live-trains-tasc-loss",
    "live", "trains", *LIVE_KEY, "--stations", "127.0.0.1:9", "--tasc-loss", "1.5",
    needles=("--tasc-loss",),
)  # fmt: skip
add(
    "live-stations-doors",
    "live", "stations", *LIVE_KEY, "--doors", "nosuch.toml",
    needles=("nosuch.toml",),
)  # fmt: skip
add(
    "live-trains-doors",
    "live", "trains", *LIVE_KEY, "--stations", "127.0.0.1:9", "--doors", "nosuch.toml",
    needles=("nosuch.toml",),
)  # fmt: skip
add(
    "office-serve-operators-missing",
    "office", "serve", *LIVE_KEY, "--operators", "ops.toml",
    needles=("ops.toml",),
)  # fmt: skip
add(
    "office-serve-operators-readable",
    "office", "serve", *LIVE_KEY, "--http-port", "0", "--operators", "ops.toml",
    files={"ops.toml": '[operators.alice]\npbkdf2_sha256 = "1$00$00"\n'},
    needles=("ops.toml", "chmod 600"),
)  # fmt: skip
add(
    "office-serve-allowed-hosts",
    "office", "serve", *LIVE_KEY, "--http-port", "0", "--allowed-hosts", "http://x/",
    needles=("--allowed-hosts", "http://x/"),
)  # fmt: skip
add(
    "office-serve-wildcard-without-allowed-hosts",
    "office", "serve", *LIVE_KEY, "--host", "0.0.0.0", "--port", "0", "--http-port", "0",
    needles=("--allowed-hosts",),
)  # fmt: skip
add(
    "office-serve-tls-key-alone",
    "office", "serve", *LIVE_KEY, "--http-port", "0", "--tls-key", "key.pem",
    needles=("--tls-cert", "--tls-key"),
)  # fmt: skip
add(
    "office-add-operator-credential-on-command-line",
    "office", "add-operator", "ops.toml", "alice", "--credential", "typed in the shell",
    needles=("--credential",),
)  # fmt: skip
add(
    "office-serve-stations-without-operators",
    "office", "serve", *LIVE_KEY, "--stations", "127.0.0.1:9",
    needles=("--stations", "--operators"),
)  # fmt: skip
add(
    "office-serve-stations-address",
    "office", "serve", *LIVE_KEY, "--stations", "nonsense", "--operators", "ops.toml",
    needles=("--stations", "nonsense"),
)  # fmt: skip
add(
    "live-stations-psd-jam",
    "live", "stations", *LIVE_KEY, "--psd-jam", "Nowhere:3",
    needles=("--psd-jam", "Nowhere:3"),
)  # fmt: skip
add(
    "live-run-psd-jam-unit",
    "live", "run", "--duration-s", "1", "--psd-jam", "Harbour:25",
    needles=("--psd-jam", "Harbour:25"),
)  # fmt: skip
add(
    "live-trains-door-mode",
    "live", "trains", *LIVE_KEY, "--stations", "127.0.0.1:9", "--door-mode", "robot",
    needles=("--door-mode", "robot"),
)  # fmt: skip
add(
    "live-trains-obstruct",
    "live", "trains", *LIVE_KEY, "--stations", "127.0.0.1:9", "--trains", "2", "--obstruct", "5:1",
    needles=("--obstruct", "5:1"),
)  # fmt: skip
add(
    "live-plant-stations-address",
    "live", "plant", *LIVE_KEY, "--stations", "nonsense",
    needles=("--stations", "nonsense"),
)  # fmt: skip
add(
    "live-plant-controller",
    "live", "plant", *LIVE_KEY, "--stations", "127.0.0.1:9", "--controller", "ato",
    needles=("--controller", "ato"),
)  # fmt: skip
add(
    "live-plant-disturbances",
    "live", "plant", *LIVE_KEY, "--stations", "127.0.0.1:9", "--disturbances", "nosuch",
    needles=("nosuch",),
)  # fmt: skip
add(
    "live-plant-trains-do-not-fit",
    "live", "plant", *LIVE_KEY, "--trains", "60", "--spacing-m", "5000",
    needles=("--trains", "--spacing-m", "60", "5000"),
)  # fmt: skip
add(
    "live-trains-plant-address",
    "live", "trains", *LIVE_KEY, "--plant", "nonsense",
    needles=("--plant", "nonsense"),
)  # fmt: skip
add("office-reports-no-db", "office", "reports", "--db", "nosuch.db", needles=("--db", "nosuch.db"))
add(
    "office-reports-kind",
    "office",
    "reports",
    "--db",
    "x.db",
    "--kind",
    "gossip",
    needles=("--kind", "gossip"),
)
add("office-reports-last", "office", "reports", "--db", "x.db", "--last", "0", needles=("--last",))
add(
    "office-reports-not-a-db",
    "office",
    "reports",
    "--db",
    "x.db",
    files={"x.db": "not a database"},
    needles=("x.db",),
)

# --------------------------------------------------------------------------
# railstop import railml: the XML, the railML structure, the numbers, the tracks, the output.

RAILML_HEAD = '<railml xmlns="https://www.railml.org/schemas/2016" version="2.3"><infrastructure><tracks>'
RAILML_TAIL = "</tracks></infrastructure></railml>"


def railml_track(body: str, ident: str = "t1", end: str = "500") -> str:
    return (
        f'<track id="{ident}"><trackTopology><trackBegin pos="0"/><trackEnd pos="{end}"/></trackTopology>'
        f"{body}</track>"
    )


RAILML_EDGE = (
    '<trackElements><platformEdges><platformEdge id="pe" pos="300" length="130" side="right"/>'
    "</platformEdges></trackElements>"
)
RAILML_OK = RAILML_HEAD + railml_track(RAILML_EDGE) + RAILML_TAIL
IMPORT = ("import", "railml", "in.xml", "--out", "out.toml")
RAILML_CASES: list[tuple[str, str | bytes, tuple[str, ...]]] = [
    ("not-xml", "a line, not XML", ("in.xml", "(xml syntax)")),
    ("binary", BINARY, ("in.xml",)),
    ("empty", "", ("in.xml",)),
    ("svg", "<svg xmlns='http://www.w3.org/2000/svg'/>", ("in.xml", "not a railML file")),
    ("no-namespace", "<railml/>", ("in.xml", "not a railML file")),
    (
        "doctype-entity",
        '<!DOCTYPE railml [<!ENTITY x SYSTEM "file:///etc/passwd">]>'
        + RAILML_OK.replace('id="pe"', 'id="&x;"'),
        ("in.xml", "DOCTYPE"),
    ),
    (
        "billion-laughs",
        '<!DOCTYPE railml [<!ENTITY a "aaaaaaaaaa"><!ENTITY b "&a;&a;&a;&a;&a;&a;&a;&a;&a;&a;">]>'
        + RAILML_OK,
        ("in.xml", "DOCTYPE"),
    ),
    (
        "no-infrastructure",
        '<railml xmlns="https://www.railml.org/schemas/2016"/>',
        ("in.xml", "infrastructure"),
    ),
    ("no-tracks", RAILML_HEAD + RAILML_TAIL, ("in.xml", "no tracks")),
    (
        "two-tracks",
        RAILML_HEAD + railml_track(RAILML_EDGE) + railml_track("", "t2") + RAILML_TAIL,
        ("--track", "t1, t2"),
    ),
    ("no-station", RAILML_HEAD + railml_track("") + RAILML_TAIL, ("in.xml", "needs a station")),
    (
        "pos-text",
        RAILML_OK.replace('pos="300"', 'pos="north"'),
        ("in.xml", "platformEdge 'pe'", "@pos", "'north'"),
    ),
    ("pos-nan", RAILML_OK.replace('pos="300"', 'pos="NaN"'), ("in.xml", "@pos", "finite")),
    ("pos-outside", RAILML_OK.replace('pos="300"', 'pos="9000"'), ("in.xml", "@pos", "outside its track")),
    ("length-negative", RAILML_OK.replace('length="130"', 'length="-130"'), ("in.xml", "@length")),
    ("track-end-before-begin", RAILML_OK.replace('<trackEnd pos="500"/>', '<trackEnd pos="-5"/>'), ("@pos",)),
    ("deep-nesting", RAILML_HEAD + "<a>" * 300 + "</a>" * 300 + RAILML_TAIL, ("in.xml",)),
]
for name, text, needles in RAILML_CASES:
    add(f"import-railml-{name}", *IMPORT, files={"in.xml": text}, needles=needles)
add("import-railml-missing", *IMPORT, needles=("in.xml", "no such file"))
add("import-railml-folder", *IMPORT, dirs=["in.xml"], needles=("in.xml", "a folder"))
add("import-railml-device", "import", "railml", "/dev/zero", "--out", "o.toml", needles=("/dev/zero",))
add(
    "import-railml-unknown-track",
    *IMPORT,
    "--track",
    "t7",
    files={"in.xml": RAILML_OK},
    needles=("t7", "no such track"),
)
add(
    "import-railml-out-exists",
    *IMPORT,
    files={"in.xml": RAILML_OK, "out.toml": "mine"},
    needles=("out.toml", "never overwrites"),
)
add(
    "import-railml-out-folder",
    "import",
    "railml",
    "in.xml",
    "--out",
    "d",
    files={"in.xml": RAILML_OK},
    dirs=["d"],
    needles=("d",),
)
add(
    "import-railml-entry-speed",
    *IMPORT,
    "--entry-speed",
    "900",
    files={"in.xml": RAILML_OK},
    needles=("--entry-speed",),
)

# --------------------------------------------------------------------------
# python -m railstop.link.udp

RECV = ("receive", "--count", "1", "--epoch", "0", *LIVE_KEY, "--wait-s", "0.2")
SEND = ("send", "--count", "1", "--epoch", "0", *LIVE_KEY)


def udp(
    id: str,
    *argv: str,
    needles: Iterable[str] = (),
    files: Mapping[str, str | bytes] | None = None,
    modes: Mapping[str, int] | None = None,
) -> None:
    add(f"udp-{id}", *argv, needles=needles, module=UDP, files=files, modes=modes)


udp("no-command", needles=("command",))
udp("unknown-command", "listen", "--port", "5000", needles=("listen",))
for name, value in (("zero", "0"), ("above", "65536"), ("text", "http"), ("empty", "")):
    udp(f"receive-port-{name}", *RECV, "--port", value, needles=("--port",))
for name, value in (("negative", "-1"), ("huge", HUGE)):
    udp(f"send-port-{name}", *SEND, "--port", value, needles=("--port",))
udp("receive-port-missing", *RECV, needles=("--port",))
udp("send-count-missing", "send", "--port", "5000", "--epoch", "0", *LIVE_KEY, needles=("--count",))
udp("send-count-negative", "send", "--port", "5000", "--count", "-1", "--epoch", "0", needles=("--count",))
udp("send-epoch-missing", "send", "--port", "5000", "--count", "1", *LIVE_KEY, needles=("--epoch",))
for name, value in (("text", "noon"), ("nan", "nan")):
    udp(
        f"send-epoch-{name}",
        "send",
        "--port",
        "5000",
        "--count",
        "1",
        *LIVE_KEY,
        "--epoch",
        value,
        needles=("--epoch",),
    )
udp(
    "receive-epoch-minus-inf",
    *RECV[:3],
    *LIVE_KEY,
    "--port",
    "5000",
    "--epoch",
    "-inf",
    needles=("--epoch",),
)
udp("send-category-four", *SEND, "--port", "5000", "--category", "4", needles=("--category",))
udp(
    "send-key-not-hex", *SEND[:5], "--port", "5000", "--key-file", "bad.key",
    files={"bad.key": "zz\n"}, modes={"bad.key": 0o600}, needles=("--key-file", "bad.key", "hexadecimal"),
)  # fmt: skip
udp(
    "send-key-empty", *SEND[:5], "--port", "5000", "--key-file", "empty.key",
    files={"empty.key": ""}, modes={"empty.key": 0o600}, needles=("--key-file", "empty"),
)  # fmt: skip
udp(
    "send-key-short", *SEND[:5], "--port", "5000", "--key-file", "short.key",
    files={"short.key": "0011\n"}, modes={"short.key": 0o600}, needles=("--key-file", "16 bytes"),
)  # fmt: skip
udp(
    "send-key-world-readable", *SEND[:5], "--port", "5000", "--key-file", "open.key",
    files={"open.key": LIVE_KEY_TEXT}, modes={"open.key": 0o644}, needles=("--key-file", "chmod 600"),
)  # fmt: skip
udp("send-key-missing", *SEND[:5], "--port", "5000", needles=("--key-file",))
udp("send-key-with-crc", *SEND, "--port", "5000", "--category", "1", needles=("--key-file",))
udp(
    "send-key-hex-refused", *SEND, "--port", "5000", "--key-hex", LIVE_KEY_TEXT.strip(),
    needles=("--key-hex", "--key-file"),
)  # fmt: skip
udp("send-src-id-negative", *SEND, "--port", "5000", "--src-id", "-1", needles=("--src-id",))
udp("send-dst-id-huge", *SEND, "--port", "5000", "--dst-id", str(2**70), needles=("--dst-id",))
for name, value in (("negative", "-1"), ("nan", "nan")):
    udp(f"send-interval-{name}", *SEND, "--port", "5000", "--interval-s", value, needles=("--interval-s",))
udp("send-corrupt-text", *SEND, "--port", "5000", "--corrupt", "x", needles=("--corrupt",))
for option, value in (("--max-age-s", "0"), ("--timeout-s", "nan"), ("--wait-s", "inf")):
    udp(f"receive{option[1:]}-{value}", *RECV, "--port", "5000", option, value, needles=(option,))
for name, value in (("negative", "-1"), ("nan", "nan")):
    udp(f"receive-linger-s-{name}", *RECV, "--port", "5000", "--linger-s", value, needles=("--linger-s",))
udp("receive-own-id-text", *RECV, "--port", "5000", "--own-id", "me", needles=("--own-id",))
udp("receive-peer-id-huge", *RECV, "--port", "5000", "--peer-id", str(2**70), needles=("--peer-id",))
for name, value in (("invalid", "no.such.host.invalid"), ("numeric", "256.0.0.1")):
    udp(f"receive-host-{name}", *RECV, "--port", "5000", "--host", value, needles=(value,))
for name, value in (("empty", ""), ("bracket", "[/]")):
    udp(f"send-host-{name}", *SEND, "--port", "5000", "--host", value, needles=(value,))


def _check_ids(cases: list[Case]) -> None:
    seen: set[str] = set()
    for case in cases:
        if case.id in seen:
            raise ValueError(f"bad_inputs: case id {case.id!r} is used twice")
        seen.add(case.id)


_check_ids(CASES)

__all__ = ["CASES", "CLI", "ERROR_PREFIX", "TIMEOUT_S", "UDP", "Case", "Outcome", "environment", "run_case"]
