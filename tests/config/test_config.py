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
from pathlib import Path

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
