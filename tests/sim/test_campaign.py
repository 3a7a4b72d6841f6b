"""Monte Carlo campaigns end to end: determinism, replay, interrupt/resume, the CLI, the database.

Everything runs for real: campaigns into ``tmp_path``, the ``railstop`` command
as a process of its own (like ``tests/cli/test_cli.py``; forked from a warm zygote,
``tests/zygote.py``, except where a signal is sent to it). Run counts are small; a campaign
that several assertions need is computed once per test (or cached per module).
"""

from __future__ import annotations

import base64
import json
import os
import re
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Mapping
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

import railstop.sim.campaign as campaign_module
from railstop.config import load_line, load_vehicle
from railstop.config.disturbances import (
    LOW_ADHESION,
    LOW_ADHESION_START,
    PARAMETERS,
    DisturbanceSet,
    load_disturbances,
    nominal_values,
)
from railstop.config.schema import Line, Station, Vehicle
from railstop.errors import RailstopError, SimulationError
from railstop.sim.campaign import (
    CHUNK_DIR,
    RESULT_COLUMNS,
    RUNS_FILE,
    SUMMARY_FILE,
    CampaignOutcome,
    CampaignSpec,
    campaign_lock,
    run_campaign,
)
from railstop.sim.engine import CONTROLLERS
from railstop.sim.single import run_stop
from railstop.store import open_store
from zygote import run_cli

EXE = [sys.executable, "-m", "railstop.cli"]
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
DRAWN_COLUMNS = (*PARAMETERS, LOW_ADHESION, LOW_ADHESION_START)
# What `railstop campaign --json` must print (beyond the station, controller, ... of the run).
SUMMARY_KEYS = (
    "runs",
    "within_0_30",
    "within_0_35",
    "within_0_50",
    "mean_m",
    "std_m",
    "p99_abs_m",
    "max_abs_m",
    "overrun_ci95_upper",
    "p99_max_jerk_mps3",
    "mean_stop_time_s",
    "runs_per_s",
)
BANDS = {"within_0_30": 0.30, "within_0_35": 0.35, "within_0_50": 0.50}

REPLAY_SEED = 5
REPLAY_RUNS = 6
CLI_REPLAY_RUN = 3
# The interrupted campaign: enough chunks to kill it half way, few runs to stay fast.
KILL_RUNS = 120
KILL_CHUNK = 20
KILL_CHUNKS = KILL_RUNS // KILL_CHUNK


def run(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    """``railstop ARGS`` in ``cwd``: a process of its own, forked from a warm zygote (tests/zygote.py)."""
    return run_cli(*args, cwd=cwd)


def error_lines(p: subprocess.CompletedProcess[str]) -> list[str]:
    return [ln for ln in p.stderr.splitlines() if ln.strip()]


def json_object(p: subprocess.CompletedProcess[str]) -> dict[str, Any]:
    """The one JSON object a ``--json`` command prints (and nothing else on stdout)."""
    assert p.returncode == 0, p.stderr
    lines = [ln for ln in p.stdout.splitlines() if ln.strip()]
    assert len(lines) == 1, p.stdout
    data = json.loads(lines[0])
    assert isinstance(data, dict)
    return data


def without(summary: Mapping[str, Any], *keys: str) -> dict[str, Any]:
    return {k: v for k, v in summary.items() if k not in keys}


def chunk_files(out: Path) -> list[Path]:
    return sorted((out / CHUNK_DIR).glob("chunk-*.parquet"))


def read_runs(out: Path) -> pa.Table:
    return pq.read_table(out / RUNS_FILE)


# --------------------------------------------------------------------------
# Shared data


@pytest.fixture(scope="module")
def line() -> Line:
    return load_line(None)


@pytest.fixture(scope="module")
def vehicle() -> Vehicle:
    return load_vehicle(None)


@pytest.fixture(scope="module")
def station(line: Line) -> Station:
    return line.station(None)


@pytest.fixture(scope="module")
def standard() -> DisturbanceSet:
    return load_disturbances("standard")


def campaign(
    line: Line,
    vehicle: Vehicle,
    out: Path,
    *,
    controller: str,
    runs: int,
    seed: int,
    disturbances: DisturbanceSet,
    chunk_size: int,
    workers: int = 1,
) -> CampaignOutcome:
    spec = CampaignSpec(
        line=line,
        vehicle=vehicle,
        station=line.station(None).name,
        controller=controller,
        runs=runs,
        seed=seed,
        disturbances=disturbances,
        chunk_size=chunk_size,
    )
    return run_campaign(spec, out, workers=workers)


@pytest.fixture(scope="module")
def replay_campaign(
    tmp_path_factory: pytest.TempPathFactory, line: Line, vehicle: Vehicle, standard: DisturbanceSet
) -> Callable[[str], pa.Table]:
    """``get(controller)``: the runs table of the standard campaign of REPLAY_RUNS runs (cached)."""
    cache: dict[str, pa.Table] = {}

    def get(controller: str) -> pa.Table:
        if controller not in cache:
            out = tmp_path_factory.mktemp(f"replay-{controller}")
            campaign(
                line,
                vehicle,
                out,
                controller=controller,
                runs=REPLAY_RUNS,
                seed=REPLAY_SEED,
                disturbances=standard,
                chunk_size=REPLAY_RUNS,
            )
            cache[controller] = read_runs(out)
        return cache[controller]

    return get


# --------------------------------------------------------------------------
# 1. Results do not depend on the chunk size or the number of workers


@pytest.mark.parametrize("controller", ["tasc-pwm", "ato"])
def test_same_seed_same_runs_whatever_chunks_and_workers(
    tmp_path: Path, line: Line, vehicle: Vehicle, standard: DisturbanceSet, controller: str
) -> None:
    common: dict[str, Any] = {"controller": controller, "runs": 60, "seed": 11, "disturbances": standard}
    one = campaign(line, vehicle, tmp_path / "one", chunk_size=60, workers=1, **common)
    two = campaign(line, vehicle, tmp_path / "two", chunk_size=17, workers=2, **common)

    assert len(chunk_files(tmp_path / "one")) == 1
    assert len(chunk_files(tmp_path / "two")) == 4  # 17 + 17 + 17 + 9
    assert one.runs_simulated == two.runs_simulated == 60
    a, b = read_runs(tmp_path / "one"), read_runs(tmp_path / "two")
    assert a.num_rows == b.num_rows == 60
    assert a.column("run").to_pylist() == list(range(60))
    assert set(RESULT_COLUMNS) | set(DRAWN_COLUMNS) <= set(a.column_names)
    assert a.equals(b)
    # The draws really vary, so equal tables are not equal by accident of constant columns.
    assert np.unique(a.column("stop_error_m").to_numpy()).size == 60
    assert np.unique(a.column("brake_gain").to_numpy()).size > 50

    # The same numbers; the provenance names each campaign (the chunk size is in its manifest).
    assert without(one.summary, "runs_per_s", "provenance") == without(
        two.summary, "runs_per_s", "provenance"
    )
    assert one.summary["provenance"]["inputs_sha256"] != two.summary["provenance"]["inputs_sha256"]
    assert one.summary["runs"] == 60
    for out, outcome in ((tmp_path / "one", one), (tmp_path / "two", two)):
        assert json.loads((out / SUMMARY_FILE).read_text(encoding="utf-8")) == outcome.summary


def test_one_chunk_is_shared_by_the_threads_and_written_whole(
    tmp_path: Path, line: Line, vehicle: Vehicle, standard: DisturbanceSet
) -> None:
    """Fewer chunks than workers: each chunk is cut into blocks for the threads, then written as
    one file, equal to the chunk one thread computes."""
    common: dict[str, Any] = {"controller": "tasc-step", "runs": 45, "seed": 4, "disturbances": standard}
    one = campaign(line, vehicle, tmp_path / "one", chunk_size=45, workers=1, **common)
    three = campaign(line, vehicle, tmp_path / "three", chunk_size=45, workers=3, **common)
    assert one.runs_simulated == three.runs_simulated == 45
    assert len(chunk_files(tmp_path / "three")) == 1
    assert pq.read_table(chunk_files(tmp_path / "one")[0]).equals(
        pq.read_table(chunk_files(tmp_path / "three")[0])
    )
    assert read_runs(tmp_path / "three").column("run").to_pylist() == list(range(45))


# --------------------------------------------------------------------------
# 2. A single stop replays any run of a campaign


@pytest.mark.parametrize("controller", CONTROLLERS)
def test_replay_equals_campaign_run(
    replay_campaign: Callable[[str], pa.Table],
    line: Line,
    station: Station,
    vehicle: Vehicle,
    standard: DisturbanceSet,
    controller: str,
) -> None:
    table = replay_campaign(controller)
    errors = table.column("stop_error_m").to_numpy()
    loads = table.column("load_factor").to_numpy()
    gains = table.column("brake_gain").to_numpy()
    notches = table.column("notch_changes").to_numpy()
    stopped = table.column("stopped").to_numpy()
    assert table.num_rows == REPLAY_RUNS
    assert np.unique(errors).size == REPLAY_RUNS  # every run is a different stop
    for i in range(REPLAY_RUNS):
        result, batch = run_stop(
            line=line,
            station=station,
            vehicle=vehicle,
            controller=controller,
            seed=REPLAY_SEED,
            disturbances=standard,
            run=i,
        )
        assert float(batch.stop_error_m[0]) == pytest.approx(errors[i], abs=1e-9), f"run {i}"
        assert abs(result.stop_error_m - errors[i]) <= 1e-6, f"run {i}"
        assert abs(result.load_factor - loads[i]) <= 1e-6, f"run {i}"
        assert abs(result.brake_gain - gains[i]) <= 1e-6, f"run {i}"
        assert result.notch_changes == notches[i], f"run {i}"
        assert result.stopped == bool(stopped[i]), f"run {i}"
        assert result.run == i and result.disturbances == "standard"


def test_cli_stop_replays_campaign_run(tmp_path: Path, replay_campaign: Callable[[str], pa.Table]) -> None:
    controller = "tasc-pwm"
    table = replay_campaign(controller)
    p = run(
        "stop",
        "--disturbances",
        "standard",
        "--seed",
        str(REPLAY_SEED),
        "--run",
        str(CLI_REPLAY_RUN),
        "--controller",
        controller,
        "--json",
        "--db",
        str(tmp_path / "stop.db"),
        cwd=tmp_path,
    )
    data = json_object(p)
    row = table.slice(CLI_REPLAY_RUN, 1).to_pylist()[0]
    assert row["run"] == CLI_REPLAY_RUN
    assert data["run"] == CLI_REPLAY_RUN and data["disturbances"] == "standard"
    assert data["controller"] == controller and data["seed"] == REPLAY_SEED
    assert abs(data["stop_error_m"] - row["stop_error_m"]) <= 1e-6
    assert abs(data["load_factor"] - row["load_factor"]) <= 1e-6
    assert abs(data["brake_gain"] - row["brake_gain"]) <= 1e-6
    # Another run is another stop: the replay does not just echo run 0.
    other = table.column("stop_error_m").to_numpy()[0]
    assert abs(data["stop_error_m"] - other) > 1e-6


# --------------------------------------------------------------------------
# 3. Interrupt (SIGKILL) and resume


def test_killed_campaign_resumes_to_the_uninterrupted_result(
    tmp_path: Path, line: Line, vehicle: Vehicle, standard: DisturbanceSet
) -> None:
    out = tmp_path / "camp"
    db = tmp_path / "camp.db"
    args = (
        "campaign",
        "--runs",
        str(KILL_RUNS),
        "--chunk-size",
        str(KILL_CHUNK),
        "--workers",
        "1",
        "--out",
        str(out),
        "--db",
        str(db),
        "--json",
    )
    log = tmp_path / "killed.stderr"
    with log.open("w") as stderr:
        proc = subprocess.Popen([*EXE, *args], cwd=tmp_path, stdout=subprocess.DEVNULL, stderr=stderr)
        try:
            deadline = time.monotonic() + 120.0
            while len(chunk_files(out)) < 2:
                if proc.poll() is not None:
                    pytest.fail(f"the campaign ended (exit {proc.returncode}) before it could be killed")
                if time.monotonic() > deadline:
                    pytest.fail("no 2 chunk files within 120 s")
                time.sleep(0.02)
            assert proc.poll() is None, "finished before the kill"
            proc.send_signal(signal.SIGKILL)
            assert proc.wait(timeout=60) == -signal.SIGKILL
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait(timeout=60)

    assert not (out / RUNS_FILE).exists()
    assert not (out / SUMMARY_FILE).exists()
    done = chunk_files(out)
    k = len(done)
    assert 2 <= k < KILL_CHUNKS
    # One worker runs the chunks in order: the finished ones are 0 .. k-1, each complete.
    assert [p.name for p in done] == [f"chunk-{j:06d}.parquet" for j in range(k)]
    for j, path in enumerate(done):
        chunk = pq.read_table(path)
        assert chunk.num_rows == KILL_CHUNK
        assert chunk.column("run").to_pylist() == list(range(KILL_CHUNK * j, KILL_CHUNK * (j + 1)))

    resumed = json_object(run(*args, "--resume", cwd=tmp_path))
    assert resumed["runs"] == KILL_RUNS
    assert resumed["runs_simulated"] == KILL_RUNS - KILL_CHUNK * k
    assert resumed["runs_simulated"] < KILL_RUNS
    assert len(chunk_files(out)) == KILL_CHUNKS
    assert not list((out / CHUNK_DIR).glob(".*.tmp"))  # a chunk killed while being written is gone

    ref = campaign(
        line,
        vehicle,
        tmp_path / "ref",
        controller="tasc-pwm",
        runs=KILL_RUNS,
        seed=1,
        disturbances=standard,
        chunk_size=KILL_RUNS,
    )
    assert read_runs(out).equals(read_runs(tmp_path / "ref"))
    expected = without(ref.summary, "runs_per_s", "provenance")
    assert {k: resumed[k] for k in expected} == expected
    with open_store(db) as store:
        rows = store.campaigns()
    assert len(rows) == 1
    assert rows[0]["runs"] == KILL_RUNS and rows[0]["summary"]["runs"] == KILL_RUNS


@pytest.mark.parametrize(
    ("sig", "code", "cause"),
    [(signal.SIGTERM, 143, "terminated (SIGTERM)"), (signal.SIGINT, 130, "interrupted")],
)
def test_sigterm_or_ctrl_c_stops_cleanly_says_what_it_kept_and_resumes(
    tmp_path: Path, sig: signal.Signals, code: int, cause: str
) -> None:
    """A signal mid-campaign (2 threads): exit 128 + signal soon, one line naming the chunks kept
    and how to finish, no traceback; a non-terminal stderr got periodic status lines; --resume
    finishes with exactly the missing runs."""
    out = tmp_path / "camp"
    runs, chunk = 24_000, 500
    args = ("campaign", "--runs", str(runs), "--chunk-size", str(chunk), "--workers", "2")
    args += ("--out", str(out), "--db", str(tmp_path / "c.db"), "--json")
    log = tmp_path / "stderr.txt"
    env = {**os.environ, "RAILSTOP_STATUS_S": "0.2"}
    with log.open("w") as stderr:
        proc = subprocess.Popen(
            [*EXE, *args], cwd=tmp_path, stdout=subprocess.DEVNULL, stderr=stderr, env=env
        )
        try:
            deadline = time.monotonic() + 120.0
            while len(chunk_files(out)) < 3:
                assert proc.poll() is None, f"ended (exit {proc.returncode}) before the signal"
                assert time.monotonic() < deadline, "no 3 chunks within 120 s"
                time.sleep(0.02)
            proc.send_signal(sig)
            t_signal = time.monotonic()
            assert proc.wait(timeout=60) == code
            stop_s = time.monotonic() - t_signal
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait(timeout=60)
    text = log.read_text()
    assert "Traceback" not in text, text
    assert stop_s < 15.0  # a running 500-run block finishes, the rest never starts
    kept = len(chunk_files(out))
    assert 3 <= kept < runs // chunk
    last = [ln for ln in text.splitlines() if ln.strip()][-1]
    assert last.startswith(f"{cause}: tasc-pwm at "), text
    assert f": {kept} of {runs // chunk} chunks ({kept * chunk:,} of {runs:,} runs) kept in {out}" in last
    assert "--resume" in last
    status = [
        ln for ln in text.splitlines() if re.match(r"railstop: tasc-pwm at \S+: [\d,]+/24,000 runs", ln)
    ]
    assert status, text
    assert not (out / RUNS_FILE).exists()

    resumed = json_object(run(*args, "--resume", cwd=tmp_path))
    assert resumed["runs_simulated"] == runs - kept * chunk
    rows = read_runs(out).column("run").to_pylist()
    assert rows == list(range(runs))


def test_campaign_summary_uses_the_station_tolerance_or_the_option(
    tmp_path: Path, line: Line, vehicle: Vehicle, standard: DisturbanceSet
) -> None:
    """The overrun count and bound are against the PSD tolerance of the station (or --tolerance-m):
    counted by hand from runs.parquet for 0.35 m (the embedded station's) and 0.10 m."""
    base = campaign(
        line,
        vehicle,
        tmp_path / "a",
        controller="ato",
        runs=300,
        seed=3,
        disturbances=standard,
        chunk_size=300,
    )
    error = read_runs(tmp_path / "a").column("stop_error_m").to_numpy()
    assert base.summary["tolerance_m"] == 0.35
    assert base.summary["overruns"] == int(np.count_nonzero(error > 0.35))
    spec = CampaignSpec(
        line=line,
        vehicle=vehicle,
        station=line.station(None).name,
        controller="ato",
        runs=300,
        seed=3,
        disturbances=standard,
        chunk_size=300,
        tolerance_m=0.10,
    )
    tight = run_campaign(spec, tmp_path / "b").summary
    assert tight["tolerance_m"] == 0.10
    assert tight["overruns"] == int(np.count_nonzero(error > 0.10)) > base.summary["overruns"]
    assert tight["within_tolerance"] == pytest.approx(float(np.mean(np.abs(error) <= 0.10)))
    assert tight["overrun_ci95_upper"] > base.summary["overrun_ci95_upper"]


def test_existing_campaign_dir_needs_matching_resume(
    tmp_path: Path, line: Line, vehicle: Vehicle, standard: DisturbanceSet
) -> None:
    out = tmp_path / "camp"
    # The campaign `railstop campaign --runs 2 --chunk-size 2 --seed 1` (defaults otherwise) asks for.
    campaign(line, vehicle, out, controller="tasc-pwm", runs=2, seed=1, disturbances=standard, chunk_size=2)
    before = read_runs(out)
    base = ("campaign", "--runs", "2", "--chunk-size", "2", "--out", str(out), "--db", str(tmp_path / "c.db"))

    p = run(*base, "--seed", "1", "--json", cwd=tmp_path)
    assert p.returncode == 2, p.stderr
    assert len(error_lines(p)) == 1, p.stderr
    assert "--resume" in p.stderr and "Traceback" not in p.stderr

    p = run(*base, "--seed", "2", "--resume", "--json", cwd=tmp_path)
    assert p.returncode == 2, p.stderr
    assert len(error_lines(p)) == 1, p.stderr
    assert re.search(r"\bseed\b", p.stderr) and "Traceback" not in p.stderr
    assert read_runs(out).equals(before)  # nothing was overwritten

    # The same campaign resumes fine (so the refusals above are about the mismatch).
    ok = json_object(run(*base, "--seed", "1", "--resume", "--json", cwd=tmp_path))
    assert ok["runs"] == 2 and ok["runs_simulated"] == 0


def test_resume_refuses_a_chunk_of_another_campaign_or_range(
    tmp_path: Path, line: Line, vehicle: Vehicle, standard: DisturbanceSet
) -> None:
    """A chunk copied in from another seed, or renamed to another slot, is refused on --resume."""
    base = ("campaign", "--runs", "6", "--chunk-size", "2", "--workers", "1", "--db", str(tmp_path / "c.db"))
    mine, other = tmp_path / "mine", tmp_path / "other"
    campaign(line, vehicle, mine, controller="tasc-pwm", runs=6, seed=1, disturbances=standard, chunk_size=2)
    campaign(line, vehicle, other, controller="tasc-pwm", runs=6, seed=2, disturbances=standard, chunk_size=2)
    before = read_runs(mine)
    name = "chunk-000001.parquet"

    # Another seed's chunk 1 in place of ours (the gap a kill left, filled by hand).
    (mine / CHUNK_DIR / name).unlink()
    (mine / CHUNK_DIR / name).write_bytes((other / CHUNK_DIR / name).read_bytes())
    p = run(*base, "--seed", "1", "--out", str(mine), "--resume", "--json", cwd=tmp_path)
    assert p.returncode == 2, p.stderr
    assert len(error_lines(p)) == 1, p.stderr
    assert name in p.stderr and "belongs to campaign" in p.stderr and "Traceback" not in p.stderr

    # Our own chunk 0 copied to slot 1: the right campaign, the wrong runs.
    (mine / CHUNK_DIR / name).write_bytes((mine / CHUNK_DIR / "chunk-000000.parquet").read_bytes())
    p = run(*base, "--seed", "1", "--out", str(mine), "--resume", "--json", cwd=tmp_path)
    assert p.returncode == 2, p.stderr
    assert len(error_lines(p)) == 1, p.stderr
    assert "holds runs 0-2" in p.stderr and "chunk 1 holds runs 2-4" in p.stderr

    # Put back what the campaign wrote: it resumes to the same rows, nothing simulated.
    (mine / CHUNK_DIR / name).unlink()
    ok = json_object(run(*base, "--seed", "1", "--out", str(mine), "--resume", "--json", cwd=tmp_path))
    assert ok["runs_simulated"] == 2
    assert read_runs(mine).equals(before)


def test_second_process_on_the_same_campaign_is_refused(tmp_path: Path) -> None:
    out = tmp_path / "camp"
    with campaign_lock(out):
        p = run("campaign", "--runs", "2", "--out", str(out), "--db", str(tmp_path / "c.db"), cwd=tmp_path)
    assert p.returncode == 2, p.stderr
    assert len(error_lines(p)) == 1, p.stderr
    assert f"another railstop process {os.getpid()} is running this campaign" in p.stderr
    assert not (out / "campaign.json").exists()  # the refused process wrote nothing
    # The lock dies with its holder: the same command now runs.
    p = run("campaign", "--runs", "2", "--out", str(out), "--db", str(tmp_path / "c.db"), cwd=tmp_path)
    assert p.returncode == 0, p.stderr


@pytest.mark.parametrize(("runs", "says"), [(10**12, "on disk"), (2**63, "64-bit run numbers")])
def test_campaign_beyond_disk_memory_or_run_numbers_is_refused_at_once(
    tmp_path: Path, runs: int, says: str
) -> None:
    """Nothing is built per chunk up front: the refusal comes before any work or memory growth."""
    out = tmp_path / "big"
    t0 = time.monotonic()
    p = run("campaign", "--runs", str(runs), "--out", str(out), "--db", str(tmp_path / "c.db"), cwd=tmp_path)
    assert p.returncode == 2, p.stderr
    assert len(error_lines(p)) == 1, p.stderr
    assert says in p.stderr and "Traceback" not in p.stderr
    assert time.monotonic() - t0 < 60.0
    assert not out.exists()


def test_campaign_whose_summary_exceeds_memory_is_refused(
    tmp_path: Path, line: Line, vehicle: Vehicle, standard: DisturbanceSet, monkeypatch: pytest.MonkeyPatch
) -> None:
    """On a machine of 1 GB, 10 million runs (1.5 GB of summary working set) are refused."""
    monkeypatch.setattr(campaign_module, "_physical_memory", lambda: 10**9)
    spec = CampaignSpec(
        line=line,
        vehicle=vehicle,
        station=line.station(None).name,
        controller="tasc-pwm",
        runs=10**7,
        seed=1,
        disturbances=standard,
    )
    with pytest.raises(RailstopError, match=r"10,000,000 runs need about 1\.5 GB of memory.*has 1\.0 GB"):
        run_campaign(spec, tmp_path / "big")
    assert not (tmp_path / "big").exists()
    campaign_module.check_capacity(replace(spec, runs=10**6), tmp_path / "big")  # 120 MB: fine


# --------------------------------------------------------------------------
# 4. `railstop campaign --json`, the statistics and the database


def test_campaign_json_statistics_and_database(tmp_path: Path) -> None:
    db = tmp_path / "campaigns.db"

    def cli_campaign(out: str, seed: int, runs: int, *extra: str) -> dict[str, Any]:
        return json_object(
            run(
                "campaign",
                "--controller",
                "ato",
                "--runs",
                str(runs),
                "--seed",
                str(seed),
                "--chunk-size",
                "6",
                "--workers",
                "1",
                "--out",
                str(tmp_path / out),
                "--db",
                str(db),
                "--json",
                *extra,
                cwd=tmp_path,
            )
        )

    data = cli_campaign("a", 3, 12)
    for key in SUMMARY_KEYS:
        assert key in data, key
    assert data["runs"] == 12 and data["runs_simulated"] == 12 and data["controller"] == "ato"
    for key in (*BANDS, "overrun_ci95_upper"):
        assert 0.0 <= data[key] <= 1.0, key
    assert data["runs_per_s"] > 0

    table = read_runs(tmp_path / "a")
    error = table.column("stop_error_m").to_numpy()
    ok = table.column("stopped").to_numpy() & np.isfinite(error)
    assert error.size == 12
    for key, band in BANDS.items():
        assert data[key] == pytest.approx(np.count_nonzero(ok & (np.abs(error) <= band)) / 12, abs=1e-12)
    assert data["mean_m"] == pytest.approx(float(np.mean(error)), abs=1e-12)
    assert data["std_m"] == pytest.approx(float(np.std(error, ddof=1)), abs=1e-12)
    assert data["max_abs_m"] == pytest.approx(float(np.max(np.abs(error))), abs=1e-12)
    assert data["p99_abs_m"] <= data["max_abs_m"]
    assert data["within_0_30"] <= data["within_0_35"] <= data["within_0_50"]

    with open_store(db) as store:
        rows = store.campaigns()
    assert len(rows) == 1
    summary = rows[0]["summary"]
    assert set(SUMMARY_KEYS) <= set(summary)
    assert summary == {k: data[k] for k in summary}
    assert rows[0]["controller"] == "ato" and rows[0]["seed"] == 3 and rows[0]["runs"] == 12
    assert Path(rows[0]["runs_file"]) == (tmp_path / "a" / RUNS_FILE).resolve()

    cli_campaign("b", 4, 3)
    with open_store(db) as store:
        assert len(store.campaigns()) == 2

    again = cli_campaign("a", 3, 12, "--resume")
    assert again["runs_simulated"] == 0
    assert without(again, "runs_per_s", "elapsed_s", "runs_simulated", "provenance") == without(
        data, "runs_per_s", "elapsed_s", "runs_simulated", "provenance"
    )
    with open_store(db) as store:
        rows = store.campaigns()
    assert len(rows) == 2
    assert sorted(r["seed"] for r in rows) == [3, 4]


# --------------------------------------------------------------------------
# 5. Bad input: one line, exit 2


def test_bad_disturbance_file_one_line_exit_2(tmp_path: Path) -> None:
    bad = tmp_path / "bad-set.toml"
    bad.write_text("brake_gain = {uniform = [1.2, 0.8]}\n", encoding="utf-8")
    out = tmp_path / "out"
    p = run(
        "campaign", "--disturbances", str(bad), "--runs", "2", "--out", str(out), "--db", "x.db", cwd=tmp_path
    )
    assert p.returncode == 2
    assert len(error_lines(p)) == 1, p.stderr
    assert str(bad) in p.stderr
    assert "brake_gain.uniform" in p.stderr
    assert "[1.2, 0.8]" in p.stderr
    assert "Traceback" not in p.stderr
    assert not out.exists()


def test_error_message_keeps_bracketed_text(tmp_path: Path) -> None:
    bad = tmp_path / "bad-set.toml"
    bad.write_text("brake_gain = {uniform = [1.2, 0.8]}\n", encoding="utf-8")
    p = run("campaign", "--disturbances", str(bad), "--runs", "2", "--out", "o", "--db", "x.db", cwd=tmp_path)
    assert p.returncode == 2
    # The ConfigError text is "...: lo must not be greater than hi in [lo, hi] (got [1.2, 0.8])".
    assert "lo must not be greater than hi in [lo, hi]" in p.stderr


def test_error_message_with_closing_tag_is_one_line_exit_2(tmp_path: Path) -> None:
    p = run("campaign", "--station", "[/b]", "--runs", "2", "--out", "o", "--db", "x.db", cwd=tmp_path)
    assert p.returncode == 2, p.stderr[-300:]
    assert len(error_lines(p)) == 1, p.stderr[-300:]
    assert "unknown station '[/b]'" in p.stderr


def test_unknown_controller_exit_2(tmp_path: Path) -> None:
    out = tmp_path / "out"
    p = run(
        "campaign", "--controller", "nope", "--runs", "2", "--out", str(out), "--db", "x.db", cwd=tmp_path
    )
    assert p.returncode == 2
    assert len(error_lines(p)) == 1, p.stderr
    assert "unknown controller 'nope'" in p.stderr
    assert "Traceback" not in p.stderr
    assert not out.exists()


# --------------------------------------------------------------------------
# 6. `railstop compare` on identical draws, then `railstop report`


def test_compare_identical_draws_and_report(tmp_path: Path) -> None:
    out = tmp_path / "cmp"
    db = tmp_path / "cmp.db"
    args = ("compare", "--runs", "6", "--chunk-size", "6", "--out", str(out), "--json", "--db", str(db))
    data = json_object(run(*args, cwd=tmp_path))
    entries = data["controllers"]
    assert [e["controller"] for e in entries] == list(CONTROLLERS)
    assert all(e["runs"] == 6 and e["seed"] == 1 and e["disturbances"] == "standard" for e in entries)

    tables = [read_runs(out / ctrl) for ctrl in CONTROLLERS]
    draws = [t.select(["run", *DRAWN_COLUMNS]) for t in tables]
    assert np.unique(draws[0].column("entry_speed_kmh").to_numpy()).size == 6
    for ctrl, d in zip(CONTROLLERS[1:], draws[1:], strict=True):
        assert d.equals(draws[0]), ctrl
    # ... but the controllers stop differently on them.
    errors = [t.column("stop_error_m").to_numpy() for t in tables]
    assert any(not np.array_equal(errors[0], e) for e in errors[1:])
    with open_store(db) as store:
        assert sorted(r["controller"] for r in store.campaigns()) == sorted(CONTROLLERS)

    p = run("report", str(out), "--worst", "1", cwd=tmp_path)
    assert p.returncode == 0, p.stderr
    html = (out / "report.html").read_text(encoding="utf-8")
    for ctrl in CONTROLLERS:
        assert ctrl in html, ctrl
    # One self-contained page: every figure is embedded; the worst-run plots name the commands
    # each run received, and the page says which railstop wrote it from which campaigns.
    sources = re.findall(r'<img[^>]*\bsrc="data:image/png;base64,([^"]+)"', html)
    assert len(sources) >= 2 + len(CONTROLLERS)
    for src in sources:
        assert base64.b64decode(src)[:8] == PNG_MAGIC
    assert "commands received / sent" in html
    assert "report written by</th><td>railstop " in html
    assert "PSD tolerance</th><td>±0.35 m" in html


# --------------------------------------------------------------------------
# 7. The nominal set draws the nominal stop


@pytest.mark.parametrize("controller", ["tasc-pwm", "ato"])
def test_nominal_set_is_the_nominal_stop(
    tmp_path: Path, line: Line, station: Station, vehicle: Vehicle, controller: str
) -> None:
    seed = 7
    outcome = campaign(
        line,
        vehicle,
        tmp_path,
        controller=controller,
        runs=3,
        seed=seed,
        disturbances=load_disturbances("nominal"),
        chunk_size=3,
    )
    assert outcome.summary["runs"] == 3
    table = read_runs(tmp_path)
    nominal = nominal_values(station, vehicle, 3)
    for name, values in nominal.items():
        np.testing.assert_array_equal(table.column(name).to_numpy(), values, err_msg=name)
    assert not table.column(LOW_ADHESION).to_numpy().any()

    result, batch = run_stop(line=line, station=station, vehicle=vehicle, controller=controller, seed=seed)
    expected = float(batch.stop_error_m[0])
    assert result.disturbances is None
    errors = table.column("stop_error_m").to_numpy()
    for i, e in enumerate(errors):
        assert e == pytest.approx(expected, abs=1e-9), f"run {i}"


def test_data_the_model_refuses_leaves_no_campaign_behind(tmp_path: Path) -> None:
    """A station the stop model cannot run (here a radar sampling at 20 ms, the model's step being
    10 ms, put in without the loader's checks) is refused by the campaign's first run before the
    campaign folder is written: the error names the station and the field, and the corrected
    command then runs into the same folder (before, the folder's manifest and lock were left and
    blocked it: "a campaign is already there", and --resume "differs in: data_sha256")."""
    line, vehicle = load_line(None), load_vehicle(None)
    st = line.stations[0]
    assert st.tasc.doppler is not None
    radar = st.tasc.doppler.model_copy(update={"sample_period_s": 0.02})
    bad_st = st.model_copy(update={"tasc": st.tasc.model_copy(update={"doppler": radar})})
    bad_line = line.model_copy(update={"stations": [bad_st, *line.stations[1:]]})
    out = tmp_path / "c"
    spec = CampaignSpec(
        line=bad_line, vehicle=vehicle, station=st.name, controller="tasc-pwm", runs=5, seed=1,
        disturbances=load_disturbances("standard"),
    )  # fmt: skip
    with pytest.raises(RailstopError, match=r"sample_period_s = 0.02 must equal the simulation step"):
        run_campaign(spec, out)
    assert not out.exists()
    done = run_campaign(replace(spec, line=line), out)
    assert done.runs_simulated == 5


def test_a_block_that_fails_is_named_by_its_runs_and_its_error(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A chunk whose runs fail after the first run (here a fault injected into the second chunk's
    block: the stop model refusing its data) ends the campaign with one message naming the runs and
    the error as its unit gave it, not the executor's internals ("block (1, 10, 20) failed:
    SimulationError: ..."); the first chunk is kept for --resume."""
    real = campaign_module.simulate_block

    def second_chunk_fails(spec: CampaignSpec, block: tuple[int, int, int]) -> pa.Table:
        if block[1] >= 10:
            raise SimulationError("station Riverside: the stop model refuses run 10")
        return real(spec, block)

    monkeypatch.setattr(campaign_module, "simulate_block", second_chunk_fails)
    line, vehicle = load_line(None), load_vehicle(None)
    spec = CampaignSpec(
        line=line, vehicle=vehicle, station=line.stations[0].name, controller="tasc-pwm", runs=20,
        seed=1, disturbances=load_disturbances("standard"), chunk_size=10,
    )  # fmt: skip
    out = tmp_path / "c"
    with pytest.raises(RailstopError) as info:
        run_campaign(spec, out, workers=1)
    text = str(info.value)
    assert text == (
        f"{out}: runs 10..19 failed: station Riverside: the stop model refuses run 10 "
        "(the chunks finished are kept for --resume)"
    ), text
    assert [p.name for p in chunk_files(out)] == ["chunk-000000.parquet"]
