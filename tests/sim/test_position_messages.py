"""``railstop position-run``: every refused value is one line naming the option as typed, the value as
typed and the rule in the option's unit; NaN and infinity are called what they are; no value is
silently changed (``--slides`` beyond the line's braking zones is refused, not capped).

Also the disturbance file's probabilities: NaN and infinity are "not a number" / "not finite".
"""

from __future__ import annotations

import math
import os
import subprocess
import sys
from pathlib import Path

import pytest

from railstop.config import default_line, default_vehicle
from railstop.config.disturbances import DisturbanceSet, load_disturbances
from railstop.errors import ConfigError, SimulationError
from railstop.sim.position_run import PositionRunSettings, SettingError, run_position
from zygote import run_cli

EXE = [sys.executable, "-m", "railstop.cli", "position-run"]
STOPS = len(default_line().stations)


def _cli(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "COLUMNS": "400"}  # help rows on one line each
    return run_cli(*EXE[3:], *args, cwd=cwd, env=env)  # forked from a warm zygote (tests/zygote.py)


def _one_line_error(p: subprocess.CompletedProcess[str]) -> str:
    assert p.returncode == 2, (p.stdout, p.stderr)
    assert "Traceback" not in p.stderr
    lines = [ln for ln in p.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1, p.stderr
    assert p.stdout == ""
    return lines[0]


@pytest.mark.parametrize(
    ("args", "want"),
    [
        # The option, the value as typed, the rule in the option's unit (mm, not m).
        (
            ("--wheel-diameter-mm", "-820"),
            "--wheel-diameter-mm: must be greater than 500 mm and less than 1200 mm (got -820)",
        ),
        (
            ("--wheel-diameter-mm=1200.0",),
            "--wheel-diameter-mm: must be greater than 500 mm and less than 1200 mm (got 1200.0)",
        ),
        (("--wheel-diameter-mm", "nan"), "--wheel-diameter-mm: not a number (got nan)"),
        (("--wheel-diameter-mm", "1e400"), "--wheel-diameter-mm: not finite (got 1e400)"),
        (("--wheel-diameter-mm", "abc"), "--wheel-diameter-mm: not a number (got 'abc')"),
        (("--diameter-error-pct", "30"), "--diameter-error-pct: must be between -20 % and 20 % (got 30)"),
        (("--diameter-error-pct", "NaN"), "--diameter-error-pct: not a number (got NaN)"),
        (("--diameter-error-pct", "-inf"), "--diameter-error-pct: not finite (got -inf)"),
        # Hours, as typed; not the seconds the simulation uses.
        (("--holdover-h", "-1"), "--holdover-h: must be between 0 h and 8888.89 h (got -1)"),
        (("--holdover-h", "10000"), "--holdover-h: must be between 0 h and 8888.89 h (got 10000)"),
        (("--holdover-h", "nan"), "--holdover-h: not a number (got nan)"),
        (("--holdover-h", "inf"), "--holdover-h: not finite (got inf)"),
        (("--low-mu", "0"), "--low-mu: must be greater than 0 and at most 0.5 (got 0)"),
        (("--low-mu", "nan"), "--low-mu: not a number (got nan)"),
        (("--low-mu", "inf"), "--low-mu: not finite (got inf)"),
        (("--slides", "-1"), "--slides: must be at least 0 (got -1)"),
        (("--slides", "1.5"), "--slides: not a whole number (got 1.5)"),
        (("--slides", "nan"), "--slides: not a number (got nan)"),
        (("--slips", "-3"), "--slips: must be at least 0 (got -3)"),
        (("--slips", "x"), "--slips: not a number (got 'x')"),
        (("--seed", "x"), "--seed: not a number (got 'x')"),
        (
            ("--seed", "99999999999999999999"),
            "--seed: must be between -2^63 and 2^63 - 1, the range of the random streams "
            "(got 99999999999999999999)",
        ),
        (("--run", "-1"), "--run: must be between 0 and 2^63 - 1 (got -1)"),
        (("--run", "9223372036854775808"), "--run: must be between 0 and 2^63 - 1 (got 9223372036854775808)"),
        # Too many patches: refused with the line's limit and why, never capped.
        (
            ("--slides", "1000"),
            f"--slides: at most {STOPS} on this line: one slide patch per braking zone, "
            f"and the line has {STOPS} stations to stop at (got 1000)",
        ),
        (
            ("--slips", "1000"),
            f"--slips: at most {STOPS} on this line: one slip patch per traction zone, "
            f"and the line has {STOPS} stations to start from (got 1000)",
        ),
    ],
)
def test_a_bad_option_value_is_one_line_in_the_options_terms(
    tmp_path: Path, args: tuple[str, ...], want: str
) -> None:
    assert _one_line_error(_cli(*args, cwd=tmp_path)) == f"error: {want}"


def test_file_options_name_the_option(tmp_path: Path) -> None:
    missing = tmp_path / "missing.toml"
    for opt in ("--line", "--vehicle", "--disturbances"):
        line = _one_line_error(_cli(opt, str(missing), cwd=tmp_path))
        assert line.startswith(f"error: {opt}: {missing}: "), line
        assert "no such file" in line
    # A plot that cannot be written is refused before the run, not after it.
    line = _one_line_error(_cli("--plot", str(tmp_path / "no-dir" / "p.png"), cwd=tmp_path))
    assert line.startswith(f"error: --plot: {tmp_path / 'no-dir' / 'p.png'}: "), line
    line = _one_line_error(_cli("--plot", str(tmp_path), cwd=tmp_path))
    assert line.startswith(f"error: --plot: {tmp_path}: is a folder"), line


@pytest.mark.parametrize(
    ("text", "want"),
    [
        ("nan", "low_adhesion_probability: not a number (got nan)"),
        ("inf", "low_adhesion_probability: not finite (got inf)"),
        ("-inf", "low_adhesion_probability: not finite (got -inf)"),
    ],
)
def test_disturbance_file_nan_and_inf_are_not_too_big_or_too_small(
    tmp_path: Path, text: str, want: str
) -> None:
    path = tmp_path / "d.toml"
    path.write_text(f"low_adhesion_probability = {text}\n", encoding="utf-8")
    with pytest.raises(ConfigError) as info:
        load_disturbances(path)
    assert str(info.value) == f"{path}: {want}"
    line = _one_line_error(_cli("--disturbances", str(path), cwd=tmp_path))
    assert line == f"error: --disturbances: {path}: {want}"
    # Out of range stays out of range.
    with pytest.raises(ConfigError, match="less than or equal to 1"):
        DisturbanceSet.from_dict({"low_adhesion_probability": 2.0})


@pytest.mark.parametrize(
    ("kwargs", "want"),
    [
        ({"low_mu": math.nan}, "low_mu: not a number (got nan)"),
        ({"diameter_error_pct": math.inf}, "diameter_error_pct: not finite (got inf)"),
        ({"holdover_s": math.nan}, "holdover_s: not a number (got nan)"),
        ({"wheel_diameter_m": -0.82}, "wheel_diameter_m: must be greater than 0.5 m and less than 1.2 m"),
        ({"slide_probability": math.nan}, "slide_probability: not a number (got nan)"),
        ({"patch_length_m": (math.nan, 50.0)}, "patch_length_m: not a number (got (nan, 50.0))"),
    ],
)
def test_settings_describe_nan_and_inf_as_such(kwargs: dict[str, object], want: str) -> None:
    with pytest.raises(SettingError) as info:
        PositionRunSettings(**kwargs)  # type: ignore[arg-type]
    assert str(info.value).startswith(want)
    assert isinstance(info.value, SimulationError)


def test_more_patches_than_zones_is_refused_not_capped() -> None:
    with pytest.raises(SettingError, match=rf"slides: at most {STOPS} on this line") as info:
        run_position(default_line(), default_vehicle(), PositionRunSettings(slides=STOPS + 1))
    assert info.value.setting == "slides" and info.value.value == STOPS + 1


def test_help_quotes_the_defaults(tmp_path: Path) -> None:
    p = _cli("--help", cwd=tmp_path)
    assert p.returncode == 0, p.stderr
    text = " ".join(p.stdout.split())
    assert "[default: 2]" in text and "[default: 0.05]" in text and "[default: the vehicle's]" in text
