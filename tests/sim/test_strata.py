"""Certification by strata (railstop.sim.strata): the patch's exact probability, one bound per stratum."""

from __future__ import annotations

import json
import math
import subprocess
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from railstop.config import load_line, load_vehicle
from railstop.config.disturbances import LOW_ADHESION, draw_scenario, load_disturbances
from railstop.sim.certify import CertifyError, CertifySpec
from railstop.sim.strata import PATCH_FIRST_RUN, allocation, stratified_certify
from railstop.stats.bounds import clopper_pearson_upper
from railstop.streams import RunStreams
from zygote import run_cli

LINE = load_line(None)
VEHICLE = load_vehicle(None)
STANDARD = load_disturbances("standard")


def _spec(threshold_m: float = 0.05, controller: str = "tasc-brake-controller") -> CertifySpec:
    return CertifySpec(
        line=LINE,
        vehicle=VEHICLE,
        station="Riverside",
        controller=controller,
        disturbances=STANDARD,
        threshold_m=threshold_m,
        seed=3,
    )


def test_allocation_is_proportional_to_the_root_of_the_weights() -> None:
    n0, n1 = allocation([0.95, 0.05], 1_000_000)
    assert n0 + n1 == 1_000_000
    assert abs(n1 / n0 - math.sqrt(0.05 / 0.95)) < 1e-5  # n_i proportional to the root of w_i
    # ... which minimises the zero-hit bound w0/n0 + w1/n1 among the splits of the runs.
    best = 0.95 / n0 + 0.05 / n1
    for other in (n1 - 1_000, n1 + 1_000, 500_000, 50_000):
        assert best < 0.95 / (1_000_000 - other) + 0.05 / other
    assert sum(allocation([0.95, 0.05], 7)) == 7
    assert allocation([1.0], 5) == [5]
    for runs in (2, 3, 10, 12_345):
        n = allocation([0.95, 0.05], runs)
        assert sum(n) == runs and min(n) >= 1


def test_a_stratum_forces_the_patch_and_keeps_every_other_draw() -> None:
    station = LINE.station("Riverside")
    streams = RunStreams.for_runs(5, 100, 400)
    _, a = draw_scenario(STANDARD, station, VEHICLE, streams)
    _, b = draw_scenario(STANDARD, station, VEHICLE, streams, patch=True)
    _, c = draw_scenario(STANDARD, station, VEHICLE, streams, patch=False)
    assert 0 < int(np.sum(a[LOW_ADHESION])) < 400  # the set's draw: some runs meet a patch
    assert bool(np.all(b[LOW_ADHESION])) and not bool(np.any(c[LOW_ADHESION]))
    for name, values in a.items():
        if name in (LOW_ADHESION, "low_adhesion_start_m"):
            continue
        assert np.array_equal(values, b[name]) and np.array_equal(values, c[name]), name
    # Where the set's own draw put a patch, the forced stratum has it at the same place.
    hit = a[LOW_ADHESION]
    assert np.array_equal(a["low_adhesion_start_m"][hit], b["low_adhesion_start_m"][hit])
    assert np.all(np.isinf(c["low_adhesion_start_m"]))


def test_the_bound_is_the_strata_bounds_weighted_by_their_exact_probabilities() -> None:
    """At a threshold that the patch's slides reach, the patch stratum has hits and the bound is
    the weighted sum of each stratum's Clopper–Pearson bound at 1 − δ/2."""
    r = stratified_certify(_spec(), runs=600, target=1e-3, workers=1)
    no, patch = r.strata
    assert (no.name, patch.name) == ("no patch", "low-adhesion patch")
    assert (no.weight, patch.weight) == (0.95, 0.05)
    assert (no.first_run, patch.first_run) == (0, PATCH_FIRST_RUN)
    assert (no.runs, patch.runs) == tuple(allocation([0.95, 0.05], 600))
    assert no.hits + patch.hits > 0
    for s in r.strata:
        assert s.upper == clopper_pearson_upper(s.hits, s.runs, 0.975)
    assert r.upper == pytest.approx(0.95 * no.upper + 0.05 * patch.upper, rel=1e-15)
    assert r.estimate == pytest.approx(0.95 * no.hits / no.runs + 0.05 * patch.hits / patch.runs, rel=1e-15)
    assert r.estimate <= r.upper and not r.certified


def test_the_same_whatever_the_workers() -> None:
    one = stratified_certify(_spec(), runs=300, target=1e-3, workers=1).to_dict()
    two = stratified_certify(_spec(), runs=300, target=1e-3, workers=2).to_dict()
    for row in (one, two):
        row.pop("elapsed_s")
        row.pop("runs_per_s")
    assert one == two


@pytest.mark.parametrize(
    ("setting", "kw"),
    [
        ("runs", {"runs": 1}),
        ("target", {"target": 1.5}),
        ("confidence", {"confidence": 1.0}),
        ("hazard", {"hazard": "derailment"}),
    ],
)
def test_bad_settings_are_named(setting: str, kw: dict[str, Any]) -> None:
    args: dict[str, Any] = {"runs": 10, "target": 1e-3, **kw}
    with pytest.raises(CertifyError) as err:
        stratified_certify(_spec(), **args)
    assert err.value.setting == setting


def _certify(args: list[str], cwd: Path) -> subprocess.CompletedProcess[str]:
    return run_cli("certify", *args, cwd=cwd)  # forked from a warm zygote (tests/zygote.py)


def test_command_platform_end(tmp_path: Path) -> None:
    p = _certify(["--method", "stratified", "--hazard", "platform-end", "--runs", "40", "--json"], tmp_path)
    assert p.returncode == 0, p.stderr
    row = json.loads(p.stdout)
    station = LINE.stations[0]
    assert row["hazard"] == "platform-end" and row["method"] == "stratified" and row["device"] == "cpu"
    assert row["threshold_m"] == station.platform_end - station.stop_point_m
    assert [s["stratum"] for s in row["strata"]] == ["no patch", "low-adhesion patch"]
    assert sum(s["runs"] for s in row["strata"]) == row["runs"] == 40
    assert math.isfinite(row["upper_bound"]) and row["estimate"] <= row["upper_bound"]


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["--hazard", "platform-end", "--threshold-m", "1"], "--threshold-m: the platform end sets"),
        (["--hazard", "overturn"], "--hazard: must be one of overrun, platform-end"),
        (["--method", "stratified", "--device", "tpu"], "--device: 'tpu' is not one of cpu, gpu"),
        (["--device", "gpu"], "--device: gpu runs --method stratified only"),
        (["--method", "magic"], "--method: must be is, mc or stratified"),
    ],
)
def test_command_errors_are_one_line(tmp_path: Path, args: list[str], needle: str) -> None:
    p = _certify(["--runs", "10", *args], tmp_path)
    assert p.returncode == 2, p.stderr
    lines = [ln for ln in p.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: ") and needle in lines[0], p.stderr
