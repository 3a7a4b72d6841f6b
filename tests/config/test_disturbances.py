"""Disturbance sets (config/disturbances.py): TOML distributions -> per-run Scenario.

Three contracts matter to a Monte Carlo campaign:

* the ``nominal`` set is exactly ``Scenario.nominal`` (no hidden disturbance);
* draws are a pure function of (seed, run index, parameter), so run i has the
  same disturbances whatever the chunk it is simulated in, and adding a
  parameter never changes the draws of the others (DESIGN rule 4);
* a bad file is rejected with one line naming the file, the field and the
  bad value (DESIGN rule 6).

Real files in tmp_path, no mocks.
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from railstop.config import default_line, default_vehicle
from railstop.config.disturbances import (
    COUNTER_BLOCKS,
    COUNTER_STRIDE,
    LOW_ADHESION,
    LOW_ADHESION_START,
    PARAMETERS,
    Distribution,
    DisturbanceSet,
    builtin_sets,
    counter_base,
    draw_scenario,
    load_disturbances,
    probability,
)
from railstop.config.gradient import GradientProfile
from railstop.config.scenario import Scenario, station_gradient
from railstop.config.schema import Station
from railstop.errors import ConfigError
from railstop.link.channel import media_preset
from railstop.quantities import MPS_PER_KMH
from railstop.streams import RunStreams

ROOT = Path(__file__).resolve().parents[2]  # the repository

FAST = settings(max_examples=40, deadline=None)
N_STAT = 20_000
SEED = 20240611

LINE = default_line()
VEHICLE = default_vehicle()
HILLCREST = LINE.station("Hillcrest")  # downhill approach: non-zero station gradients
TRAIN_M = VEHICLE.length_m

SCENARIO_ARRAYS = [f.name for f in dataclasses.fields(Scenario) if f.name != "gradient"]


def write(tmp_path: Path, text: str, name: str = "dist.toml") -> Path:
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


def positions(station: Station) -> np.ndarray:
    """Train-front chainages from well before the TASC zone to beyond the platform."""
    first = station.detector_positions_m()[0]
    return np.linspace(first - 500.0, station.platform_end + 200.0, 997)


def same_gradient(a: GradientProfile, b: GradientProfile, station: Station, n: int) -> None:
    x = np.tile(positions(station), (n, 1))
    np.testing.assert_array_equal(a.mean_gradient(x, TRAIN_M), b.mean_gradient(x, TRAIN_M))
    np.testing.assert_array_equal(a.elevation_m(x), b.elevation_m(x))


@pytest.fixture(scope="module")
def standard() -> DisturbanceSet:
    return load_disturbances("standard")


@pytest.fixture(scope="module")
def big_draw(standard: DisturbanceSet) -> tuple[Scenario, dict[str, np.ndarray]]:
    return draw_scenario(standard, HILLCREST, VEHICLE, RunStreams.for_runs(SEED, 0, N_STAT))


# --------------------------------------------------------------------------
# The embedded sets


def test_builtin_sets_load(standard: DisturbanceSet) -> None:
    assert builtin_sets() == ["control-law", "loss-95", "nominal", "outage-after-first", "standard", "wide"]
    assert standard.name == "standard"
    assert standard.source == "railstop/data/disturbances/standard.toml"
    assert standard.description
    # The standard set names every supported parameter.
    assert set(standard.params) == set(PARAMETERS)
    nominal = load_disturbances("nominal")
    assert nominal.name == "nominal"
    assert nominal.source == "railstop/data/disturbances/nominal.toml"
    assert nominal.params == {}
    assert nominal.to_dict() == {"description": nominal.description}
    # The control law alone: the standard set without odometer error and low adhesion.
    law = load_disturbances("control-law")
    differ = {k for k in PARAMETERS if law.params.get(k) != standard.params.get(k)}
    assert differ == {"odometer_diameter_error_pct", "low_adhesion_probability"}


def test_standard_matches_the_issue_table(standard: DisturbanceSet) -> None:
    expected: dict[str, Any] = {
        "entry_speed_kmh": {"uniform": [45.0, 65.0]},
        "load_factor": {"uniform": [0.0, 1.0]},
        "load_weighing_error_pct": {"normal": [0.0, 3.0], "clip": [-10.0, 10.0]},
        "brake_gain": {"normal": [1.0, 0.07], "clip": [0.8, 1.2]},
        "brake_dead_time_s": {"uniform": [0.2, 0.5]},
        "brake_time_constant_s": {"uniform": [0.3, 0.6]},
        "platform_gradient_permille": {"uniform": [-3.0, 3.0]},
        "approach_gradient_permille": {"uniform": [-20.0, 20.0]},
        "wheel_diameter_mm": {"uniform": [780.0, 860.0]},
        "odometer_diameter_error_pct": {"uniform": [-1.5, 1.5]},
        "low_adhesion_probability": 0.05,
        "low_adhesion_mu": {"uniform": [0.05, 0.09]},
        "low_adhesion_length_m": {"uniform": [30.0, 80.0]},
        "radio_latency_ms": {"uniform": [20.0, 80.0]},
        "radio_loss_probability": 0.02,
        "sensor_jitter_ms": {"fixed": 1.0},
        "sensor_miss_probability": 0.001,
        "doppler_noise_pct": {"fixed": 0.5},
        # Added with the link layer: none in the standard set.
        "radio_jitter_ms": {"fixed": 0.0},
        "radio_bit_error_rate": {"fixed": 0.0},
        # Added with the supervision: a fault, none in service.
        "radio_outage_start_s": {"fixed": 0.0},
        "radio_outage_duration_s": {"fixed": 0.0},
        # Added with the medium's bursts and reordering (stop model 13): none in the standard set.
        "radio_burst_enter_probability": 0.0,
        "radio_burst_exit_probability": 1.0,
        "radio_burst_loss_probability": 0.0,
        "radio_reorder_probability": 0.0,
    }
    d = standard.to_dict()
    assert d.pop("description") == standard.description
    assert d == expected
    assert list(d) == list(PARAMETERS)  # to_dict keeps the fixed parameter order
    json.dumps(standard.to_dict())  # JSON-able for the campaign manifest


def test_wide_is_the_standard_set_with_slow_brakes_and_a_poor_radio(standard: DisturbanceSet) -> None:
    """The wide set differs from the standard one exactly in the six parameters it widens, and
    its draws span the new ranges (10,000 runs)."""
    wide = load_disturbances("wide")
    changed = {
        "brake_gain": {"uniform": [0.8, 1.25]},
        "brake_dead_time_s": {"uniform": [0.15, 0.8]},
        "brake_time_constant_s": {"uniform": [0.25, 0.9]},
        "radio_latency_ms": {"uniform": [20.0, 200.0]},
        "radio_loss_probability": 0.10,
        "sensor_miss_probability": 0.01,
    }
    d, base = wide.to_dict(), standard.to_dict()
    d.pop("description"), base.pop("description")
    assert {k: v for k, v in d.items() if base.get(k) != v} == changed
    _, values = draw_scenario(wide, HILLCREST, VEHICLE, RunStreams.for_runs(SEED, 0, 10_000))
    for name, spec in changed.items():
        if isinstance(spec, dict):
            lo, hi = spec["uniform"]
            x = values[name]
            assert lo <= x.min() < lo + 0.01 * (hi - lo) and hi - 0.01 * (hi - lo) < x.max() <= hi, name


@pytest.mark.parametrize("station", LINE.stations, ids=lambda s: s.name)
@pytest.mark.parametrize("n", [1, 7])
def test_nominal_set_is_the_nominal_scenario(station: Station, n: int) -> None:
    scen, values = draw_scenario(
        load_disturbances("nominal"), station, VEHICLE, RunStreams.for_runs(SEED, 100, n)
    )
    ref = Scenario.nominal(station, VEHICLE, n=n)
    assert scen.n == n
    for name in SCENARIO_ARRAYS:
        np.testing.assert_array_equal(getattr(scen, name), getattr(ref, name), err_msg=name)
        assert getattr(scen, name).shape == (n,)
    np.testing.assert_array_equal(scen.gradient.breakpoints_m, ref.gradient.breakpoints_m)
    np.testing.assert_array_equal(scen.gradient.values_permille, ref.gradient.values_permille)
    same_gradient(scen.gradient, ref.gradient, station, n)
    # The columns hold the nominal values in the file's units.
    assert set(values) == {*PARAMETERS, LOW_ADHESION, LOW_ADHESION_START}
    for name, arr in values.items():
        assert arr.shape == (n,), name
    np.testing.assert_array_equal(values["entry_speed_kmh"], station.tasc.entry_speed_kmh)
    np.testing.assert_array_equal(values["wheel_diameter_mm"], VEHICLE.wheel_diameter_m * 1e3)
    np.testing.assert_array_equal(values["brake_gain"], 1.0)
    np.testing.assert_array_equal(values["low_adhesion_probability"], 0.0)
    assert values[LOW_ADHESION].dtype == np.bool_
    assert not values[LOW_ADHESION].any()
    assert np.all(np.isinf(values[LOW_ADHESION_START]))


def test_nominal_columns_report_the_station_gradients() -> None:
    # Hillcrest: -15 permille up to 2525 m (= platform start), -2 permille on the platform.
    _, values = draw_scenario(load_disturbances("nominal"), HILLCREST, VEHICLE, RunStreams.for_runs(1, 0, 3))
    np.testing.assert_allclose(values["approach_gradient_permille"], -15.0, atol=1e-9)
    np.testing.assert_allclose(values["platform_gradient_permille"], -2.0, atol=1e-9)


# --------------------------------------------------------------------------
# Reproducibility


def test_same_seed_same_draws(standard: DisturbanceSet) -> None:
    a_scen, a = draw_scenario(standard, HILLCREST, VEHICLE, RunStreams.for_runs(SEED, 0, 500))
    b_scen, b = draw_scenario(standard, HILLCREST, VEHICLE, RunStreams.for_runs(SEED, 0, 500))
    for name in a:
        np.testing.assert_array_equal(a[name], b[name], err_msg=name)
    for name in SCENARIO_ARRAYS:
        np.testing.assert_array_equal(getattr(a_scen, name), getattr(b_scen, name), err_msg=name)
    np.testing.assert_array_equal(a_scen.gradient.values_permille, b_scen.gradient.values_permille)
    # Another seed gives other draws.
    _, c = draw_scenario(standard, HILLCREST, VEHICLE, RunStreams.for_runs(SEED + 1, 0, 500))
    assert not np.array_equal(a["brake_gain"], c["brake_gain"])
    assert not np.array_equal(a["entry_speed_kmh"], c["entry_speed_kmh"])


CHUNK_SEED = 987_654_321


@pytest.fixture(scope="module")
def chunk_1000(standard: DisturbanceSet) -> tuple[Scenario, dict[str, np.ndarray]]:
    return draw_scenario(standard, HILLCREST, VEHICLE, RunStreams.for_runs(CHUNK_SEED, 0, 1000))


@given(st.integers(0, 999))
@FAST
def test_run_drawn_alone_equals_run_in_a_chunk(
    standard: DisturbanceSet, chunk_1000: tuple[Scenario, dict[str, np.ndarray]], i: int
) -> None:
    chunk_scen, chunk = chunk_1000
    alone_scen, alone = draw_scenario(standard, HILLCREST, VEHICLE, RunStreams.for_runs(CHUNK_SEED, i, 1))
    for name in chunk:
        np.testing.assert_array_equal(alone[name], chunk[name][i : i + 1], err_msg=name)
    for name in SCENARIO_ARRAYS:
        np.testing.assert_array_equal(
            getattr(alone_scen, name), getattr(chunk_scen, name)[i : i + 1], err_msg=name
        )
    np.testing.assert_array_equal(alone_scen.gradient.breakpoints_m, chunk_scen.gradient.breakpoints_m)
    np.testing.assert_array_equal(
        alone_scen.gradient.values_permille, chunk_scen.gradient.values_permille[i : i + 1]
    )


def test_chunking_does_not_matter(standard: DisturbanceSet) -> None:
    # 1000 runs drawn in uneven chunks equal the 1000 drawn at once.
    _, whole = draw_scenario(standard, HILLCREST, VEHICLE, RunStreams.for_runs(5, 0, 1000))
    parts = [
        draw_scenario(standard, HILLCREST, VEHICLE, RunStreams.for_runs(5, a, b - a))[1]
        for a, b in [(0, 1), (1, 334), (334, 999), (999, 1000)]
    ]
    for name in whole:
        np.testing.assert_array_equal(np.concatenate([p[name] for p in parts]), whole[name], err_msg=name)


def test_counter_blocks_are_disjoint() -> None:
    blocks = list(COUNTER_BLOCKS.values())
    assert len(blocks) == len(set(blocks)), "two quantities share a counter block"
    assert set(PARAMETERS) <= set(COUNTER_BLOCKS)
    assert COUNTER_STRIDE >= 2  # a uniform at base, a normal at base + 1
    for name in COUNTER_BLOCKS:
        assert counter_base(name) == COUNTER_BLOCKS[name] * COUNTER_STRIDE
    # The numbers are fixed: renumbering would change every stored campaign.
    assert COUNTER_BLOCKS["entry_speed_kmh"] == 0
    assert COUNTER_BLOCKS["brake_gain"] == 3
    assert COUNTER_BLOCKS["doppler_noise_pct"] == 18


def test_a_parameter_draw_does_not_depend_on_the_others(tmp_path: Path, big_draw: Any) -> None:
    # The same distribution alone in a file, or with other parameters, gives the
    # same per-run values: adding or removing a parameter changes no other draw.
    _, full = big_draw
    alone = load_disturbances(write(tmp_path, "brake_gain = {normal = [1.0, 0.07], clip = [0.8, 1.2]}\n"))
    _, values = draw_scenario(alone, HILLCREST, VEHICLE, RunStreams.for_runs(SEED, 0, N_STAT))
    np.testing.assert_array_equal(values["brake_gain"], full["brake_gain"])
    # ... and the absent ones take their nominal values.
    np.testing.assert_array_equal(values["load_factor"], 0.0)
    np.testing.assert_array_equal(values["entry_speed_kmh"], HILLCREST.tasc.entry_speed_kmh)
    two = load_disturbances(
        write(
            tmp_path,
            "low_adhesion_probability = 0.05\nlow_adhesion_mu = {uniform = [0.05, 0.09]}\n"
            "wheel_diameter_mm = {uniform = [780.0, 860.0]}\n",
            "two.toml",
        )
    )
    _, values = draw_scenario(two, HILLCREST, VEHICLE, RunStreams.for_runs(SEED, 0, N_STAT))
    for name in ("wheel_diameter_mm", "low_adhesion_mu", LOW_ADHESION, LOW_ADHESION_START):
        np.testing.assert_array_equal(values[name], full[name], err_msg=name)


def test_subset_of_runs_gets_the_same_values(standard: DisturbanceSet) -> None:
    rs = RunStreams.for_runs(11, 40, 300)
    mask = np.arange(300) % 3 == 1
    _, whole = draw_scenario(standard, HILLCREST, VEHICLE, rs)
    _, sub = draw_scenario(standard, HILLCREST, VEHICLE, rs.subset(mask))
    for name in whole:
        np.testing.assert_array_equal(sub[name], whole[name][mask], err_msg=name)


# --------------------------------------------------------------------------
# Sample statistics of the standard set (20,000 runs, fixed seed)

UNIFORMS = {
    "entry_speed_kmh": (45.0, 65.0),
    "load_factor": (0.0, 1.0),
    "brake_dead_time_s": (0.2, 0.5),
    "brake_time_constant_s": (0.3, 0.6),
    "platform_gradient_permille": (-3.0, 3.0),
    "approach_gradient_permille": (-20.0, 20.0),
    "wheel_diameter_mm": (780.0, 860.0),
    "odometer_diameter_error_pct": (-1.5, 1.5),
    "low_adhesion_mu": (0.05, 0.09),
    "low_adhesion_length_m": (30.0, 80.0),
    "radio_latency_ms": (20.0, 80.0),
}


@pytest.mark.parametrize("name", list(UNIFORMS))
def test_uniform_statistics(big_draw: Any, name: str) -> None:
    _, values = big_draw
    x = values[name]
    lo, hi = UNIFORMS[name]
    w = hi - lo
    assert x.shape == (N_STAT,)
    assert x.min() >= lo and x.max() <= hi
    assert x.min() - lo < 0.002 * w and hi - x.max() < 0.002 * w  # the whole range is used
    assert x.mean() == pytest.approx((lo + hi) / 2, abs=4 * w / math.sqrt(12 * N_STAT))
    assert x.std() == pytest.approx(w / math.sqrt(12), rel=0.03)
    hist, _ = np.histogram(x, bins=10, range=(lo, hi))
    np.testing.assert_allclose(hist / N_STAT, 0.1, atol=0.01)


@pytest.mark.parametrize(
    ("name", "mean", "sd", "clip"),
    [("load_weighing_error_pct", 0.0, 3.0, (-10.0, 10.0)), ("brake_gain", 1.0, 0.07, (0.8, 1.2))],
)
def test_clipped_normal_statistics(
    big_draw: Any, name: str, mean: float, sd: float, clip: tuple[float, float]
) -> None:
    _, values = big_draw
    x = values[name]
    assert x.min() >= clip[0] and x.max() <= clip[1]
    assert x.mean() == pytest.approx(mean, abs=4 * sd / math.sqrt(N_STAT))
    assert x.std() == pytest.approx(sd, rel=0.04)
    # Clipped, not resampled: the tails sit on the bounds.
    c = (clip[1] - mean) / sd
    at_bounds = np.mean((x == clip[0]) | (x == clip[1]))
    assert at_bounds == pytest.approx(math.erfc(c / math.sqrt(2)), abs=0.0015)
    inside = x[(x > clip[0]) & (x < clip[1])]
    assert np.mean(np.abs(inside - mean) < sd) == pytest.approx(0.6827, abs=0.012)


def test_fixed_and_probability_values(big_draw: Any) -> None:
    scen, values = big_draw
    np.testing.assert_array_equal(values["sensor_jitter_ms"], 1.0)
    np.testing.assert_array_equal(values["doppler_noise_pct"], 0.5)
    np.testing.assert_array_equal(values["radio_loss_probability"], 0.02)
    np.testing.assert_array_equal(values["sensor_miss_probability"], 0.001)
    np.testing.assert_array_equal(values["low_adhesion_probability"], 0.05)
    np.testing.assert_allclose(scen.sensor_jitter_s, 0.001)
    np.testing.assert_allclose(scen.doppler_noise_frac, 0.005)
    np.testing.assert_array_equal(scen.radio_loss_probability, 0.02)
    np.testing.assert_array_equal(scen.sensor_miss_probability, 0.001)


def test_low_adhesion_patches(big_draw: Any) -> None:
    scen, values = big_draw
    hit = values[LOW_ADHESION]
    p = 0.05
    assert hit.mean() == pytest.approx(p, abs=4 * math.sqrt(p * (1 - p) / N_STAT))
    first = HILLCREST.detector_positions_m()[0]
    last = HILLCREST.stop_point_m - 10.0
    start = values[LOW_ADHESION_START]
    assert np.all(np.isinf(start[~hit]))
    assert np.all((start[hit] >= first) & (start[hit] <= last))
    # Patch starts spread over the whole TASC zone.
    assert start[hit].mean() == pytest.approx((first + last) / 2, abs=0.05 * (last - first))
    np.testing.assert_array_equal(scen.low_mu_start_m, start)
    np.testing.assert_allclose(scen.low_mu_end_m[hit], start[hit] + values["low_adhesion_length_m"][hit])
    assert np.all(np.isinf(scen.low_mu_end_m[~hit]))
    np.testing.assert_array_equal(scen.low_mu[hit], values["low_adhesion_mu"][hit])
    np.testing.assert_array_equal(scen.low_mu[~hit], VEHICLE.adhesion_mu)
    np.testing.assert_array_equal(scen.adhesion_mu, VEHICLE.adhesion_mu)


def test_units_are_converted_to_the_scenario(big_draw: Any) -> None:
    scen, v = big_draw
    np.testing.assert_array_equal(scen.entry_speed_mps, v["entry_speed_kmh"] * MPS_PER_KMH)
    np.testing.assert_array_equal(scen.load_factor, v["load_factor"])
    np.testing.assert_allclose(scen.load_weighing_error, v["load_weighing_error_pct"] / 100)
    np.testing.assert_array_equal(scen.brake_gain, v["brake_gain"])
    np.testing.assert_array_equal(scen.dead_time_s, v["brake_dead_time_s"])
    np.testing.assert_array_equal(scen.time_constant_s, v["brake_time_constant_s"])
    np.testing.assert_allclose(scen.wheel_diameter_m, v["wheel_diameter_mm"] / 1000)
    np.testing.assert_allclose(scen.odometer_diameter_error, v["odometer_diameter_error_pct"] / 100)
    np.testing.assert_allclose(scen.radio_latency_s, v["radio_latency_ms"] / 1000)


def test_gradient_zones(big_draw: Any) -> None:
    scen, v = big_draw
    n = 200
    g = scen.gradient
    first = HILLCREST.detector_positions_m()[0]
    a0, p0, p1 = first - 150.0, HILLCREST.platform_start, HILLCREST.platform_end
    rows = np.arange(n)

    def mean_under(front: float) -> np.ndarray:
        return g.mean_gradient(np.full(n, front), TRAIN_M, rows) * 1e3

    # Whole train in the approach zone, on the platform, before the zone.
    np.testing.assert_allclose(mean_under(p0 - 1.0), v["approach_gradient_permille"][:n], atol=1e-9)
    np.testing.assert_allclose(mean_under(a0 + TRAIN_M), v["approach_gradient_permille"][:n], atol=1e-9)
    assert p1 - p0 >= TRAIN_M
    np.testing.assert_allclose(mean_under(p1), v["platform_gradient_permille"][:n], atol=1e-9)
    np.testing.assert_allclose(mean_under(a0 - 1.0), 0.0, atol=1e-12)
    np.testing.assert_allclose(mean_under(p1 + TRAIN_M), 0.0, atol=1e-12)
    # Straddling the platform start: the length-weighted mix of both zones.
    front = p0 + 30.0
    want = (
        v["approach_gradient_permille"][:n] * (TRAIN_M - 30.0) + v["platform_gradient_permille"][:n] * 30.0
    ) / TRAIN_M
    np.testing.assert_allclose(mean_under(front), want, atol=1e-9)


def test_one_gradient_absent_keeps_the_station_mean(tmp_path: Path) -> None:
    path = write(tmp_path, "platform_gradient_permille = {uniform = [-3.0, 3.0]}\n")
    scen, v = draw_scenario(load_disturbances(path), HILLCREST, VEHICLE, RunStreams.for_runs(3, 0, 50))
    # Hillcrest's approach is -15 permille; the approach zone keeps it.
    np.testing.assert_allclose(v["approach_gradient_permille"], -15.0, atol=1e-9)
    p0 = HILLCREST.platform_start
    got = scen.gradient.mean_gradient(np.full(50, p0 - 1.0), TRAIN_M) * 1e3
    np.testing.assert_allclose(got, -15.0, atol=1e-9)
    got = scen.gradient.mean_gradient(np.full(50, HILLCREST.platform_end), TRAIN_M) * 1e3
    np.testing.assert_allclose(got, v["platform_gradient_permille"], atol=1e-9)
    assert not np.allclose(v["platform_gradient_permille"], -2.0)
    # Both absent: the station's own profile, unchanged.
    path = write(tmp_path, "brake_gain = {fixed = 0.9}\n", "other.toml")
    scen, _ = draw_scenario(load_disturbances(path), HILLCREST, VEHICLE, RunStreams.for_runs(3, 0, 5))
    same_gradient(scen.gradient, station_gradient(HILLCREST, 5), HILLCREST, 5)


# --------------------------------------------------------------------------
# Other distribution kinds


def test_clip_is_respected(tmp_path: Path) -> None:
    # A wide normal clipped hard: every draw inside the clip, the excess on the bounds.
    path = write(tmp_path, "brake_gain = {normal = [1.0, 0.5], clip = [0.9, 1.1]}\n")
    _, v = draw_scenario(load_disturbances(path), HILLCREST, VEHICLE, RunStreams.for_runs(8, 0, N_STAT))
    x = v["brake_gain"]
    assert x.min() == 0.9 and x.max() == 1.1
    p_out = math.erfc(0.2 / math.sqrt(2))  # P(|Z| > 0.2) = 0.84
    assert np.mean((x == 0.9) | (x == 1.1)) == pytest.approx(p_out, abs=0.01)
    assert np.mean(x == 0.9) == pytest.approx(p_out / 2, abs=0.01)


def test_choice_picks_uniformly(tmp_path: Path) -> None:
    path = write(
        tmp_path, "wheel_diameter_mm = {choice = [780, 820.0, 860]}\nentry_speed_kmh = {choice = [50]}\n"
    )
    scen, v = draw_scenario(load_disturbances(path), HILLCREST, VEHICLE, RunStreams.for_runs(9, 0, N_STAT))
    x = v["wheel_diameter_mm"]
    assert set(np.unique(x)) == {780.0, 820.0, 860.0}
    for value in (780.0, 820.0, 860.0):
        assert np.mean(x == value) == pytest.approx(1 / 3, abs=0.015)
    np.testing.assert_array_equal(v["entry_speed_kmh"], 50.0)
    np.testing.assert_array_equal(scen.entry_speed_mps, 50.0 * MPS_PER_KMH)


def test_certain_low_adhesion(tmp_path: Path) -> None:
    path = write(tmp_path, "low_adhesion_probability = 1\nlow_adhesion_mu = {fixed = 0.06}\n")
    scen, v = draw_scenario(load_disturbances(path), HILLCREST, VEHICLE, RunStreams.for_runs(4, 0, 1000))
    assert v[LOW_ADHESION].all()
    np.testing.assert_array_equal(scen.low_mu, 0.06)
    # Absent length: uniform 30..80 m.
    length = scen.low_mu_end_m - scen.low_mu_start_m
    assert length.min() >= 30.0 - 1e-9 and length.max() <= 80.0 + 1e-9
    assert length.mean() == pytest.approx(55.0, abs=1.5)


def test_load_by_path_object_and_string(tmp_path: Path) -> None:
    path = write(tmp_path, 'description = "mine"\nload_factor = {fixed = 0.5}\n')
    a = load_disturbances(path)
    b = load_disturbances(str(path))
    assert a.name == str(path) and a.source == str(path)
    assert a.params == b.params
    assert a.description == "mine"
    assert a.params["load_factor"] == Distribution(fixed=0.5)


# --------------------------------------------------------------------------
# to_dict round trip (the campaign manifest)


def _range_floats(lo: float, hi: float) -> st.SearchStrategy[float]:
    return st.floats(lo, hi, allow_nan=False, allow_infinity=False, allow_subnormal=False)


# Parameters with a closed, wide-enough range for generated distributions.
GEN_RANGES = {
    "load_factor": (0.0, 1.0),
    "load_weighing_error_pct": (-50.0, 50.0),
    "approach_gradient_permille": (-60.0, 60.0),
    "brake_dead_time_s": (0.0, 2.0),
    "radio_latency_ms": (0.0, 2000.0),
}


@st.composite
def distributions(draw: st.DrawFn, name: str) -> dict[str, Any]:
    lo, hi = GEN_RANGES[name]
    kind = draw(st.sampled_from(["fixed", "uniform", "normal", "choice"]))
    x = _range_floats(lo, hi)
    if kind == "fixed":
        return {"fixed": draw(x)}
    if kind == "uniform":
        return {"uniform": sorted([draw(x), draw(x)])}
    if kind == "choice":
        return {"choice": draw(st.lists(x, min_size=1, max_size=5))}
    return {
        "normal": [draw(x), draw(_range_floats(0.0, hi - lo))],
        "clip": sorted([draw(x), draw(x)]),
    }


@st.composite
def disturbance_dicts(draw: st.DrawFn) -> dict[str, Any]:
    out: dict[str, Any] = {}
    if draw(st.booleans()):
        out["description"] = draw(st.text("abc xyz", max_size=20))
    for name in GEN_RANGES:
        if draw(st.booleans()):
            out[name] = draw(distributions(name))
    for name in ("radio_loss_probability", "low_adhesion_probability"):
        if draw(st.booleans()):
            out[name] = draw(_range_floats(0.0, 1.0))
    return out


def to_toml(data: dict[str, Any]) -> str:
    lines = []
    for key, value in data.items():
        if isinstance(value, dict):
            inner = ", ".join(f"{k} = {json.dumps(v)}" for k, v in value.items())
            lines.append(f"{key} = {{{inner}}}")
        else:
            lines.append(f"{key} = {json.dumps(value)}")
    return "\n".join(lines) + "\n"


@given(disturbance_dicts())
@FAST
def test_to_dict_round_trips(tmp_path_factory: pytest.TempPathFactory, data: dict[str, Any]) -> None:
    ds = DisturbanceSet.from_dict(data)
    d = ds.to_dict()
    assert json.loads(json.dumps(d)) == d
    again = DisturbanceSet.from_dict(json.loads(json.dumps(d)))
    assert again.params == ds.params
    assert again.description == ds.description
    # The dict means the same as the TOML file it describes: same draws.
    path = tmp_path_factory.mktemp("rt") / "d.toml"
    path.write_text(to_toml(d), encoding="utf-8")
    from_file = load_disturbances(path)
    assert from_file.params == ds.params
    rs = RunStreams.for_runs(77, 0, 64)
    _, a = draw_scenario(ds, HILLCREST, VEHICLE, rs)
    _, b = draw_scenario(from_file, HILLCREST, VEHICLE, rs)
    for name in a:
        np.testing.assert_array_equal(a[name], b[name], err_msg=name)
    # Every draw lies within its distribution's bounds.
    for name, dist in ds.params.items():
        if dist.uniform is not None:
            assert np.all((a[name] >= dist.uniform[0]) & (a[name] <= dist.uniform[1]))
        if dist.clip is not None:
            assert np.all((a[name] >= dist.clip[0]) & (a[name] <= dist.clip[1]))
        if dist.choice is not None:
            assert set(a[name]) <= set(dist.choice)


# --------------------------------------------------------------------------
# Bad files: one line naming the file, the field and the bad value

BAD_FILES = [
    ("unknown name", "brake_gian = {fixed = 1.0}\n", "brake_gian", None),
    ("lo > hi", "load_factor = {uniform = [0.8, 0.2]}\n", "load_factor.uniform", "[0.8, 0.2]"),
    ("probability 1.5", "radio_loss_probability = 1.5\n", "radio_loss_probability", "1.5"),
    ("normal without clip", "brake_gain = {normal = [1.0, 0.07]}\n", "brake_gain.normal", "[1.0, 0.07]"),
    ("uniform out of range", "load_factor = {uniform = [0, 2]}\n", "load_factor.uniform", "[0, 2]"),
    ("toml syntax", "entry_speed_kmh = {uniform = [45.0, \n", "(toml syntax)", None),
    ("empty choice", "wheel_diameter_mm = {choice = []}\n", "wheel_diameter_mm.choice", "[]"),
    (
        "choice out of range",
        "wheel_diameter_mm = {choice = [800, 1300]}\n",
        "wheel_diameter_mm.choice",
        "[800, 1300]",
    ),
    (
        "negative sd",
        "brake_gain = {normal = [1.0, -0.1], clip = [0.8, 1.2]}\n",
        "brake_gain.normal",
        "[1.0, -0.1]",
    ),
    (
        "clip out of range",
        "brake_gain = {normal = [1.0, 0.1], clip = [0.0, 1.2]}\n",
        "brake_gain.clip",
        "[0.0, 1.2]",
    ),
    (
        "clip lo > hi",
        "brake_gain = {normal = [1.0, 0.1], clip = [1.2, 0.8]}\n",
        "brake_gain.clip",
        "[1.2, 0.8]",
    ),
    ("fixed out of range", "brake_time_constant_s = {fixed = 0.0}\n", "brake_time_constant_s.fixed", "0.0"),
    (
        "negative time",
        "brake_dead_time_s = {uniform = [-0.1, 0.5]}\n",
        "brake_dead_time_s.uniform",
        "[-0.1, 0.5]",
    ),
    ("zero wheel", "wheel_diameter_mm = {fixed = 0}\n", "wheel_diameter_mm.fixed", "0"),
    ("two kinds", "brake_gain = {fixed = 1.0, uniform = [0.9, 1.1]}\n", "brake_gain.uniform", "[0.9, 1.1]"),
    ("not a table", "brake_gain = 1.0\n", "brake_gain", "1.0"),
    ("unknown kind key", "brake_gain = {mean = 1.0}\n", "brake_gain.mean", None),
    (
        "clip without normal",
        "load_factor = {uniform = [0, 1], clip = [0, 1]}\n",
        "load_factor.clip",
        "[0, 1]",
    ),
    ("uniform of one number", "load_factor = {uniform = [0.5]}\n", "load_factor.uniform", "[0.5]"),
    ("negative probability", "sensor_miss_probability = -0.1\n", "sensor_miss_probability", "-0.1"),
    ("boolean probability", "sensor_miss_probability = true\n", "sensor_miss_probability", "True"),
    ("nan", "brake_gain = {fixed = nan}\n", "brake_gain.fixed", "nan"),
]


@pytest.mark.parametrize(("case", "text", "field", "value"), BAD_FILES, ids=[c[0] for c in BAD_FILES])
def test_bad_file_is_rejected(tmp_path: Path, case: str, text: str, field: str, value: str | None) -> None:
    path = write(tmp_path, text)
    with pytest.raises(ConfigError) as info:
        load_disturbances(path)
    msg = str(info.value)
    assert "\n" not in msg
    assert msg.startswith(f"{path}: {field}: "), msg
    assert info.value.source == str(path)
    assert info.value.field == field
    if value is not None:
        assert msg.endswith(f"(got {value})"), msg
    else:
        assert field in msg


def test_error_messages_are_actionable(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="did you mean 'brake_gain'"):
        load_disturbances(write(tmp_path, "brake_gian = {fixed = 1.0}\n"))
    with pytest.raises(ConfigError, match="add clip"):
        load_disturbances(write(tmp_path, "brake_gain = {normal = [1.0, 0.07]}\n"))
    with pytest.raises(ConfigError, match=r"0 <= load_factor <= 1"):
        load_disturbances(write(tmp_path, "load_factor = {uniform = [0, 2]}\n"))
    with pytest.raises(ConfigError) as info:
        load_disturbances(write(tmp_path, "x = [\n"))
    assert info.value.field == "(toml syntax)" and info.value.message  # tomllib says what and where


def test_missing_file_and_unknown_set(tmp_path: Path) -> None:
    with pytest.raises(ConfigError) as info:
        load_disturbances(tmp_path / "absent.toml")
    assert str(tmp_path / "absent.toml") in str(info.value)
    with pytest.raises(ConfigError, match="nominal, outage-after-first, standard"):
        load_disturbances("standrad")


def test_from_dict_validates_like_a_file() -> None:
    with pytest.raises(ConfigError) as info:
        DisturbanceSet.from_dict({"load_factor": {"uniform": [0, 2]}}, source="manifest.json")
    assert str(info.value).startswith("manifest.json: load_factor.uniform: ")


def test_standard_draws_are_pairwise_uncorrelated() -> None:
    """No two parameters share random numbers: their draws are uncorrelated."""
    st = default_line().stations[0]
    _, drawn = draw_scenario(
        load_disturbances("standard"), st, default_vehicle(), RunStreams.for_runs(11, 0, 20_000)
    )
    names = [k for k, v in drawn.items() if np.ptp(np.asarray(v, dtype=np.float64)[np.isfinite(v)]) > 0]
    names = [k for k in names if k != "low_adhesion_start_m"]
    x = np.array([np.asarray(drawn[k], dtype=np.float64) for k in names])
    corr = np.corrcoef(x)
    off = np.abs(corr - np.eye(len(names)))
    worst = np.unravel_index(off.argmax(), off.shape)
    assert off.max() < 0.03, (names[worst[0]], names[worst[1]], off.max())


def test_the_bursty_radio_example_is_the_standard_set_on_bursts(standard: DisturbanceSet) -> None:
    """``examples/disturbances/bursty-radio.toml`` (docs/campaigns.md): the standard set with the
    radio medium preset's bursts and reordering, nothing else changed."""
    example = load_disturbances(ROOT / "examples" / "disturbances" / "bursty-radio.toml")
    differ = {k for k in PARAMETERS if example.params.get(k) != standard.params.get(k)}
    assert differ == {
        "radio_burst_enter_probability",
        "radio_burst_exit_probability",
        "radio_burst_loss_probability",
        "radio_reorder_probability",
    }
    radio = media_preset("radio")
    assert probability(example, "radio_burst_enter_probability") == radio.burst_enter_probability
    assert probability(example, "radio_burst_exit_probability") == radio.burst_exit_probability
    assert probability(example, "radio_burst_loss_probability") == radio.burst_loss_probability
    assert probability(example, "radio_reorder_probability") == radio.reorder_probability
