"""Engineering plausibility of a line with a vehicle (``railstop.config.plausibility``)."""

from __future__ import annotations

import subprocess
import tomllib
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from railstop.config import load_line, load_vehicle
from railstop.config.disturbances import DisturbanceSet, load_disturbances
from railstop.config.loader import validate
from railstop.config.plausibility import (
    BRAKE_MARGIN,
    beyond_envelope,
    envelope_note,
    plausibility_problems,
    stopping_distance_m,
)
from railstop.config.schema import Line
from railstop.sim.single import run_stop
from zygote import run_cli

LINE_TOML = Path(__file__).resolve().parents[2] / "src" / "railstop" / "data" / "line.toml"


def run(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return run_cli(*args, cwd=cwd)  # forked from a warm zygote (tests/zygote.py)


def line_data() -> dict[str, Any]:
    """The embedded line's data, every radar's range long enough for the zones these tests move
    (a radar must see its whole zone, ``TascZone``: the rule is not the one tested here)."""
    data = tomllib.loads(LINE_TOML.read_text(encoding="utf-8"))
    for st in data["stations"]:
        st["tasc"]["doppler"]["range_m"] = 2000.0
    return data


def write_line(tmp_path: Path, data: dict[str, Any]) -> Path:
    """The line as TOML (tomllib reads, a tiny writer for this file's shapes writes)."""

    def value(v: Any) -> str:
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, str):
            return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
        if isinstance(v, list):
            return "[" + ", ".join(value(x) for x in v) + "]"
        if isinstance(v, dict):
            return "{ " + ", ".join(f"{k} = {value(x)}" for k, x in v.items()) + " }"
        return repr(v)

    lines = ["[line]", *(f"{k} = {value(v)}" for k, v in data["line"].items())]
    for st in data["stations"]:
        lines.append("[[stations]]")
        lines += [f"{k} = {value(v)}" for k, v in st.items()]
    lines.append("[track]")
    lines += [f"{k} = {value(v)}" for k, v in data["track"].items()]
    path = tmp_path / "line.toml"
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def as_line(data: dict[str, Any]) -> Line:
    return validate(Line, data, "test")


def fields(problems: list[Any]) -> list[str]:
    return [p.field for p in problems]


def test_the_embedded_line_is_plausible() -> None:
    assert plausibility_problems(load_line(None), load_vehicle(None), "x") == []


def test_a_detector_off_the_line_is_named_with_its_value() -> None:
    data = line_data()
    data["stations"][0]["tasc"]["detectors_before_stop_m"][0] = 1300.0  # Riverside stops at 1200 m
    problems = plausibility_problems(as_line(data), load_vehicle(None), "line.toml")
    assert fields(problems) == ["stations[0].tasc.detectors_before_stop_m[0]"]
    assert "at -100 m, off the line (0 .. 5800 m)" in str(problems[0])
    assert "(got 1300.0)" in str(problems[0])


def test_a_zone_reaching_back_past_the_previous_stop_and_a_radar_off_the_end() -> None:
    data = line_data()
    # Hillcrest stops at 2650 m; a detector 1500 m before it is at 1150 m, before Riverside's 1200 m.
    data["stations"][1]["tasc"]["detectors_before_stop_m"][0] = 1500.0
    data["stations"][3]["tasc"]["doppler"]["beyond_stop_m"] = 250.0  # Harbour 5600 + 250 > 5800
    problems = plausibility_problems(as_line(data), load_vehicle(None), "line.toml")
    assert fields(problems) == [
        "stations[1].tasc.detectors_before_stop_m[0]",
        "stations[3].tasc.doppler.beyond_stop_m",
    ]
    assert "at or before the stopping point of 'Riverside' (1200 m)" in str(problems[0])
    assert "puts the radar at 5850 m, off the line" in str(problems[1])


def test_the_approach_must_start_on_the_line() -> None:
    data = line_data()
    data["stations"][0]["stop_point_m"] = 400.0  # first detector at 70 m, approach from -80 m
    data["stations"][0]["gradient"] = []
    problems = plausibility_problems(as_line(data), load_vehicle(None), "line.toml")
    assert fields(problems) == ["stations[0].tasc.detectors_before_stop_m[0]"]
    assert "the approach starts 150 m before the first detector, at -80 m" in str(problems[0])


def test_entry_speed_above_the_line_limit() -> None:
    data = line_data()
    data["line"]["speed_limit_kmh"] = 58.0  # Riverside and Hillcrest enter at 60, Museum at 65
    problems = plausibility_problems(as_line(data), load_vehicle(None), "line.toml")
    assert fields(problems) == [f"stations[{i}].tasc.entry_speed_kmh" for i in (0, 1, 2)]
    assert "above the line's speed limit line.speed_limit_kmh = 58 km/h (got 60.0)" in str(problems[0])


def test_the_stopping_distance_is_the_kinematics_of_the_margin_braking() -> None:
    """Level zone: v·(dead time + build-up) + v²/(2·0.8·full service); a downhill lengthens it."""
    line, vehicle = load_line(None), load_vehicle(None)
    st = line.station("Riverside")  # level
    v = 60.0 / 3.6
    brake = vehicle.brake
    expected = v * (brake.dead_time_s + brake.time_constant_s) + v * v / (
        2 * BRAKE_MARGIN * brake.full_service_mps2
    )
    assert stopping_distance_m(st, vehicle, 60.0) == pytest.approx(expected, rel=1e-12)
    hill = line.station("Hillcrest")  # -15 permille in its zone
    assert stopping_distance_m(hill, vehicle, 60.0) > expected


def test_a_zone_flagged_too_short_overruns_and_one_passed_stops() -> None:
    """The check means what it says: the stop from a flagged zone overruns the PSD tolerance by
    far, and the same station with its zone just long enough stops within it."""
    vehicle = load_vehicle(None)
    data = line_data()
    harbour = data["stations"][3]
    need = stopping_distance_m(as_line(data).stations[3], vehicle, harbour["tasc"]["entry_speed_kmh"])
    harbour["tasc"]["detectors_before_stop_m"] = [0.6 * need, 0.45 * need, 0.3 * need, 0.15 * need, 6.0]
    short = as_line(data)
    problems = plausibility_problems(short, vehicle, "line.toml")
    assert fields(problems) == ["stations[3].tasc.detectors_before_stop_m[0]"]
    shorter = stopping_distance_m(short.stations[3], vehicle, harbour["tasc"]["entry_speed_kmh"])
    assert f"is too short: from 55 km/h '6-car metro EMU (4M2T)' needs {shorter:.0f} m at 80%" in str(
        problems[0]
    )
    result, _ = run_stop(
        line=short, station=short.stations[3], vehicle=vehicle, controller="tasc-pwm", seed=1
    )
    # A runaway the overrun guard had to stop by emergency brake (DESIGN rule 10), well outside
    # the tolerance, not a near miss.
    assert result.emergency_brake is not None
    assert result.stop_error_m > 0.5

    harbour["tasc"]["detectors_before_stop_m"] = [1.05 * need, 0.7 * need, 0.45 * need, 0.2 * need, 6.0]
    ok = as_line(data)
    assert plausibility_problems(ok, vehicle, "line.toml") == []
    result, _ = run_stop(line=ok, station=ok.stations[3], vehicle=vehicle, controller="tasc-pwm", seed=1)
    assert abs(result.stop_error_m) <= 0.35


def test_check_lists_every_problem_and_stop_refuses_in_one_line(tmp_path: Path) -> None:
    data = line_data()
    data["stations"][0]["tasc"]["detectors_before_stop_m"][0] = 1300.0
    data["stations"][2]["tasc"]["entry_speed_kmh"] = 95.0
    path = write_line(tmp_path, data)

    p = run("check", "--line", str(path), cwd=tmp_path)
    assert p.returncode == 2, p.stderr
    lines = [ln for ln in p.stderr.splitlines() if ln.strip()]
    assert "Traceback" not in p.stderr
    assert [ln.split(": ")[2] for ln in lines] == [
        "stations[0].tasc.detectors_before_stop_m[0]",
        "stations[2].tasc.entry_speed_kmh",
        "stations[2].tasc.detectors_before_stop_m[0]",  # 95 km/h does not stop in Museum's zone
    ]
    assert all(ln.startswith(f"error: {path}: ") for ln in lines)

    for args in (("stop", "--no-db"), ("campaign", "--runs", "10", "--out", "c")):
        p = run(*args, "--line", str(path), cwd=tmp_path)
        assert p.returncode == 2, p.stderr
        lines = [ln for ln in p.stderr.splitlines() if ln.strip()]
        assert len(lines) == 1, p.stderr
        assert "detectors_before_stop_m[0]: puts the detector at -100 m" in lines[0]
        assert lines[0].endswith("2 more: `railstop check` lists them")
    assert not (tmp_path / "c").exists()


def test_the_detectors_only_layout_is_checked_on_the_line(tmp_path: Path) -> None:
    """SPEC §1 claim 6: a zone's variant layout is placed on the line like its own detectors."""
    data = line_data()
    data["stations"][1]["tasc"]["detectors_only_before_stop_m"] = [1600.0, 320.0, 4.0]
    path = write_line(tmp_path, data)
    p = run("check", "--line", str(path), cwd=tmp_path)
    assert p.returncode == 2, p.stderr
    lines = [ln for ln in p.stderr.splitlines() if ln.strip()]
    assert "Traceback" not in p.stderr
    assert len(lines) == 1, p.stderr
    assert "stations[1].tasc.detectors_only_before_stop_m[0]: puts the detector at 1050 m" in lines[0]
    assert "'Riverside'" in lines[0]


def _set(**params: object) -> DisturbanceSet:
    return DisturbanceSet.from_dict(params, name="test", source="test")


def test_the_envelope_note_is_the_layout_rule_at_the_sets_fastest_entry_and_steepest_downhill() -> None:
    """The standard set draws entries to 65 km/h on approaches to -20 permille at every station: the
    rule (v·response + v²/(2·(0.8·full service - g·grade))) needs 284 m, which Riverside's 330 m zone
    has and the three others' 250-265 m zones have not; the nominal set (each station's own entry
    speed and gradient) is within every zone, as `railstop check` found."""
    line, vehicle = load_line(None), load_vehicle(None)
    standard = load_disturbances("standard")
    brake = vehicle.brake
    v = 65.0 / 3.6
    need = v * (brake.dead_time_s + brake.time_constant_s) + v * v / (
        2.0 * (BRAKE_MARGIN * brake.full_service_mps2 - 9.80665 * 20.0 / 1000.0)
    )
    for st in line.stations:
        first = st.tasc.detectors_before_stop_m[0]
        note = envelope_note(st, vehicle, standard)
        assert (note is not None) == (need > first), st.name
        if note is not None:
            assert f"entries up to 65 km/h (the station's entry speed is {st.tasc.entry_speed_kmh:g})" in note
            assert f"on downhills to -20 ‰ need {need:.0f} m" in note
            assert f"the first detector is {first:g} m out" in note
        assert envelope_note(st, vehicle, load_disturbances("nominal")) is None
    flagged = [envelope_note(st, vehicle, standard) is not None for st in line.stations]
    assert flagged == [False, True, True, True]
    # The set's steepest downhill is the steeper of its approach and platform draws, its fastest
    # entry the top of any distribution (here a clipped normal), never below the station's own.
    harbour = line.station("Harbour")
    assert envelope_note(harbour, vehicle, _set(platform_gradient_permille={"uniform": [-3.0, 3.0]})) is None
    # A set that draws the platform's gradient only keeps the approach's own (Hillcrest: -15).
    hill = line.station("Hillcrest")
    fast_on_own = _set(entry_speed_kmh={"fixed": 70.0}, platform_gradient_permille={"uniform": [-3.0, 3.0]})
    assert "on downhills to -15 ‰" in str(envelope_note(hill, vehicle, fast_on_own))
    steep = _set(platform_gradient_permille={"uniform": [-40.0, 0.0]})
    assert "on downhills to -40 ‰" in str(envelope_note(harbour, vehicle, steep))
    fast = _set(entry_speed_kmh={"normal": [55.0, 5.0], "clip": [45.0, 70.0]})
    assert "entries up to 70 km/h" in str(envelope_note(harbour, vehicle, fast))
    # Harbour with its first detector where the rule wants it: no note.
    data = line_data()
    data["stations"][3]["tasc"]["detectors_before_stop_m"] = [330.0, 230.0, 140.0, 60.0, 6.0]
    assert envelope_note(as_line(data).stations[3], vehicle, standard) is None


def test_beyond_envelope_is_the_note_run_by_run() -> None:
    """A run at its station's own entry speed and gradient is inside every default zone (the line
    passes `railstop check`); one at the standard set's extremes (65 km/h, -20 permille) is beyond
    exactly the zones the note names; an uphill draw does not count as a downhill."""
    line, vehicle = load_line(None), load_vehicle(None)
    standard = load_disturbances("standard")
    for st in line.stations:
        own = np.array([st.tasc.entry_speed_kmh])
        flat = np.zeros(1)
        assert not beyond_envelope(st, vehicle, own, flat, flat)[0]
        extreme = beyond_envelope(st, vehicle, np.array([65.0]), np.array([-20.0]), np.array([3.0]))
        assert bool(extreme[0]) == (envelope_note(st, vehicle, standard) is not None), st.name
        uphill = beyond_envelope(st, vehicle, np.array([65.0]), np.array([20.0]), np.array([3.0]))
        assert bool(uphill[0]) == (
            stopping_distance_m(st, vehicle, 65.0, 0.0) > st.tasc.detectors_before_stop_m[0]
        )
