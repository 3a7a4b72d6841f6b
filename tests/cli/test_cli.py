"""The ``railstop`` command end to end, each run a process of its own (forked from a warm zygote,
tests/zygote.py, unless a test needs a fresh interpreter)."""

from __future__ import annotations

import json
import re
import sqlite3
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from zygote import run_cli

EXE = [sys.executable, "-m", "railstop.cli"]


def run(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    """``railstop ARGS`` in ``cwd``: a process of its own, forked from a warm zygote (tests/zygote.py)."""
    return run_cli(*args, cwd=cwd)


def test_check_default_line(tmp_path: Path) -> None:
    p = run("check", cwd=tmp_path)
    assert p.returncode == 0, p.stderr
    assert "4 stations" in p.stdout


def test_check_says_which_zones_a_disturbance_set_reaches_beyond(tmp_path: Path) -> None:
    """`railstop check --disturbances SET`: the zones too short for the set's fastest entry on its
    steepest approach, a note each (the standard set: Hillcrest, Museum, Harbour); none for the
    nominal set; a set that is no file, one line and exit 2."""
    p = run("check", "--disturbances", "standard", cwd=tmp_path)
    assert p.returncode == 0, p.stderr
    notes = [line for line in p.stdout.splitlines() if line.startswith("note: ")]
    assert [n.split("'")[1] for n in notes] == ["Hillcrest", "Museum", "Harbour"]
    p = run("check", "--disturbances", "nominal", cwd=tmp_path)
    assert "every zone is laid out for the 'nominal' set" in p.stdout
    assert "note:" not in p.stdout
    assert "note:" not in run("check", cwd=tmp_path).stdout
    _one_line_error(run("check", "--disturbances", "nope.toml", cwd=tmp_path), "nope.toml")


def test_check_bad_file_one_line_exit_2(tmp_path: Path) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text(
        '[line]\nname = "x"\n[[stations]]\nname = "A"\nstop_point_m = 100.0\n'
        'platform_length_m = 130.0\nplatform_side = "R"\n[stations.tasc]\n'
        "detectors_before_stop_m = [50.0, 80.0, 5.0]\n"
        "doppler = { beyond_stop_m = 10.0 }\n"
    )
    p = run("check", "--line", str(bad), cwd=tmp_path)
    _one_line_error(p, str(bad), "stations[0].tasc.detectors_before_stop_m")


def test_check_unknown_key(tmp_path: Path) -> None:
    bad = tmp_path / "typo.toml"
    bad.write_text('[line]\nname = "x"\nspeed_limt_kmh = 80\n')
    p = run("check", "--line", str(bad), cwd=tmp_path)
    assert p.returncode == 2
    assert "line.speed_limt_kmh" in p.stderr and "unknown key" in p.stderr


def test_stop_json_plot_and_db(tmp_path: Path) -> None:
    db = tmp_path / "runs.db"
    png = tmp_path / "stop.png"
    args = (
        "stop",
        "--controller",
        "tasc-step",
        "--seed",
        "3",
        "--json",
        "--db",
        str(db),
        "--plot",
        str(png),
    )
    p = run(*args, cwd=tmp_path)
    assert p.returncode == 0, p.stderr
    data = json.loads(p.stdout)
    for key in (
        "controller",
        "station",
        "seed",
        "stop_error_m",
        "stop_time_s",
        "max_jerk_mps3",
        "notch_changes",
        "commands",
    ):
        assert key in data
    assert data["station"] == "Riverside" and data["controller"] == "tasc-step"
    assert abs(data["stop_error_m"]) <= 0.10
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # Same run again: identical JSON, and the database does not duplicate it.
    p2 = run(*args, cwd=tmp_path)
    assert json.loads(p2.stdout) == data
    with sqlite3.connect(db) as con:
        assert con.execute("select count(*) from runs").fetchone()[0] == 1
        n_cmd = con.execute("select count(*) from commands").fetchone()[0]
    assert n_cmd == data["commands"]


def test_stop_disturbed(tmp_path: Path) -> None:
    p = run(
        "stop",
        "--station",
        "Museum",
        "--controller",
        "tasc-pwm",
        "--load-factor",
        "1",
        "--brake-gain",
        "0.85",
        "--json",
        "--db",
        str(tmp_path / "x.db"),
        cwd=tmp_path,
    )
    assert p.returncode == 0, p.stderr
    assert abs(json.loads(p.stdout)["stop_error_m"]) <= 0.35


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (("--station", "Nowhere"), "unknown station 'Nowhere'"),
        (("--controller", "magic"), "unknown controller 'magic'"),
    ],
)
def test_stop_bad_arguments(tmp_path: Path, args: tuple[str, ...], needle: str) -> None:
    p = run("stop", *args, "--db", str(tmp_path / "x.db"), cwd=tmp_path)
    assert p.returncode == 2
    assert needle in p.stderr.replace("\n", "")
    assert "Traceback" not in p.stderr


def _one_line_error(p: subprocess.CompletedProcess[str], *needles: str) -> None:
    assert p.returncode == 2, (p.returncode, p.stderr)
    lines = [ln for ln in p.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), p.stderr
    assert "Traceback" not in p.stderr
    for needle in needles:
        assert needle in lines[0], (needle, lines[0])


def test_run_beyond_64_bits_is_one_line(tmp_path: Path) -> None:
    p = run("stop", "--disturbances", "standard", "--run", str(2**63), "--no-db", cwd=tmp_path)
    _one_line_error(p, "--run", str(2**63))


def test_plot_with_no_image_extension_is_one_line(tmp_path: Path) -> None:
    p = run("stop", "--plot", "x.txt", "--no-db", cwd=tmp_path)
    _one_line_error(p, "x.txt", "'txt' is not supported")
    assert not (tmp_path / "x.txt").exists()


@pytest.mark.parametrize("content", [b"\xff\xfe garbage", b"[1, 2]", b"{not json"])
def test_unreadable_campaign_manifest_is_one_line(tmp_path: Path, content: bytes) -> None:
    folder = tmp_path / "c"
    folder.mkdir()
    (folder / "campaign.json").write_bytes(content)
    db = tmp_path / "x.db"
    p = run("campaign", "--out", str(folder), "--resume", "--runs", "10", "--db", str(db), cwd=tmp_path)
    _one_line_error(p, "campaign.json", "manifest")
    assert (folder / "campaign.json").read_bytes() == content  # nothing overwritten


def test_names_with_brackets_are_printed_literally(tmp_path: Path) -> None:
    """User data is never rich markup: a station named "River[side]" or "[/]x" keeps its brackets."""
    from importlib import resources

    text = resources.files("railstop.data").joinpath("line.toml").read_text(encoding="utf-8")
    for name in ("River[side]", "[/]x"):
        line = tmp_path / "line.toml"
        line.write_text(text.replace('name = "Riverside"', f'name = "{name}"', 1), encoding="utf-8")
        p = run("check", "--line", str(line), cwd=tmp_path)
        assert p.returncode == 0, p.stderr
        assert name in p.stdout
        p = run("stop", "--line", str(line), "--station", name, "--no-db", cwd=tmp_path)
        assert p.returncode == 0, p.stderr
        assert p.stdout.startswith(f"tasc-pwm at {name}: "), p.stdout
        p = run("stop", "--line", str(line), "--station", name + "?", "--no-db", cwd=tmp_path)
        _one_line_error(p, f"'{name}?'", name)


@pytest.fixture(scope="module")
def compared(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, tuple[str, ...], list[dict[str, Any]]]:
    """One compare of every controller in two chunks (run, then resumed), shared by the widths."""
    tmp_path = tmp_path_factory.mktemp("compare")
    args = (
        "compare",
        "--runs",
        "200",
        "--chunk-size",
        "100",
        "--out",
        str(tmp_path / "cmp"),
        "--db",
        str(tmp_path / "c.db"),
    )
    first = run(*args, "--json", cwd=tmp_path)
    assert first.returncode == 0, first.stderr
    resumed = run(*args, "--resume", "--json", cwd=tmp_path)
    return tmp_path, args, json.loads(resumed.stdout)["controllers"]


@pytest.mark.parametrize("columns", [80, 120])
def test_summary_tables_never_cut_a_number(
    compared: tuple[Path, tuple[str, ...], list[dict[str, Any]]], columns: int
) -> None:
    """At 80 or 120 columns the compare table shows every number whole (a vertical layout when
    the one-line-per-controller table does not fit), never an ellipsis."""
    import os

    from railstop.cli.campaign import _fmt

    tmp_path, args, rows = compared
    env = {**os.environ, "COLUMNS": str(columns)}
    p = subprocess.run(
        [*EXE, *args, "--resume"], cwd=tmp_path, capture_output=True, text=True, timeout=300, env=env
    )
    assert p.returncode == 0, p.stderr
    assert "…" not in p.stdout
    assert max(len(line) for line in p.stdout.splitlines()) <= columns
    for row in rows:
        assert row["controller"] in p.stdout
        for key in (
            "within_0_30",
            "within_0_35",
            "mean_m",
            "p99_abs_m",
            "overrun_ci95_upper",
            "mean_stop_time_s",
        ):
            assert _fmt(key, row[key]) in p.stdout, (key, _fmt(key, row[key]))


def test_version(tmp_path: Path) -> None:
    from railstop import __version__

    p = run("--version", cwd=tmp_path)
    assert p.returncode == 0 and p.stdout.strip() == f"railstop {__version__}"


def test_run_without_its_disturbances_is_refused(tmp_path: Path) -> None:
    """--run replays a campaign run; without --disturbances it used to be ignored silently."""
    p = run("stop", "--run", "5", "--no-db", cwd=tmp_path)
    _one_line_error(p, "--run 5", "--disturbances")


def test_a_stop_that_never_stands_still_is_not_an_overrun(tmp_path: Path) -> None:
    """Fail safe: a train still moving when the simulation ends has no stop error; the command says
    so and exits 1 (text and JSON), never 'stop error +1608 m (overrun)' with exit 0.

    The line and vehicle are plausible; the run's brakes deliver a fiftieth of their nominal
    deceleration (a disturbance set with brake_gain fixed at 0.02).
    """
    weak = tmp_path / "weak.toml"
    weak.write_text('description = "failed brakes"\nbrake_gain = { fixed = 0.02 }\n', encoding="utf-8")
    p = run("stop", "--disturbances", str(weak), "--no-db", cwd=tmp_path)
    assert p.returncode == 1, p.stderr
    assert "did NOT come to a stand" in p.stdout and "overrun" not in p.stdout
    p = run("stop", "--disturbances", str(weak), "--no-db", "--json", cwd=tmp_path)
    assert p.returncode == 1
    row = json.loads(p.stdout)
    assert row["stopped"] is False and row["stop_time_s"] is None


def test_plot_path_printed_is_the_file_written(tmp_path: Path) -> None:
    """A name without extension gets .png, and the command prints that name; a folder is refused."""
    p = run("stop", "--plot", "noext", "--no-db", cwd=tmp_path)
    assert p.returncode == 0, p.stderr
    assert p.stdout.strip().splitlines()[-1] == "plot: noext.png"
    assert (tmp_path / "noext.png").stat().st_size > 10_000
    (tmp_path / "adir").mkdir()
    p = run("stop", "--plot", "adir", "--no-db", cwd=tmp_path)
    _one_line_error(p, "adir", "is a folder")
    assert not (tmp_path / "adir.png").exists()


@pytest.mark.parametrize(
    ("args", "needles"),
    [
        (("campaign", "--runs", "0"), ("railstop campaign", "'--runs'", "greater than or equal to 1")),
        (("campaign", "--no-such-option"), ("railstop campaign", "No such option: --no-such-option")),
        (("campain",), ("No such command 'campain'", "Did you mean 'campaign'?")),
        (("doors", "verify", "--doors-per-side", "x"), ("railstop doors verify", "'--doors-per-side'")),
        (("stop", "--seed"), ("'--seed' requires an argument",)),
    ],
)
def test_usage_errors_are_one_line_not_a_box(
    tmp_path: Path, args: tuple[str, ...], needles: tuple[str, ...]
) -> None:
    """Option values the command line itself refuses: one line naming the command and the
    option, exit 2, and where to look (not Typer's framed multi-line box)."""
    p = run(*args, cwd=tmp_path)
    _one_line_error(p, *needles, "--help)")
    assert "╭" not in p.stderr and "│" not in p.stderr


def test_railstop_alone_prints_the_help(tmp_path: Path) -> None:
    p = run(cwd=tmp_path)
    assert p.returncode == 0, p.stderr
    assert "Usage: railstop" in p.stdout and "campaign" in p.stdout


def test_psd_tolerance_is_station_data_and_an_option(tmp_path: Path) -> None:
    """The tolerance a stop is judged by comes from the station (psd_tolerance_m; SPEC §3 lines use
    ±0.50 m) unless --tolerance-m says otherwise; nothing assumes 0.35 m."""
    from importlib import resources

    text = resources.files("railstop.data").joinpath("line.toml").read_text(encoding="utf-8")
    manual = tmp_path / "manual.toml"  # Riverside with the ±0.50 m of a manually driven line
    manual.write_text(
        text.replace('platform_side = "R"\n', 'platform_side = "R"\npsd_tolerance_m = 0.5\n', 1),
        encoding="utf-8",
    )
    default = json.loads(run("stop", "--no-db", "--json", cwd=tmp_path).stdout)
    assert default["psd_tolerance_m"] == 0.35 and default["within_tolerance"] is True
    row = json.loads(run("stop", "--no-db", "--json", "--line", str(manual), cwd=tmp_path).stdout)
    assert row["psd_tolerance_m"] == 0.5 and row["within_tolerance"] is True
    assert row["stop_error_m"] == default["stop_error_m"]  # the tolerance judges; it does not steer

    tight = 0.5 * abs(default["stop_error_m"])  # half the nominal stop's error: outside
    p = run("stop", "--no-db", "--tolerance-m", str(tight), cwd=tmp_path)
    assert p.returncode == 0, p.stderr
    assert f"OUTSIDE the PSD tolerance ±{tight:g} m" in p.stdout
    row = json.loads(run("stop", "--no-db", "--json", "--tolerance-m", str(tight), cwd=tmp_path).stdout)
    assert row["psd_tolerance_m"] == tight and row["within_tolerance"] is False

    for bad in ("0", "-0.1", "nan", "2.5"):
        _one_line_error(run("stop", "--no-db", "--tolerance-m", bad, cwd=tmp_path), "--tolerance-m", bad)


def test_a_campaign_beyond_the_zones_layout_says_so(tmp_path: Path) -> None:
    """The standard set's entries (to 65 km/h) on its approach gradients (to -20 permille) need a
    longer zone than Harbour's: the campaign and the comparison say so beside their figures (text
    and JSON), and a campaign within the zone's envelope (Riverside) says nothing."""
    harbour = ("--station", "Harbour", "--runs", "6", "--db", "c.db")
    p = run("campaign", *harbour, "--out", "h", cwd=tmp_path)
    assert p.returncode == 0, p.stderr
    assert "note: the zone of 'Harbour' is short for the 'standard' set" in " ".join(p.stdout.split())
    p = run("campaign", *harbour, "--out", "h2", "--json", cwd=tmp_path)
    assert "the first detector is 250 m out" in json.loads(p.stdout)["zone_note"]
    # Run by run: the runs whose own entry and gradients the rule finds beyond the zone, counted
    # from the campaign's own rows, and the shares within the tolerance on either side.
    import numpy as np
    import pyarrow.parquet as pq

    from railstop.config import default_line, default_vehicle
    from railstop.config.plausibility import beyond_envelope

    many = ("--station", "Harbour", "--runs", "300", "--db", "c.db")
    p = run("campaign", *many, "--out", "h3", "--json", cwd=tmp_path)
    row = json.loads(p.stdout)
    t = pq.read_table(tmp_path / "h3" / "runs.parquet").to_pydict()
    col = {k: np.array(v, dtype=float) for k, v in t.items() if k != "emergency_brake"}
    beyond = beyond_envelope(
        default_line().station("Harbour"), default_vehicle(), col["entry_speed_kmh"],
        col["approach_gradient_permille"], col["platform_gradient_permille"],
    )  # fmt: skip
    assert 0 < row["runs_beyond_zone"] == int(beyond.sum()) < 300
    within = np.abs(col["stop_error_m"]) <= row["tolerance_m"]
    assert row["within_tolerance_beyond_zone"] == pytest.approx(within[beyond].mean(), abs=1e-6)
    assert row["within_tolerance_inside_zone"] == pytest.approx(within[~beyond].mean(), abs=1e-6)
    text = run("campaign", *many, "--out", "h4", cwd=tmp_path).stdout
    line = f"tasc-pwm: {row['runs_beyond_zone']} of the 300 runs drew beyond the zone's envelope"
    assert line in text
    p = run("campaign", "--runs", "6", "--out", "r", "--db", "c.db", "--json", cwd=tmp_path)
    assert json.loads(p.stdout)["zone_note"] is None
    p = run("campaign", "--runs", "6", "--out", "r2", "--db", "c.db", cwd=tmp_path)
    assert "note:" not in p.stdout
    p = run(
        "compare", "--station", "Harbour", "--runs", "3", "--controllers", "tasc-pwm,ato", "--out", "cmp",
        "--db", "c.db", cwd=tmp_path,
    )  # fmt: skip
    assert p.returncode == 0, p.stderr
    assert " ".join(p.stdout.split()).count("note: the zone of 'Harbour'") == 1


def test_campaign_and_compare_take_a_signal_form(tmp_path: Path) -> None:
    """--form on campaign and compare: the manifest and the rows say which form ran, and a run
    of the form-3 campaign replays as the detailed stop with --form 3."""
    import pyarrow.parquet as pq

    p = run("campaign", "--runs", "12", "--form", "3", "--out", "c3", "--db", "c.db", "--json", cwd=tmp_path)
    assert p.returncode == 0, p.stderr
    row = json.loads(p.stdout)
    assert row["form"] == 3
    assert json.loads((tmp_path / "c3" / "campaign.json").read_text())["form"] == 3
    errors = pq.read_table(tmp_path / "c3" / "runs.parquet").column("stop_error_m").to_pylist()
    replay = run(
        "stop", "--form", "3", "--disturbances", "standard", "--run", "7", "--no-db", "--json", cwd=tmp_path
    )
    assert replay.returncode == 0, replay.stderr
    assert json.loads(replay.stdout)["stop_error_m"] == pytest.approx(errors[7], abs=1e-6)
    default = run("campaign", "--runs", "12", "--out", "c6", "--db", "c.db", "--json", cwd=tmp_path)
    assert json.loads(default.stdout)["form"] == 6  # the station's
    assert pq.read_table(tmp_path / "c6" / "runs.parquet").column("stop_error_m").to_pylist() != errors

    p = run("compare", "--runs", "4", "--form", "5", "--out", "cmp", "--db", "c.db", "--json", cwd=tmp_path)
    assert p.returncode == 0, p.stderr
    assert {r["form"] for r in json.loads(p.stdout)["controllers"]} == {5}
    _one_line_error(run("campaign", "--form", "9", "--runs", "2", cwd=tmp_path), "--form", "(got 9)")


def test_a_form_for_a_controller_that_receives_no_telegrams_is_refused(tmp_path: Path) -> None:
    """The signal form is that of the wayside TASC's telegrams (SPEC §1 claim 3): an onboard ATO or
    a driver receives none, so a result labelled with a form would be a false label (one line,
    exit 2, nothing written)."""
    p = run("stop", "--controller", "ato", "--form", "3", "--no-db", cwd=tmp_path)
    _one_line_error(p, "--form", "ato receives none")
    p = run("campaign", "--controller", "driver-ats", "--form", "2", "--runs", "5", "--out", "c",
            cwd=tmp_path)  # fmt: skip
    _one_line_error(p, "--form", "driver-ats")
    assert not (tmp_path / "c").exists() and not (tmp_path / "railstop.db").exists()
    ok = run("stop", "--controller", "tasc-pwm", "--form", "3", "--json", "--no-db", cwd=tmp_path)
    assert ok.returncode == 0 and json.loads(ok.stdout)["form"] == 3


def test_resume_without_a_campaign_there_is_refused_not_started_afresh(tmp_path: Path) -> None:
    """--resume continues a campaign; a folder without one would silently start a new one."""
    p = run("campaign", "--runs", "5", "--out", "none-yet", "--resume", "--db", "x.db", cwd=tmp_path)
    _one_line_error(p, "none-yet", "--resume", "no campaign there")
    assert not (tmp_path / "none-yet").exists()
    p = run("line", "campaign", "--runs", "1", "--trains", "1", "--duration-s", "100", "--out", "lc",
            "--resume", cwd=tmp_path)  # fmt: skip
    _one_line_error(p, "lc", "--resume", "no line campaign there")


def test_line_run_under_an_hour_says_so_instead_of_none(tmp_path: Path) -> None:
    p = run("line", "run", "--trains", "1", "--duration-s", "300", cwd=tmp_path)
    assert p.returncode == 0, p.stderr
    assert "None" not in p.stdout and "the run is under an hour" in p.stdout


def test_line_run_regulation_holds_trains_and_needs_cbtc(tmp_path: Path) -> None:
    """``--regulation``: the ATS holds trains at their platforms (the summary counts the holds, the
    text says so); without CBTC it is refused in one line."""
    p = run("line", "run", "--trains", "5", "--headway-s", "60", "--duration-s", "900", "--signalling",
            "cbtc", "--regulation", "--json", cwd=tmp_path)  # fmt: skip
    assert p.returncode == 0, p.stderr
    cbtc = json.loads(p.stdout)["cbtc"]
    assert cbtc["regulation_holds"] >= 1 and cbtc["regulation_hold_s"] > 0.0
    assert cbtc["authority_overlaps"] == 0 and cbtc["collisions"] == 0
    p = run("line", "run", "--trains", "5", "--headway-s", "60", "--duration-s", "900", "--signalling",
            "cbtc", "--regulation", cwd=tmp_path)  # fmt: skip
    assert p.returncode == 0, p.stderr
    assert "the ATS held trains" in p.stdout
    # Under CBTC the text gives its safety counts too.
    assert "CBTC (minimal zones):" in p.stdout and " authority overlaps, 0 collisions" in p.stdout
    p = run("line", "run", "--trains", "1", "--duration-s", "100", "--regulation", cwd=tmp_path)
    _one_line_error(p, "regulation", "CBTC", "fixed-block")


def _all_help_paths() -> list[tuple[str, ...]]:
    """Every command and group of ``railstop``, as argv before ``--help``."""
    import typer

    from railstop.cli import app

    paths: list[tuple[str, ...]] = [()]
    root = typer.main.get_command(app)

    def walk(group: Any, prefix: tuple[str, ...]) -> None:
        context = group.context_class(group)
        for name in group.list_commands(context):
            paths.append((*prefix, name))
            cmd = group.get_command(context, name)
            if hasattr(cmd, "list_commands"):
                walk(cmd, (*prefix, name))

    walk(root, ())
    return paths


def test_no_help_text_cuts_a_word_at_80_columns(monkeypatch: pytest.MonkeyPatch) -> None:
    """Every --help at 80 columns: no ellipsis (nothing cut), every command's first paragraph
    and every controller's name whole (a name may wrap at its own hyphen)."""
    from typer.testing import CliRunner

    from railstop.controllers import CONTROLLERS

    monkeypatch.setenv("COLUMNS", "80")
    runner = CliRunner()
    from railstop.cli import app

    seen_controllers = False
    for path in _all_help_paths():
        r = runner.invoke(app, [*path, "--help"], prog_name="railstop")
        assert r.exit_code == 0, (path, r.output)
        text = r.output
        cut = [ln for ln in text.splitlines() if ln.rstrip().endswith("...") and "Usage:" not in ln]
        assert "…" not in text and not cut, (path, cut)
        joined = re.sub(r"-\n\s+", "-", text)  # a word wrapped at its own hyphen
        if "--controller " in text and "One of:" in text:
            seen_controllers = True
            for name in CONTROLLERS:
                assert name in joined, (path, name)
    assert seen_controllers


def test_the_detectors_only_variant_from_the_command_line(tmp_path: Path) -> None:
    """SPEC §1 claim 6 on `stop` and `campaign`: --detectors-only runs the station without its
    Doppler radar on its zone's variant layout, and the database keeps the station as run."""
    db = tmp_path / "runs.db"
    p = run("stop", "--detectors-only", "--station", "Museum", "--json", "--db", str(db), cwd=tmp_path)
    assert p.returncode == 0, p.stderr
    data = json.loads(p.stdout)
    # One command per passage but the first (a speed needs two), within the PSD tolerance.
    assert data["commands"] == 7 - 1
    assert data["within_tolerance"] and data["emergency_brake"] is None
    with sqlite3.connect(db) as con:
        query = "select detector_positions_m_json, tasc_json, doppler_position_m from stations"
        (positions, tasc, radar) = con.execute(query).fetchone()
    assert json.loads(tasc)["doppler"] is None and radar is None
    assert len(json.loads(positions)) == 7
    args = ("campaign", "--detectors-only", "--runs", "40", "--out", "c", "--json", "--db", str(db))
    c = run(*args, cwd=tmp_path)
    assert c.returncode == 0, c.stderr
    assert json.loads(c.stdout)["within_0_30"] >= 0.95
    cmp = run(
        "compare", "--detectors-only", "--controllers", "tasc-pwm", "--runs", "40", "--out", "k", cwd=tmp_path
    )
    assert cmp.returncode == 0, cmp.stderr
    assert "tasc-pwm" in cmp.stdout


def test_a_zone_without_a_variant_layout_is_refused_in_one_line(tmp_path: Path) -> None:
    text = (Path(__file__).parents[2] / "src/railstop/data/line.toml").read_text(encoding="utf-8")
    text = text.replace("[330.0, 230.0, 140.0, 60.0, 6.0]", "[330.0, 230.0]", 1)
    text = "\n".join(ln for ln in text.splitlines() if not ln.startswith("detectors_only_before_stop_m"))
    (tmp_path / "line.toml").write_text(text, encoding="utf-8")
    for args in (("stop", "--no-db"), ("campaign", "--runs", "10", "--out", "c"), ("compare", "--out", "c")):
        p = run(*args, "--detectors-only", "--line", "line.toml", cwd=tmp_path)
        assert p.returncode == 2, p.stderr
        lines = [ln for ln in p.stderr.splitlines() if ln.strip()]
        assert len(lines) == 1 and "Traceback" not in p.stderr
        assert "'Riverside': no detectors-only variant: tasc.detectors_before_stop_m" in lines[0]
    assert not (tmp_path / "c").exists()


def _printed_report_command(stdout: str) -> list[str]:
    """The ``railstop report ...`` command a run printed as its hint, as argv (without railstop)."""
    import shlex

    found = re.search(r"`(railstop report [^`]+)` writes the HTML report", " ".join(stdout.split()))
    assert found, stdout
    argv = shlex.split(found.group(1))
    assert argv[:2] == ["railstop", "report"]
    return argv[1:]


def test_the_printed_report_command_works_on_ones_own_data(tmp_path: Path) -> None:
    """compare on one's own line and vehicle (and --detectors-only) prints the `railstop report`
    command with the data options it ran on: run as printed, it writes the report (the report
    replays the worst runs on the same data; without them it would refuse)."""
    data = Path(__file__).parents[2] / "src/railstop/data"
    text = (data / "line.toml").read_text(encoding="utf-8")
    (tmp_path / "my line.toml").write_text(text.replace('"Riverside"', '"Quayside"'), encoding="utf-8")
    vehicle = (data / "vehicle.toml").read_text(encoding="utf-8")
    assert 'name = "6-car metro EMU (4M2T)"' in vehicle
    (tmp_path / "veh.toml").write_text(vehicle.replace("(4M2T)", "(4M2T), ours"), encoding="utf-8")
    own = ("--line", "my line.toml", "--vehicle", "veh.toml", "--db", "c.db")
    for extra, out in (((), "cmp a"), (("--detectors-only",), "cmp b")):
        p = run(
            "compare", "--controllers", "tasc-pwm", "--runs", "3", "--out", out, *own, *extra, cwd=tmp_path
        )
        assert p.returncode == 0, p.stderr
        argv = _printed_report_command(p.stdout)
        assert argv[1] == out and "--line" in argv and "--vehicle" in argv
        assert ("--detectors-only" in argv) == bool(extra)
        r = run(*argv, cwd=tmp_path)
        assert r.returncode == 0, (argv, r.stderr)
        assert (tmp_path / out / "report.html").is_file()
    # The command as printed before (the folder alone, or without the vehicle) is refused on these
    # campaigns: the hint needs the options.
    for argv in (("report", "cmp a"), ("report", "cmp a", "--line", "my line.toml")):
        _one_line_error(run(*argv, cwd=tmp_path), "other line or vehicle data than given")


def test_the_report_command_names_every_data_option_given() -> None:
    """The hint of compare and demo: the data options given, quoted for the shell."""
    from railstop.cli.campaign import report_command

    assert report_command(Path("cmp")) == "railstop report cmp"
    command = report_command(
        Path("out dir/compare"),
        line=Path("l.toml"),
        vehicle=Path("v.toml"),
        driver=Path("d.toml"),
        platform=Path("p.toml"),
        law=Path("law.py"),
        detectors_only=True,
    )
    assert command == (
        "railstop report 'out dir/compare' --line l.toml --vehicle v.toml --driver d.toml "
        "--platform p.toml --law law.py --detectors-only"
    )
