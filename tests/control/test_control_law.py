"""A stop-control law of the user's own (railstop.control.law): written outside the package, run
by the campaign, compare and the detailed stop like the built-in laws; bad laws refused with one
line; a law that misbehaves at run time brakes at full service (HZ-LAW-1)."""

from __future__ import annotations

import hashlib
import json
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from railstop.config import default_line, default_vehicle
from railstop.config.disturbances import load_disturbances
from railstop.control.law import LawFile, load_law_file
from railstop.controllers import known_controllers
from railstop.errors import ConfigError
from railstop.sim.campaign import CampaignSpec, simulate_block, simulate_runs
from zygote import run_cli

EXE = [sys.executable, "-m", "railstop.cli"]

#: The example law of docs/control-law.md (a file outside the package).
EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "laws" / "constant_decel.py"
CONSTANT_DECEL = EXAMPLE.read_text()


def _write(path: Path, text: str) -> Path:
    path.write_text(textwrap.dedent(text))  # (a copy: a test may change it)
    return path


def run(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    """``railstop ARGS`` in ``cwd``: a process of its own, forked from a warm zygote (tests/zygote.py)."""
    return run_cli(*args, cwd=cwd)


def _one_line_error(p: subprocess.CompletedProcess[str], *needles: str) -> None:
    assert p.returncode == 2, (p.stdout, p.stderr)
    assert "Traceback" not in p.stderr
    assert len(p.stderr.strip().splitlines()) == 1, p.stderr
    for needle in needles:
        assert needle in p.stderr, (needle, p.stderr)


def test_a_law_written_outside_the_package_runs_in_campaign_and_compare(tmp_path: Path) -> None:
    law = _write(tmp_path / "mylaw.py", CONSTANT_DECEL)
    db = str(tmp_path / "r.db")
    p = run("campaign", "--law", str(law), "--controller", "constant-decel", "--runs", "40", "--json",
            "--db", db, "--out", "c", cwd=tmp_path)  # fmt: skip
    assert p.returncode == 0, p.stderr
    row = json.loads(p.stdout)
    assert row["controller"] == "constant-decel" and row["runs"] == 40
    manifest = json.loads((tmp_path / "c" / "campaign.json").read_text())
    assert manifest["controller"] == "constant-decel"
    assert manifest["law"] == {"file": "mylaw.py", "sha256": LawFile.of(law).sha256}

    p = run("compare", "--law", str(law), "--controllers", "tasc-pwm,constant-decel", "--runs", "40",
            "--json", "--db", db, "--out", "cmp", cwd=tmp_path)  # fmt: skip
    assert p.returncode == 0, p.stderr
    rows = json.loads(p.stdout)["controllers"]
    assert [r["controller"] for r in rows] == ["tasc-pwm", "constant-decel"]
    # Identical draws: every drawn column of the two campaigns' runs is the same.
    a = pq.read_table(tmp_path / "cmp" / "tasc-pwm" / "runs.parquet").to_pydict()
    b = pq.read_table(tmp_path / "cmp" / "constant-decel" / "runs.parquet").to_pydict()
    for column in ("entry_speed_kmh", "load_factor", "brake_gain", "brake_dead_time_s", "wheel_diameter_mm"):
        assert a[column] == b[column]
    assert a["stop_error_m"] != b["stop_error_m"]  # two different laws
    # The built-in controller's campaign keeps its identity: it records no law file.
    assert "law" not in json.loads((tmp_path / "cmp" / "tasc-pwm" / "campaign.json").read_text())
    # The same law campaign of the comparison equals the campaign above (same seed, same draws).
    c = pq.read_table(tmp_path / "c" / "runs.parquet").to_pydict()
    assert c["stop_error_m"] == b["stop_error_m"]

    # The report replays the worst runs: a law campaign's needs its file, a built-in one's not.
    p = run("report", "cmp", "--worst", "1", cwd=tmp_path)
    _one_line_error(p, "constant-decel", "--law")
    p = run("report", "cmp", "--worst", "1", "--law", str(law), cwd=tmp_path)
    assert p.returncode == 0, p.stderr
    assert (tmp_path / "cmp" / "report.html").is_file()

    # Resuming with a changed law file is refused: the campaign would mix two laws.
    law.write_text(law.read_text().replace("0.5", "0.6"))
    p = run("campaign", "--law", str(law), "--controller", "constant-decel", "--runs", "40",
            "--db", db, "--out", "c", "--resume", cwd=tmp_path)  # fmt: skip
    _one_line_error(p, "law")


def test_the_ato_law_from_a_file_equals_the_built_in_ato(tmp_path: Path) -> None:
    """The interface gives a law everything the ATO needs: the ATO's own function, loaded from a
    file as a user's law, stops every run exactly as the built-in ``ato`` and ``ato-corrected``."""
    law = _write(
        tmp_path / "copy.py",
        """
        from railstop.control.law import control_law
        from railstop.onboard.ato import ato_law_function

        my_ato = control_law(name="my-ato")(ato_law_function)
        my_ato_corrected = control_law(name="my-ato-corrected", positioning="corrected")(ato_law_function)
        """,
    )
    names = [x.name for x in load_law_file(law)]
    assert sorted(names) == ["my-ato", "my-ato-corrected"]
    assert "my-ato" in known_controllers()
    line, vehicle = default_line(), default_vehicle()
    dist = load_disturbances("standard")
    station = line.stations[1]
    for builtin, mine in (("ato", "my-ato"), ("ato-corrected", "my-ato-corrected")):
        kw = dict(station=station, vehicle=vehicle, disturbances=dist, seed=5, track=line.track)
        a, _ = simulate_runs(controller=builtin, first_run=0, n=60, **kw)  # type: ignore[arg-type]
        b, _ = simulate_runs(controller=mine, first_run=0, n=60, **kw)  # type: ignore[arg-type]
        np.testing.assert_array_equal(a.stop_error_m, b.stop_error_m)
        np.testing.assert_array_equal(a.notch_changes, b.notch_changes)
        ra, _ = simulate_runs(controller=builtin, first_run=3, n=1, record=True, **kw)  # type: ignore[arg-type]
        rb, _ = simulate_runs(controller=mine, first_run=3, n=1, record=True, **kw)  # type: ignore[arg-type]
        assert ra.trace is not None and rb.trace is not None
        np.testing.assert_array_equal(ra.trace.target_decel_mps2, rb.trace.target_decel_mps2)
        np.testing.assert_array_equal(ra.trace.position_m, rb.trace.position_m)


@pytest.mark.parametrize(
    ("body", "what"),
    [
        ("return np.nan", "not a number"),
        ("return state[LAW_STATE_SIZE + 1000]", "an index outside its state"),
        ("raise ValueError('no')", "an error"),
        ("return 1.0e9", "more than full service"),
    ],
)
def test_a_misbehaving_law_brakes_at_full_service(tmp_path: Path, body: str, what: str) -> None:
    """HZ-LAW-1: whatever the law returns or does, the demand the brakes get is within [0, full
    service], and a law that fails asks for full service."""
    name = f"bad-{hashlib.sha256(body.encode()).hexdigest()[:12]}"  # one name per body in every run
    law = _write(
        tmp_path / "bad.py",
        f"""
        import numpy as np
        from railstop.control.law import LAW_STATE_SIZE, control_law

        @control_law(name="{name}")
        def bad(meas, state, params):
            if meas[0].distance_m < 1.0e9:
                {body}
            return 0.0
        """,
    )
    load_law_file(law)
    line, vehicle = default_line(), default_vehicle()
    station = line.stations[0]
    kw = dict(station=station, vehicle=vehicle, disturbances=load_disturbances("nominal"), seed=1, n=1)
    result, _ = simulate_runs(controller=name, first_run=0, record=True, **kw)  # type: ignore[arg-type]
    assert result.trace is not None
    target = result.trace.target_decel_mps2[:, 0]
    asked = target[np.isfinite(target)]
    full = vehicle.brake.full_service_mps2
    assert asked.size > 0, what
    # From the law's first call (the first controller cycle after the first fix) to the stop.
    first_call = round(vehicle.brake.controller_cycle_s / 0.01)
    assert np.all(asked[first_call:] == full) and np.all(asked[:first_call] <= full), what
    # Full service from the first fix (a transponder far before the stop): the train stops short.
    assert result.stopped[0] and result.stop_error_m[0] < -5.0, what


def test_a_campaign_block_in_another_process_gets_the_law_from_the_spec(tmp_path: Path) -> None:
    """A worker process (or a Dask worker on another machine) gets the law's text with the spec,
    not a path it may not have."""
    import concurrent.futures
    import multiprocessing

    law = _write(tmp_path / "mylaw.py", CONSTANT_DECEL)
    law_file = LawFile.of(law)
    law_file.load()
    line, vehicle = default_line(), default_vehicle()
    spec = CampaignSpec(
        line=line,
        vehicle=vehicle,
        station=line.stations[0].name,
        controller="constant-decel",
        runs=8,
        seed=2,
        disturbances=load_disturbances("standard"),
        law=law_file,
    )
    here = simulate_block(spec, (0, 0, 8))
    law.unlink()  # the worker cannot read the file
    ctx = multiprocessing.get_context("spawn")
    with concurrent.futures.ProcessPoolExecutor(1, mp_context=ctx) as pool:
        there = pool.submit(simulate_block, spec, (0, 0, 8)).result(timeout=280)
    assert here.equals(there)


@pytest.mark.parametrize(
    ("text", "needles"),
    [
        ("def f(:\n    pass\n", ("bad.py", "line 1", "SyntaxError")),
        ("x = 1\n", ("bad.py", "defines no law")),
        (
            "from railstop.control.law import control_law\n"
            "@control_law(name='ato')\ndef f(meas, state, params):\n    return 0.0\n",
            ("bad.py", "built-in controller", "'ato'"),
        ),
        (
            "from railstop.control.law import control_law\n"
            "@control_law(name='Bad Name')\ndef f(meas, state, params):\n    return 0.0\n",
            ("bad.py", "name", "'Bad Name'"),
        ),
        (
            "from railstop.control.law import control_law\n"
            "@control_law(name='strings')\ndef f(meas, state, params):\n    return meas[0].nothing\n",
            ("bad.py", "strings", "does not compile"),
        ),
        ("import no_such_module_here\n", ("bad.py", "line 1", "ModuleNotFoundError")),
    ],
)
def test_a_bad_law_file_is_refused_with_one_line(tmp_path: Path, text: str, needles: tuple[str, ...]) -> None:
    bad = tmp_path / "bad.py"
    bad.write_text(text)
    with pytest.raises(ConfigError) as err:
        load_law_file(bad)
    message = str(err.value)
    assert "\n" not in message
    for needle in needles:
        assert needle in message, (needle, message)


def test_the_cli_refuses_a_missing_law_file_and_an_unknown_law(tmp_path: Path) -> None:
    p = run("stop", "--law", "nowhere.py", "--controller", "x", "--no-db", cwd=tmp_path)
    _one_line_error(p, "--law", "nowhere.py", "no such law file")
    p = run("stop", "--controller", "constant-decel", "--no-db", cwd=tmp_path)
    _one_line_error(p, "--controller", "constant-decel", "--law")
    law = _write(tmp_path / "mylaw.py", CONSTANT_DECEL)
    p = run("compare", "--law", str(law), "--controllers", "tasc-pwm,nope", cwd=tmp_path)
    _one_line_error(p, "--controllers", "'nope'")


def test_the_line_stops_its_trains_by_a_law_of_the_users_own(tmp_path: Path) -> None:
    """``railstop line run --law``: the operation file names the law; every station stop of the
    line runs it (the same stop model as the campaign)."""
    law = _write(tmp_path / "mylaw.py", CONSTANT_DECEL)
    default_op = (
        Path(__file__).resolve().parents[2] / "src" / "railstop" / "data" / "operation" / "default.toml"
    )
    op = tmp_path / "op.toml"
    op.write_text(default_op.read_text().replace('controller = "tasc-pwm"', 'controller = "constant-decel"'))
    args = ("line", "run", "--operation", str(op), "--trains", "2", "--duration-s", "700", "--json")
    p = run(*args, cwd=tmp_path)
    _one_line_error(p, "op.toml", "controller", "constant-decel")
    p = run(*args, "--law", str(law), cwd=tmp_path)
    assert p.returncode == 0, p.stderr
    summary = json.loads(p.stdout)
    assert summary["stops"] >= 4, summary
    # The law's stops, not tasc-pwm's: it stops about half a metre short (docs/control-law.md),
    # where tasc-pwm's nominal stops are within a few centimetres.
    assert summary["stop_error_max_m"] > 0.3 and summary["stops_within_tolerance"] < summary["stops"]


def test_a_line_campaign_runs_a_law_in_its_worker_processes_and_resumes_only_with_its_text(
    tmp_path: Path,
) -> None:
    """``railstop line campaign --law``: the law's text travels with the campaign to its worker
    processes; the campaign records the file's hash and ``--resume`` with another text is refused."""
    law = _write(tmp_path / "mylaw.py", CONSTANT_DECEL)
    default_op = (
        Path(__file__).resolve().parents[2] / "src" / "railstop" / "data" / "operation" / "default.toml"
    )
    op = tmp_path / "op.toml"
    op.write_text(default_op.read_text().replace('controller = "tasc-pwm"', 'controller = "constant-decel"'))
    out = tmp_path / "lc"
    args = ("line", "campaign", "--operation", str(op), "--trains", "2", "--duration-s", "700")
    p = run(
        *args, "--runs", "2", "--workers", "2", "--out", str(out), "--law", str(law), "--json", cwd=tmp_path
    )
    assert p.returncode == 0, p.stderr
    summary = json.loads(p.stdout)
    assert summary["runs"] == 2
    manifest = json.loads((out / "campaign.json").read_text())
    assert manifest["law"]["sha256"] == hashlib.sha256(law.read_bytes()).hexdigest()
    stops = [s for line in (out / "runs.jsonl").read_text().splitlines() for s in json.loads(line)["stops"]]
    assert len(stops) >= 8
    # The law's stops (about half a metre short, docs/control-law.md), not tasc-pwm's.
    assert max(abs(s["error_m"]) for s in stops) > 0.3
    law.write_text(CONSTANT_DECEL + "\n# changed\n")
    p = run(*args, "--runs", "3", "--out", str(out), "--resume", "--law", str(law), cwd=tmp_path)
    _one_line_error(p, str(out), "--resume")
