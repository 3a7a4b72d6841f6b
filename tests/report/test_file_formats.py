"""The data-file reference generated from the schemas, and the starter set of ``railstop init``.

``railstop.report.file_formats`` walks the model each loader validates against; the meaning of a
key is the source's comment on its field. The reference in ``docs/`` must be what the code
renders, every key must have a meaning, and every key of every embedded file must be in it.
``railstop init DIR`` writes commented copies of the embedded files; a newcomer's path (init,
edit three numbers, check, campaign) is scripted here through the real command.
"""

from __future__ import annotations

import json
import os
import subprocess
import tomllib
from importlib import resources
from pathlib import Path
from typing import Any

import pytest

from railstop.report.file_formats import (
    file_formats,
    missing_meanings,
    range_text,
    render_markdown,
    tables,
    unit_of,
)
from zygote import run_cli

ROOT = Path(__file__).resolve().parents[2]
DOC = ROOT / "docs" / "file-formats.md"


def run(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "COLUMNS": "200"}  # the tables' keys unfolded
    return run_cli(*args, cwd=cwd, env=env)  # forked from a warm zygote of its own COLUMNS


@pytest.mark.parametrize("fmt", file_formats(), ids=lambda f: f.name)
def test_every_key_of_every_file_has_a_meaning(fmt: Any) -> None:
    assert missing_meanings(fmt) == []


def test_the_reference_in_the_docs_is_up_to_date() -> None:
    """``railstop formats --markdown docs/file-formats.md`` rewrites it."""
    assert DOC.read_text(encoding="utf-8") == render_markdown()


def _key_paths(data: dict[str, Any], prefix: str = "") -> set[str]:
    """Every key of a TOML document as ``table.key`` (arrays of tables without their index)."""
    out: set[str] = set()
    for key, value in data.items():
        path = f"{prefix}.{key}" if prefix else key
        out.add(path)
        if isinstance(value, dict):
            out |= _key_paths(value, path)
        elif isinstance(value, list) and value and all(isinstance(v, dict) for v in value):
            for item in value:
                out |= _key_paths(item, path)
    return out


def _documented(fmt: Any) -> set[str]:
    out: set[str] = set()
    for t in tables(fmt.model, fmt.root):
        base = t.header.strip("[]")
        out.add(base)
        for k in t.keys:
            out.add(f"{base}.{k.key}" if base else k.key)
    return out


@pytest.mark.parametrize("fmt", [f for f in file_formats() if f.embedded], ids=lambda f: f.name)
def test_every_key_of_the_embedded_file_is_in_the_reference(fmt: Any) -> None:
    name = fmt.embedded.removeprefix("railstop/data/")
    data = tomllib.loads(resources.files("railstop.data").joinpath(name).read_text(encoding="utf-8"))
    documented = _documented(fmt)
    # media: one table per medium, each documented as the one [<medium>].
    paths = set().union(*(_key_paths({fmt.root: v}) for v in data.values())) if fmt.root else _key_paths(data)
    # A table of named tables (the driver's levels) is documented under <name>.
    keys = {p if p in documented else _named(p, documented) for p in paths}
    assert keys <= documented, sorted(keys - documented)


def _named(path: str, documented: set[str]) -> str:
    parts = path.split(".")
    for i in range(len(parts)):
        trial = ".".join([*parts[:i], "<name>", *parts[i + 1 :]])
        if trial in documented:
            return trial
    return path


def test_units_ranges_and_types_read_as_the_schema_says() -> None:
    line = next(f for f in file_formats() if f.name == "line")
    keys = {(t.header.strip("[]"), k.key): k for t in tables(line.model) for k in t.keys}
    tol = keys[("stations", "psd_tolerance_m")]
    assert (tol.unit, tol.range, tol.default, tol.type) == ("m", "0 < x ≤ 2", "0.35", "number")
    assert keys[("line", "speed_limit_kmh")].unit == "km/h"
    side = keys[("stations", "platform_side")]
    assert side.type == 'one of "L", "R"' and side.default == "required"
    det = keys[("stations.tasc", "detectors_before_stop_m")]
    assert det.type == "list of numbers" and det.range == "each x > 0"
    assert keys[("", "stations")].range == "at least 1 item"
    assert unit_of("davis_b_n_per_mps") == "N/(m/s)" and unit_of("gradient_permille") == "‰"
    assert range_text([]) == ""


def test_formats_prints_the_overview_one_kind_and_refuses_an_unknown_one(tmp_path: Path) -> None:
    r = run("formats", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert "line" in r.stdout and "railstop/data/line" in r.stdout
    r = run("formats", "vehicle", cwd=tmp_path)
    assert r.returncode == 0 and "tare_mass_kg" in r.stdout
    r = run("formats", "tracks", cwd=tmp_path)
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "tracks" in r.stderr
    r = run("formats", "--markdown", str(tmp_path / "ref.md"), cwd=tmp_path)
    assert r.returncode == 0 and (tmp_path / "ref.md").read_text(encoding="utf-8") == render_markdown()


def _edit(path: Path, old: str, new: str) -> None:
    text = path.read_text(encoding="utf-8")
    assert text.count(old) >= 1, old
    path.write_text(text.replace(old, new, 1), encoding="utf-8")


def test_a_newcomer_inits_edits_three_numbers_checks_and_runs_a_campaign(tmp_path: Path) -> None:
    r = run("init", "mystation", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    d = tmp_path / "mystation"
    names = sorted(p.name for p in d.iterdir())
    assert names == sorted(
        [
            "line.toml",
            "vehicle.toml",
            "operation.toml",
            "doors.toml",
            "platform.toml",
            "driver.toml",
            "disturbances.toml",
        ]
    )
    head = (d / "line.toml").read_text(encoding="utf-8").splitlines()[:8]
    assert head[0].startswith("# railstop line file") and any("psd_tolerance_m" in h for h in head)
    # Three numbers of one's own: the line's limit, the first station's entry speed, the mass.
    _edit(d / "line.toml", "speed_limit_kmh = 80.0", "speed_limit_kmh = 70.0")
    _edit(d / "line.toml", "entry_speed_kmh = 60.0", "entry_speed_kmh = 55.0")
    _edit(d / "vehicle.toml", "tare_mass_kg = 200000.0", "tare_mass_kg = 210000.0")
    files = ["--line", "mystation/line.toml", "--vehicle", "mystation/vehicle.toml"]
    r = run("check", *files, "--operation", "mystation/operation.toml", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert r.stdout.startswith("ok: mystation/line.toml")
    out = tmp_path / "c"
    r = run(
        "campaign", *files, "--runs", "40", "--disturbances", "mystation/disturbances.toml",
        "--out", str(out), "--json", "--db", str(tmp_path / "mine.db"),
        cwd=tmp_path,
    )  # fmt: skip
    assert r.returncode == 0, r.stderr
    mine = json.loads(r.stdout)
    assert mine["runs"] == 40
    # The edited files are the ones run: the same draws on the embedded data stop elsewhere.
    r = run(
        "campaign",
        "--runs",
        "40",
        "--out",
        str(tmp_path / "e"),
        "--json",
        "--db",
        str(tmp_path / "e.db"),
        cwd=tmp_path,
    )
    assert r.returncode == 0, r.stderr
    embedded = json.loads(r.stdout)
    assert mine != embedded


def test_init_never_overwrites_and_says_so_in_one_line(tmp_path: Path) -> None:
    d = tmp_path / "mine"
    d.mkdir()
    (d / "vehicle.toml").write_text("# my own\n", encoding="utf-8")
    r = run("init", "mine", cwd=tmp_path)
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "vehicle.toml" in r.stderr
    assert (d / "vehicle.toml").read_text(encoding="utf-8") == "# my own\n"
    assert not (d / "line.toml").exists()  # nothing written when anything is in the way
    (tmp_path / "afile").write_text("x", encoding="utf-8")
    r = run("init", "afile", cwd=tmp_path)
    assert r.returncode == 2 and "not a folder" in r.stderr


def test_check_judges_a_line_of_one_s_own_without_the_embedded_operation(tmp_path: Path) -> None:
    run("init", "s", cwd=tmp_path)
    line = tmp_path / "s" / "line.toml"
    _edit(line, 'name = "Hillcrest"', 'name = "Eastfield"')  # the operation gives it a dwell
    r = run("check", "--line", str(line), cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert "operation: none given" in r.stdout
    # Given, the operation is checked against the line, and its file is named.
    r = run("check", "--line", str(line), "--operation", "s/operation.toml", cwd=tmp_path)
    assert r.returncode == 2 and "s/operation.toml" in r.stderr and "Hillcrest" in r.stderr


# ---------------------------------------------------------------------- one PSD tolerance per station


def _station_tolerance(tmp_path: Path, tolerance_m: float) -> Path:
    """The embedded line with its first station's PSD tolerance set."""
    line = tmp_path / "line.toml"
    text = resources.files("railstop.data").joinpath("line.toml").read_text(encoding="utf-8")
    line.write_text(
        text.replace('platform_side = "R"', f'platform_side = "R"\npsd_tolerance_m = {tolerance_m}', 1),
        encoding="utf-8",
    )
    return line


def test_the_dwell_judges_a_stop_by_the_station_s_own_tolerance(tmp_path: Path) -> None:
    """A 0.32 m stop: in tolerance at a ±0.35 m station, corrected at a ±0.30 m one (the doors file
    used to judge every dwell by its own 0.35 m whatever the station's)."""
    results = {}
    for tol in (0.35, 0.30):
        line = _station_tolerance(tmp_path, tol)
        r = run(
            "dwell",
            "--line",
            str(line),
            "--stop-error-m",
            "0.32",
            "--json",
            "--db",
            str(tmp_path / "d.db"),
            cwd=tmp_path,
        )
        assert r.returncode == 0, r.stderr
        results[tol] = json.loads(r.stdout)
    assert results[0.35]["corrections"] == 0
    assert results[0.30]["corrections"] >= 1


def test_a_doors_file_with_another_tolerance_than_the_station_s_is_refused(tmp_path: Path) -> None:
    line = _station_tolerance(tmp_path, 0.30)
    doors = tmp_path / "doors.toml"
    text = resources.files("railstop.data").joinpath("doors.toml").read_text(encoding="utf-8")
    doors.write_text(
        text.replace('tolerance = "psd"\n', 'tolerance = "psd"\npsd_tolerance_m = 0.35\n', 1),
        encoding="utf-8",
    )
    r = run("dwell", "--line", str(line), "--doors", str(doors), "--stop-error-m", "0.1", cwd=tmp_path)
    assert r.returncode == 2 and r.stderr.count("\n") == 1, r.stderr
    assert "doors.toml" in r.stderr and "stop_confirm.psd_tolerance_m" in r.stderr and str(line) in r.stderr
    # The same value as the station's is accepted.
    doors.write_text(
        text.replace('tolerance = "psd"\n', 'tolerance = "psd"\npsd_tolerance_m = 0.3\n', 1), encoding="utf-8"
    )
    r = run(
        "dwell",
        "--line",
        str(line),
        "--doors",
        str(doors),
        "--stop-error-m",
        "0.1",
        "--db",
        str(tmp_path / "d.db"),
        cwd=tmp_path,
    )
    assert r.returncode == 0, r.stderr
