"""Config schemas, TOML loaders and the error hierarchy.

The data files are what a railway engineer edits (DESIGN rule 3). A bad file
must be rejected with a message the engineer can act on without reading the
code (DESIGN rule 6): one line naming the file, the field and the bad value.
The default data must describe the system of SPEC §1 (five wheel sensors per
station, a 7-step notch table, a 6-car ~120 m metro EMU).
"""

from __future__ import annotations

import itertools
import math
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from railstop.config import default_line, default_vehicle, load_line, load_vehicle
from railstop.config.loader import format_loc
from railstop.errors import ConfigError, RailstopError

# --------------------------------------------------------------------------
# Minimal valid files, written in the test so that the bad-file cases do not
# depend on the embedded data. Station "Beta" has no Doppler radar: it is the
# SPEC §1 variant 2 (detectors only).
BASE_LINE = """\
[line]
name = "test line"
speed_limit_kmh = 80.0

[[stations]]
name = "Alpha"
stop_point_m = 1000.0
platform_length_m = 130.0
platform_side = "R"
[stations.tasc]
entry_speed_kmh = 60.0
detectors_before_stop_m = [220.0, 150.0, 90.0, 40.0, 6.0]
doppler = { beyond_stop_m = 10.0, sample_period_s = 0.01 }

[[stations]]
name = "Beta"
stop_point_m = 3000.0
platform_length_m = 130.0
platform_side = "L"
[stations.tasc]
entry_speed_kmh = 55.0
detectors_before_stop_m = [250.0, 190.0, 120.0, 55.0, 6.0]
"""

BASE_VEHICLE = """\
[vehicle]
name = "test EMU"
cars = 6
length_m = 120.0
tare_mass_kg = 200000.0
crush_payload_kg = 110000.0
rotating_mass_factor = 0.08
davis_a_n = 2900.0
davis_b_n_per_mps = 120.0
davis_c_n_per_mps2 = 8.0
wheel_diameter_m = 0.82
adhesion_mu = 0.20

[vehicle.brake]
notch_decel_mps2 = [0.143, 0.286, 0.429, 0.571, 0.714, 0.857, 1.0]
emergency_decel_mps2 = 1.3
pwm_duty = [0.0, 0.1, 0.9, 1.0]
pwm_decel_mps2 = [0.0, 0.0, 1.0, 1.0]
dead_time_s = 0.35
time_constant_s = 0.45
jerk_limit_mps3 = 1.0
"""

# SPEC "typical values": full service brake ~ 1.0 m/s², emergency ~ 1.3 m/s²,
# crush load adds ~ 55 % of tare, dead time 0.2-0.6 s, lag 0.3-0.6 s,
# wheel diameter 780-860 mm.
FULL_SERVICE_MPS2 = 1.0


def _edit(base: str, old: str, new: str) -> str:
    # Guard against a silent no-op replace: the bad case would then be a valid file.
    assert base.count(old) >= 1, f"test fixture does not contain {old!r}"
    return base.replace(old, new, 1)


def _write(tmp_path: Path, text: str, name: str = "bad.toml") -> Path:
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


def _assert_one_line(err: ConfigError, path: Path, field: str) -> str:
    # DESIGN rule 6 / errors.py: ``file: field.path: message (got value)`` on one line.
    text = str(err)
    assert "\n" not in text
    assert str(path) in text
    assert field in text
    assert text.startswith(f"{path}: {field}: ")
    return text


# --------------------------------------------------------------------------
# Error hierarchy


def test_config_error_is_value_error_and_railstop_error() -> None:
    # Callers that only know ValueError (e.g. argument parsing) must catch it,
    # and callers that catch the package's own base class must catch it too.
    assert issubclass(ConfigError, ValueError)
    assert issubclass(ConfigError, RailstopError)
    err = ConfigError("f.toml", "a.b", "bad", 3)
    assert isinstance(err, ValueError)
    assert isinstance(err, RailstopError)


def test_config_error_message_format() -> None:
    err = ConfigError("line.toml", "stations[2].tasc.x", "must be positive", -1.5)
    assert str(err) == "line.toml: stations[2].tasc.x: must be positive (got -1.5)"
    assert (err.source, err.field, err.message, err.value) == (
        "line.toml",
        "stations[2].tasc.x",
        "must be positive",
        -1.5,
    )
    # No value: no "(got ...)" suffix.
    assert str(ConfigError("f", "g", "m")) == "f: g: m"


def test_config_error_caps_a_long_value() -> None:
    # A whole list (of track circuits, say) is never quoted whole: the line stays readable.
    circuits = [{"id": i, "start_m": 100.0 * i, "end_m": 100.0 * (i + 1)} for i in range(60)]
    text = str(ConfigError("line.toml", "track.circuits", "bad", circuits))
    assert len(text) < 250 and "60 items in all" in text and "\n" not in text


def test_format_loc_matches_toml_paths() -> None:
    # The path printed must be the one the engineer navigates in the file.
    assert format_loc(("stations", 1, "tasc", "x")) == "stations[1].tasc.x"
    assert format_loc(("a", 0, 3)) == "a[0][3]"
    assert format_loc(()) == "(top level)"


# --------------------------------------------------------------------------
# Default data satisfy SPEC §1 and the issue


def test_default_line_stations_and_detectors() -> None:
    line = default_line()
    # At least three stations so that campaigns can vary the site.
    assert len(line.stations) >= 3
    names = [s.name for s in line.stations]
    assert len(set(names)) == len(names)
    stops = [s.stop_point_m for s in line.stations]
    assert stops == sorted(stops)
    for st in line.stations:
        d = st.tasc.detectors_before_stop_m
        # SPEC §1 embodiment: five detectors, wheel sensors preferred, listed
        # farthest first (distances before the stop strictly decreasing).
        assert len(d) == 5, st.name
        assert st.tasc.detector_kind == "wheel-sensor", st.name
        assert all(a > b for a, b in itertools.pairwise(d)), st.name
        assert all(x > 0 for x in d), st.name
        # The chainages go the other way: the train (running +x) meets them in order.
        pos = st.detector_positions_m()
        assert all(a < b < st.stop_point_m for a, b in itertools.pairwise(pos))
        # Variant 2 (no Doppler) needs >= 3 detectors.
        assert st.tasc.doppler is not None or len(d) >= 3


def test_default_line_first_command_leaves_room_to_stop() -> None:
    # Physics sanity of the layout: at the detector where the first command
    # can be issued (the first one with a Doppler radar, the second one with
    # detectors only, as a speed needs two passages), a train at the entry
    # speed must still be able to stop at full service after the brake's
    # dead time: d >= v * t_dead + v² / (2 a_B7).
    line = default_line()
    veh = default_vehicle()
    for st in line.stations:
        v = st.tasc.entry_speed_kmh / 3.6
        need = v * veh.brake.dead_time_s + v * v / (2.0 * veh.brake.full_service_mps2)
        first = st.tasc.detectors_before_stop_m[0 if st.tasc.doppler else 1]
        assert first >= need, (st.name, first, need)


def test_default_vehicle_matches_spec_typical_values() -> None:
    veh = default_vehicle()
    assert veh.cars == 6
    assert veh.length_m == pytest.approx(120.0, rel=0.1)
    notches = veh.brake.notch_decel_mps2
    # SPEC §1 fig. 3: 3 wires carry exactly 7 service steps B1..B7.
    assert len(notches) == 7
    assert all(b > a for a, b in itertools.pairwise(notches))
    assert notches[-1] == pytest.approx(FULL_SERVICE_MPS2, abs=0.05)
    assert veh.brake.full_service_mps2 == notches[-1]
    assert veh.brake.emergency_decel_mps2 == pytest.approx(1.3, abs=0.15)
    assert veh.brake.emergency_decel_mps2 >= notches[-1]
    assert 0.2 <= veh.brake.dead_time_s <= 0.6
    assert 0.3 <= veh.brake.time_constant_s <= 0.6
    assert 0.45 <= veh.crush_payload_kg / veh.tare_mass_kg <= 0.65
    assert 0.78 <= veh.wheel_diameter_m <= 0.86
    # The PWM map must span released .. full service so that PWM control
    # (SPEC §1 config 2/3) can ask for any service deceleration.
    assert min(veh.brake.pwm_decel_mps2) == 0.0
    assert max(veh.brake.pwm_decel_mps2) == pytest.approx(notches[-1])


def test_base_fixtures_are_valid(tmp_path: Path) -> None:
    # Each bad case below differs from these files by one edit, so they must load.
    line = load_line(_write(tmp_path, BASE_LINE, "line.toml"))
    assert [s.name for s in line.stations] == ["Alpha", "Beta"]
    veh = load_vehicle(_write(tmp_path, BASE_VEHICLE, "vehicle.toml"))
    assert veh.cars == 6
    # Accepts str as well as Path.
    assert load_line(str(tmp_path / "line.toml")) == line


def test_two_detectors_with_doppler_is_accepted(tmp_path: Path) -> None:
    # SPEC §1 variant 1: >= 2 detectors are enough when a Doppler radar
    # measures the speed; only variant 2 needs 3.
    text = _edit(BASE_LINE, "[220.0, 150.0, 90.0, 40.0, 6.0]", "[220.0, 40.0]")
    line = load_line(_write(tmp_path, text))
    assert line.stations[0].tasc.detectors_before_stop_m == [220.0, 40.0]


# --------------------------------------------------------------------------
# Bad files

LINE_CASES = [
    pytest.param(
        'platform_side = "R"\n',
        'platform_side = "R"\nplatform_colour = "red"\n',
        "stations[0].platform_colour",
        None,
        "unknown key",
        id="unknown-key",
    ),
    pytest.param(
        "[line]\n",
        '[line]\nowner = "someone"\n',
        "line.owner",
        None,
        "unknown key",
        id="unknown-key-line",
    ),
    pytest.param(
        "platform_length_m = 130.0",
        'platform_length_m = "long"',
        "stations[0].platform_length_m",
        "'long'",
        "number",
        id="wrong-type",
    ),
    pytest.param(
        "entry_speed_kmh = 60.0",
        "entry_speed_kmh = 500.0",
        "stations[0].tasc.entry_speed_kmh",
        "500.0",
        "120",
        id="out-of-range",
    ),
    pytest.param(
        'platform_side = "R"',
        'platform_side = "X"',
        "stations[0].platform_side",
        "'X'",
        "",
        id="bad-literal",
    ),
    pytest.param(
        "[220.0, 150.0, 90.0, 40.0, 6.0]",
        "[220.0, 150.0, 160.0, 40.0, 6.0]",
        "stations[0].tasc.detectors_before_stop_m",
        "[220.0, 150.0, 160.0, 40.0, 6.0]",
        "decreasing",
        id="detectors-not-decreasing",
    ),
    pytest.param(
        "[220.0, 150.0, 90.0, 40.0, 6.0]",
        "[220.0, 150.0, 90.0, 40.0, -6.0]",
        "stations[0].tasc.detectors_before_stop_m[4]",
        "-6.0",
        "greater than 0",
        id="detector-negative",
    ),
]


@pytest.mark.parametrize(("old", "new", "field", "value", "words"), LINE_CASES)
def test_bad_line_file(tmp_path: Path, old: str, new: str, field: str, value: str | None, words: str) -> None:
    path = _write(tmp_path, _edit(BASE_LINE, old, new))
    with pytest.raises(ConfigError) as info:
        load_line(path)
    text = _assert_one_line(info.value, path, field)
    assert info.value.field == field
    assert info.value.source == str(path)
    assert words in text
    if value is not None:
        # The bad value is quoted so the engineer sees what the loader read.
        assert f"(got {value})" in text


def test_detectors_only_station_with_two_detectors(tmp_path: Path) -> None:
    # SPEC §1 variant 2: without a Doppler radar the speed and the
    # deceleration come from passage times, which needs >= 3 detectors.
    path = _write(tmp_path, _edit(BASE_LINE, "[250.0, 190.0, 120.0, 55.0, 6.0]", "[250.0, 190.0]"))
    with pytest.raises(ConfigError) as info:
        load_line(path)
    text = _assert_one_line(info.value, path, "stations[1].tasc.detectors_before_stop_m")
    assert "3 detectors" in text


def test_detectors_only_station_names_field_and_value(tmp_path: Path) -> None:
    # DESIGN rule 6: the message names the field and the bad value.
    path = _write(tmp_path, _edit(BASE_LINE, "[250.0, 190.0, 120.0, 55.0, 6.0]", "[250.0, 190.0]"))
    with pytest.raises(ConfigError) as info:
        load_line(path)
    text = _assert_one_line(info.value, path, "stations[1].tasc.detectors_before_stop_m")
    assert "(got [250.0, 190.0])" in text


def test_toml_syntax_error(tmp_path: Path) -> None:
    path = _write(tmp_path, _edit(BASE_LINE, "[line]", "[line"))
    with pytest.raises(ConfigError) as info:
        load_line(path)
    text = _assert_one_line(info.value, path, "(toml syntax)")
    # The parser's position lets the engineer find the typo.
    assert "line 1" in text


def test_missing_file(tmp_path: Path) -> None:
    path = tmp_path / "nowhere" / "line.toml"
    with pytest.raises(ConfigError) as info:
        load_line(path)
    text = _assert_one_line(info.value, path, "(file)")
    assert "no such file" in text
    with pytest.raises(ConfigError):
        load_vehicle(path)


def test_not_utf8_file(tmp_path: Path) -> None:
    path = tmp_path / "latin1.toml"
    path.write_bytes(BASE_LINE.replace("test line", "l\xedne").encode("latin-1"))
    with pytest.raises(ConfigError) as info:
        load_line(path)
    _assert_one_line(info.value, path, "(file)")


VEHICLE_CASES = [
    pytest.param(
        "cars = 6",
        'cars = "six"',
        "vehicle.cars",
        "'six'",
        "integer",
        id="wrong-type",
    ),
    pytest.param(
        "wheel_diameter_m = 0.82",
        "wheel_diameter_m = 8.2",
        "vehicle.wheel_diameter_m",
        "8.2",
        "less than 1.2",
        id="out-of-range",
    ),
    pytest.param(
        "adhesion_mu = 0.20",
        "adhesion_mu = 0.20\nadhesion_nu = 0.1",
        "vehicle.adhesion_nu",
        None,
        "unknown key",
        id="unknown-key",
    ),
    pytest.param(
        # SPEC §1 fig. 3: 7 steps, not 6.
        "[0.143, 0.286, 0.429, 0.571, 0.714, 0.857, 1.0]",
        "[0.143, 0.286, 0.429, 0.571, 0.714, 1.0]",
        "vehicle.brake.notch_decel_mps2",
        "[0.143, 0.286, 0.429, 0.571, 0.714, 1.0]",
        "7 notches",
        id="six-notches",
    ),
    pytest.param(
        "[0.143, 0.286, 0.429, 0.571, 0.714, 0.857, 1.0]",
        "[0.143, 0.286, 0.429, 0.571, 0.900, 0.857, 1.0]",
        "vehicle.brake.notch_decel_mps2",
        "[0.143, 0.286, 0.429, 0.571, 0.9, 0.857, 1.0]",
        "increase",
        id="notches-not-increasing",
    ),
    pytest.param(
        "dead_time_s = 0.35",
        "dead_time_s = nan",
        "vehicle.brake.dead_time_s",
        None,
        "",
        id="nan",
    ),
]


@pytest.mark.parametrize(("old", "new", "field", "value", "words"), VEHICLE_CASES)
def test_bad_vehicle_file(
    tmp_path: Path, old: str, new: str, field: str, value: str | None, words: str
) -> None:
    path = _write(tmp_path, _edit(BASE_VEHICLE, old, new))
    with pytest.raises(ConfigError) as info:
        load_vehicle(path)
    text = _assert_one_line(info.value, path, field)
    assert words in text
    if value is not None:
        assert f"(got {value})" in text


def test_nan_value_is_quoted(tmp_path: Path) -> None:
    path = _write(tmp_path, _edit(BASE_VEHICLE, "dead_time_s = 0.35", "dead_time_s = nan"))
    with pytest.raises(ConfigError) as info:
        load_vehicle(path)
    assert isinstance(info.value.value, float)
    assert math.isnan(info.value.value)


# --------------------------------------------------------------------------
# Physically impossible or inconsistent data (the embedded files with one edit): refused at load,
# and by `railstop check`, with one line naming the file, the field and the value, exit code 2.

EMBEDDED_LINE = (Path(__file__).resolve().parents[2] / "src" / "railstop" / "data" / "line.toml").read_text(
    encoding="utf-8"
)
EMBEDDED_VEHICLE = (
    Path(__file__).resolve().parents[2] / "src" / "railstop" / "data" / "vehicle.toml"
).read_text(encoding="utf-8")
RIVERSIDE_DOPPLER = "doppler = { beyond_stop_m = 10.0, sample_period_s = 0.01 }"  # the first station's

# (old, new, field, value, words): one rule each.
PHYSICAL_LINE_CASES = [
    pytest.param(
        # Hillcrest (the second station) moved before Riverside's stop at 1200 m.
        "stop_point_m = 2650.0\n",
        "stop_point_m = 1150.0\n",
        "stations[1].stop_point_m",
        "1150.0",
        "before the previous station 'Riverside' (stations[0].stop_point_m = 1200 m)",
        id="stations-out-of-order",
    ),
    pytest.param(
        # A platform length typed in mm: refused on the station's field, not on the track circuits.
        "stop_point_m = 1200.0\nplatform_length_m = 130.0",
        "stop_point_m = 1200.0\nplatform_length_m = 140000.0",
        "stations[0].platform_length_m",
        "140000.0",
        "less than or equal to 1000",
        id="platform-length-in-mm",
    ),
    pytest.param(
        "stop_point_m = 1200.0\n",
        "stop_point_m = -50.0\n",
        "stations[0].stop_point_m",
        "-50.0",
        "the stopping point of station 'Riverside' is off the line",
        id="stop-point-before-line-start",
    ),
    pytest.param(
        # A platform that fits its bound but reaches back past the line's start.
        "stop_point_m = 1200.0\nplatform_length_m = 130.0",
        "stop_point_m = 100.0\nplatform_length_m = 300.0",
        "stations[0].platform_length_m",
        "300.0",
        "platform -195 .. 105 m starts before the line's start",
        id="platform-before-line-start",
    ),
    pytest.param(
        # Riverside stops at 1200 m; a platform 1270 .. 1400 m leaves the stop before its start.
        "stop_point_m = 1200.0\n",
        "stop_point_m = 1200.0\nplatform_end_m = 1400.0\n",
        "stations[0].stop_point_m",
        "1200.0",
        "before the platform's start at 1270 m",
        id="stop-before-platform-start",
    ),
    pytest.param(
        # A platform ending at the stopping point: a stop within the tolerance passes its end.
        "stop_point_m = 1200.0\n",
        "stop_point_m = 1200.0\nplatform_end_m = 1200.0\n",
        "stations[0].platform_end_m",
        "1200.0",
        "at least psd_tolerance_m (0.35 m)",
        id="platform-end-at-stop",
    ),
    pytest.param(
        "stop_point_m = 1200.0\n",
        "stop_point_m = 1200.0\nplatform_end_m = 1200.2\n",
        "stations[0].platform_end_m",
        "1200.2",
        "at least psd_tolerance_m (0.35 m)",
        id="platform-end-within-tolerance",
    ),
    pytest.param(
        # Riverside's first detector is 330 m before the stop, the radar 10 m past it: 340 m.
        RIVERSIDE_DOPPLER,
        "doppler = { beyond_stop_m = 10.0, sample_period_s = 0.01, range_m = 300.0 }",
        "stations[0].tasc.doppler.range_m",
        "300.0",
        "range_m must be at least 340 m",
        id="doppler-range-short-of-first-detector",
    ),
    pytest.param(
        RIVERSIDE_DOPPLER,
        "doppler = { beyond_stop_m = 10.0, sample_period_s = 0.02 }",
        "stations[0].tasc.doppler.sample_period_s",
        "0.02",
        "must equal the simulation step 0.01 s",
        id="doppler-sample-period-not-the-step",
    ),
    pytest.param(
        # Riverside's last segment reaching to 2200 m overlaps Hillcrest's 2150 .. 2525 m.
        "{ start_m = 1075.0, end_m = 1260.0, permille = 0.0 }",
        "{ start_m = 1075.0, end_m = 2200.0, permille = 0.0 }",
        "stations[1].gradient[0].start_m",
        "2150.0",
        "2150 .. 2525 m of station 'Hillcrest' overlaps the segment 1075 .. 2200 m of station "
        "'Riverside' over 2150 .. 2200 m",
        id="gradients-of-two-stations-overlap",
    ),
]

PHYSICAL_VEHICLE_CASES = [
    pytest.param(
        # A PWM map that never brakes harder than 0.2 m/s² while B7 gives 1.0 m/s².
        "pwm_decel_mps2 = [0.0, 0.0, 1.0, 1.0]",
        "pwm_decel_mps2 = [0, 0, 0.2, 0.2]",
        "vehicle.brake.pwm_decel_mps2",
        "[0, 0, 0.2, 0.2]",
        "largest deceleration 0.2 m/s² falls short of full service (notch_decel_mps2 B7 = 1 m/s²)",
        id="pwm-map-short-of-full-service",
    ),
    pytest.param(
        "adhesion_mu = 0.20",
        "adhesion_mu = 0.02",
        "vehicle.adhesion_mu",
        "0.02",
        "greater than or equal to 0.1",
        id="adhesion-below-wet-rail",
    ),
    pytest.param(
        # Davis A is 2900 N: 2000 N of tractive effort never starts the train.
        "max_force_n = 320000.0",
        "max_force_n = 2000.0",
        "vehicle.traction.max_force_n",
        "2000.0",
        "davis_a_n (2900 N): the train could never start",
        id="traction-below-standstill-resistance",
    ),
    pytest.param(
        "jerk_limit_mps3 = 1.0",
        "jerk_limit_mps3 = 0.05",
        "vehicle.brake.jerk_limit_mps3",
        "0.05",
        "greater than or equal to 0.1",
        id="jerk-limit-below-0.1",
    ),
    pytest.param(
        "crush_payload_kg = 110000.0",
        "crush_payload_kg = 300000.0",
        "vehicle.crush_payload_kg",
        "300000.0",
        "50 t per car for 6 cars: a crush-loaded car carries at most 40 t",
        id="crush-payload-above-40-t-a-car",
    ),
]


def _railstop(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [str(Path(sys.executable).with_name("railstop")), *args], capture_output=True, text=True, check=False
    )


def test_embedded_data_meet_the_physical_rules() -> None:
    # Each rule below, on the embedded data: they pass, and `railstop check` says ok.
    line, veh = default_line(), default_vehicle()
    for st in line.stations:
        assert st.platform_start <= st.stop_point_m <= st.platform_end, st.name
        assert st.platform_end - st.stop_point_m >= st.psd_tolerance_m, st.name
        radar = st.tasc.doppler
        assert radar is not None, st.name
        assert radar.beyond_stop_m + st.tasc.detectors_before_stop_m[0] <= radar.range_m, st.name
        assert radar.sample_period_s == 0.01, st.name
    segs = sorted((g.start_m, g.end_m) for st in line.stations for g in st.gradient)
    assert all(a[1] <= b[0] for a, b in itertools.pairwise(segs))
    assert veh.adhesion_mu >= 0.1
    assert veh.traction is not None and veh.traction.max_force_n > veh.davis_a_n
    assert veh.brake.jerk_limit_mps3 >= 0.1
    assert veh.crush_payload_kg / veh.cars <= 40_000.0
    ok = _railstop("check")
    assert ok.returncode == 0, ok.stdout + ok.stderr
    assert ok.stdout.startswith("ok: embedded default line")


@pytest.mark.parametrize(
    ("kind", "old", "new", "field", "value", "words"),
    [
        pytest.param(kind, *case.values, id=case.id)
        for kind, cases in (("line", PHYSICAL_LINE_CASES), ("vehicle", PHYSICAL_VEHICLE_CASES))
        for case in cases
    ],
)
def test_physically_impossible_data_is_refused(
    tmp_path: Path, kind: str, old: str, new: str, field: str, value: str, words: str
) -> None:
    """A line whose data contradict each other, a vehicle that is no train: one line naming the
    file, the field and the value."""
    embedded, load = {"line": (EMBEDDED_LINE, load_line), "vehicle": (EMBEDDED_VEHICLE, load_vehicle)}[kind]
    path = _write(tmp_path, _edit(embedded, old, new), f"{kind}.toml")
    with pytest.raises(ConfigError) as info:
        load(path)
    text = _assert_one_line(info.value, path, field)
    assert words in text and f"(got {value})" in text, text


@pytest.mark.parametrize(
    ("option", "base", "case"),
    [("--line", EMBEDDED_LINE, c) for c in PHYSICAL_LINE_CASES]
    + [("--vehicle", EMBEDDED_VEHICLE, c) for c in PHYSICAL_VEHICLE_CASES],
    ids=[str(c.id) for c in PHYSICAL_LINE_CASES + PHYSICAL_VEHICLE_CASES],
)
def test_check_refuses_physically_bad_data_in_one_line(
    tmp_path: Path, option: str, base: str, case: Any
) -> None:
    # The promise: exit code 2 and one line naming the file, the field and the value, no traceback.
    old, new, field, value, words = case.values
    path = _write(tmp_path, _edit(base, old, new), "bad.toml")
    p = _railstop("check", option, str(path))
    assert p.returncode == 2, p.stdout + p.stderr
    lines = (p.stdout + p.stderr).strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in p.stderr, lines
    assert f"{path}: {field}: " in lines[0] and f"(got {value})" in lines[0] and words in lines[0], lines[0]


@pytest.mark.parametrize(
    ("base", "old", "new"),
    [
        # At each bound the data are accepted: a platform ending psd_tolerance_m past the stop, the
        # stop at the platform's start, a radar whose range just reaches the first detector, two
        # stations' segments that meet, wet-rail adhesion, the least jerk limit, 40 t a car, and a
        # traction just above the standstill resistance.
        (EMBEDDED_LINE, "stop_point_m = 1200.0\n", "stop_point_m = 1200.0\nplatform_end_m = 1200.35\n"),
        (EMBEDDED_LINE, "stop_point_m = 1200.0\n", "stop_point_m = 1200.0\nplatform_end_m = 1330.0\n"),
        (
            EMBEDDED_VEHICLE,
            "pwm_decel_mps2 = [0.0, 0.0, 1.0, 1.0]",
            "pwm_decel_mps2 = [0.0, 0.0, 0.98, 0.98]",
        ),
        (EMBEDDED_LINE, RIVERSIDE_DOPPLER, "doppler = { beyond_stop_m = 10.0, range_m = 340.0 }"),
        (
            EMBEDDED_LINE,
            "{ start_m = 1075.0, end_m = 1260.0, permille = 0.0 }",
            "{ start_m = 1075.0, end_m = 2150.0, permille = 0.0 }",
        ),
        (EMBEDDED_VEHICLE, "adhesion_mu = 0.20", "adhesion_mu = 0.1"),
        (EMBEDDED_VEHICLE, "jerk_limit_mps3 = 1.0", "jerk_limit_mps3 = 0.1"),
        (EMBEDDED_VEHICLE, "crush_payload_kg = 110000.0", "crush_payload_kg = 240000.0"),
        (EMBEDDED_VEHICLE, "max_force_n = 320000.0", "max_force_n = 2901.0"),
    ],
)
def test_physical_rules_accept_their_bounds(tmp_path: Path, base: str, old: str, new: str) -> None:
    path = _write(tmp_path, _edit(base, old, new), "ok.toml")
    if base is EMBEDDED_LINE:
        load_line(path)
    else:
        load_vehicle(path)
