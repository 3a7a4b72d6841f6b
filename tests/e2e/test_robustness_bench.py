"""``benchmarks/robustness.py`` on a few runs: every setting row is there, the shares are shares,
the JSON parses, and each cell's distribution is one the disturbance file accepts."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

from bench_loader import load_benchmark
from railstop.config import default_line, default_vehicle

bench = load_benchmark("robustness")

ARGS = ["--runs", "20", "--controllers", "tasc-pwm", "--scales", "2"]


def _row_names() -> list[str]:
    swept = [name for name, _ in bench.SWEPT]
    return [bench.STANDARD_ROW, bench.NO_ADHESION_ROW, *swept, bench.ALL_ROW]


def test_json_has_every_setting_and_shares_between_0_and_1(capsys: pytest.CaptureFixture[str]) -> None:
    assert bench.main([*ARGS, "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["runs_per_cell"] == 20 and out["scales"] == [2.0]
    assert [s["name"] for s in out["settings"]] == _row_names()
    rows = out["results"]["tasc-pwm"]
    assert list(rows) == _row_names()
    for name, cells in rows.items():
        expected = {"1"} if name in (bench.STANDARD_ROW, bench.NO_ADHESION_ROW) else {"1", "2"}
        assert set(cells) == expected, name
        for r in cells.values():
            assert r["runs"] == 20
            for key in ("within_tolerance", "within_0_30", "within_0_35"):
                assert 0.0 <= r[key] <= 1.0
            assert r["within_0_30"] <= r["within_0_35"]
            assert 0 <= r["emergency_brakes"] <= 20
    # The k=1 column of a swept row is the standard set itself, on the same runs.
    assert rows["brake_gain"]["1"] == rows[bench.STANDARD_ROW]["1"]
    below = out["below_target_at_2x"]["tasc-pwm"]
    assert set(below) <= set(_row_names())
    assert out["wall_s"]["total"] > 0.0


def test_the_detectors_only_variant_is_swept_too(capsys: pytest.CaptureFixture[str]) -> None:
    """--detectors-only sweeps the station without its radar: its sensor-jitter row then moves the
    passage times the speed comes from, and the runs differ from the radar's."""
    assert bench.main([*ARGS, "--json", "--detectors-only"]) == 0
    variant = json.loads(capsys.readouterr().out)
    assert bench.main([*ARGS, "--json"]) == 0
    radar = json.loads(capsys.readouterr().out)
    assert variant["detectors_only"] is True and radar["detectors_only"] is False
    assert variant["station"] == radar["station"]
    assert variant["results"] != radar["results"]


def test_tables_print_every_row_and_the_summary(capsys: pytest.CaptureFixture[str]) -> None:
    assert bench.main(ARGS) == 0
    text = capsys.readouterr().out
    table = text.split("tasc-pwm at ", 1)[1]
    for name in _row_names():
        line = next(ln for ln in table.splitlines() if ln.startswith(name + " "))
        shares = [float(x) for x in re.findall(r"(\d+\.\d+)%", line)]
        assert shares and all(0.0 <= s <= 100.0 for s in shares), line
    assert "settings below 99 % within ±0.35 m at k=2:" in text
    assert re.search(r"^  tasc-pwm \(standard set [\d.]+ %\): ", text, re.MULTILINE)
    assert "wall time" in text


def test_scaling_rules_and_clipping() -> None:
    standard = bench.load_disturbances("standard")
    # A noise given by its sd: times k.
    assert bench.scaled("doppler_noise_pct", standard, 2.0).value == {"fixed": 1.0}
    # A uniform range: widened about its centre; a probability: times k.
    assert bench.scaled("brake_dead_time_s", standard, 2.0).value["uniform"] == pytest.approx([0.05, 0.65])
    assert bench.scaled("radio_loss_probability", standard, 3.0).value == pytest.approx(0.06)
    # A normal: sd times k, the clip widened about its centre.
    gain = bench.scaled("brake_gain", standard, 2.0).value
    assert gain["normal"] == pytest.approx([1.0, 0.14]) and gain["clip"] == pytest.approx([0.6, 1.4])
    # Beyond the physical range: clipped (inside an open bound) and said so.
    tau = bench.scaled("brake_time_constant_s", standard, 3.0)
    assert tau.clipped and 0.0 < tau.value["uniform"][0] < 0.15
    latency = bench.scaled("radio_latency_ms", standard, 2.0)
    assert latency.clipped and latency.value["uniform"] == pytest.approx([0.0, 110.0])
    assert bench.scaled("radio_loss_probability", standard, 100.0).value == 1.0
    # Every cell builds a set the disturbance file's validation accepts.
    for row in bench.settings(standard, [2.0, 3.0]):
        for k in row.cells:
            assert row.build(k).params


def test_a_cell_is_split_by_the_zone_and_by_the_odometers_declared_accuracy() -> None:
    """The envelope has two parts: the zone's (its length rule at the run's entry and downhill) and
    the vehicle's declared odometer accuracy, which the onboard overrun guard counts; a run beyond
    the zone counts there, one inside it with an odometer beyond its declaration counts apart."""
    line, vehicle = default_line(), default_vehicle()
    station = line.stations[0]
    declared = vehicle.atp.odometer_uncertainty_pct
    n = 6
    col = {
        "speed": np.array([60.0, 60.0, 60.0, 60.0, 120.0, 120.0]),  # the last two beyond the zone
        "approach": np.zeros(n),
        "platform": np.array([0.0, 0.0, 0.0, 0.0, -40.0, -40.0]),
        "odometer": np.array([0.0, declared, -(declared + 0.5), declared + 0.5, declared + 1.0, 0.0]),
        "error": np.array([0.01, 0.02, -0.5, -2.0, 0.01, 3.0]),
        "eb": np.array([0, 0, 0, 5, 0, 0]),
        "patch": np.zeros(n),
    }
    split = bench.envelope_split(station, vehicle, col)
    inside, odometer, zone = split["inside_envelope"], split["beyond_odometer"], split["beyond_zone"]
    assert (inside["runs"], odometer["runs"], zone["runs"]) == (2, 2, 2)
    assert inside["within_tolerance"] == 1.0 and inside["emergency_brakes"] == 0
    assert odometer["within_tolerance"] == 0.0 and odometer["emergency_brakes"] == 1
    assert odometer["silent_misses_off_patches"] == 1
    assert zone["within_tolerance"] == 0.5 and zone["silent_misses_off_patches"] == 1
