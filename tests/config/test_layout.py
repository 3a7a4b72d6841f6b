"""Line layout (segments, fixed blocks, speed limits) and operation files: the data checks.

Every bad file ends in one ConfigError naming the file, the field and the value (DESIGN
rule 9); the CLI turns it into one line and exit code 2.
"""

from __future__ import annotations

import copy
import subprocess
import sys
import tomllib
from importlib import resources
from pathlib import Path
from typing import Any

import pytest

from railstop.config import default_line
from railstop.config.loader import validate
from railstop.config.operation import Operation, load_operation
from railstop.config.schema import Line
from railstop.errors import ConfigError

LINE_DATA: dict[str, Any] = tomllib.loads(
    resources.files("railstop.data").joinpath("line.toml").read_text(encoding="utf-8")
)


def _line(change: Any) -> Line:
    data = copy.deepcopy(LINE_DATA)
    change(data)
    return validate(Line, data, "test.toml")


def _fails(change: Any, field: str, words: str) -> ConfigError:
    with pytest.raises(ConfigError) as info:
        _line(change)
    err = info.value
    assert err.source == "test.toml"
    assert err.field == field, str(err)
    assert words in err.message, str(err)
    return err


# ---------------------------------------------------------------- the default line


def test_the_default_line_has_its_layout() -> None:
    line = default_line()
    segs = line.segments
    assert segs[0].start_m == 0.0 and segs[-1].end_m == line.line.length_m
    assert all(a.end_m == b.start_m for a, b in zip(segs, segs[1:], strict=False))
    assert len({s.id for s in segs}) == len(segs)
    assert line.signalling is not None
    covered = [c for b in line.signalling.blocks for c in b.circuits]
    assert covered == [c.id for c in line.track.circuits]  # every circuit once, in running order
    # Each station's platform is a block of its own (a train can close up behind a departing one).
    starts = {c.id: c.start_m for c in line.track.circuits}
    for st in line.stations:
        platform = [
            b
            for b in line.signalling.blocks
            if len(b.circuits) == 1 and starts[b.circuits[0]] < st.stop_point_m
        ][-1]
        assert st.platform_start <= starts[platform.circuits[0]] + 1.0
    assert line.speed_limits[0].limit_kmh < line.line.speed_limit_kmh


# ---------------------------------------------------------------- segments


def test_segments_must_be_contiguous() -> None:
    def gap(d: dict[str, Any]) -> None:
        d["segments"][3]["start_m"] = 310.0

    err = _fails(gap, "segments[3].start_m", "leaves a gap")
    assert err.value == 310.0

    def overlap(d: dict[str, Any]) -> None:
        d["segments"][3]["start_m"] = 290.0

    _fails(overlap, "segments[3].start_m", "overlaps")


def test_segments_start_at_zero_and_reach_the_end() -> None:
    def late(d: dict[str, Any]) -> None:
        d["segments"] = d["segments"][1:]

    _fails(late, "segments[0].start_m", "chainage 0")

    def short(d: dict[str, Any]) -> None:
        d["segments"] = d["segments"][:-1]

    _fails(short, f"segments[{len(LINE_DATA['segments']) - 2}].end_m", "line's end")


def test_segment_ids_are_unique_and_16_bit() -> None:
    def dup(d: dict[str, Any]) -> None:
        d["segments"][5]["id"] = 1

    err = _fails(dup, "segments[5].id", "unique")
    assert err.value == 1

    def big(d: dict[str, Any]) -> None:
        d["segments"][5]["id"] = 70000

    _fails(big, "segments[5].id", "less than or equal to 65535")


def test_a_segment_must_not_be_empty() -> None:
    def empty(d: dict[str, Any]) -> None:
        d["segments"][0]["end_m"] = 0.0

    _fails(empty, "segments[0].end_m", "greater than start_m")


# ---------------------------------------------------------------- blocks


def test_a_block_of_an_unknown_circuit_is_refused() -> None:
    def unknown(d: dict[str, Any]) -> None:
        d["signalling"]["blocks"][0]["circuits"] = [101, 999]

    err = _fails(unknown, "signalling.blocks[0].circuits[1]", "no track circuit 999")
    assert err.value == 999


def test_blocks_take_the_circuits_in_running_order() -> None:
    def swapped(d: dict[str, Any]) -> None:
        d["signalling"]["blocks"][0]["circuits"] = [102, 101]

    _fails(swapped, "signalling.blocks[0].circuits[0]", "running order")

    def missing(d: dict[str, Any]) -> None:
        d["signalling"]["blocks"] = d["signalling"]["blocks"][:-1]

    _fails(missing, "signalling.blocks", "every track circuit")


def test_block_ids_and_signals_are_unique() -> None:
    def dup_id(d: dict[str, Any]) -> None:
        d["signalling"]["blocks"][1]["id"] = "B01"

    _fails(dup_id, "signalling.blocks[1].id", "unique")

    def dup_signal(d: dict[str, Any]) -> None:
        d["signalling"]["blocks"][1]["signal"] = "S01"

    _fails(dup_signal, "signalling.blocks[1].signal", "unique")


def test_unknown_keys_in_the_signalling_are_refused() -> None:
    def typo(d: dict[str, Any]) -> None:
        d["signalling"]["overlapp_m"] = 50.0

    _fails(typo, "signalling.overlapp_m", "unknown key")


# ---------------------------------------------------------------- speed limits


def test_speed_limits_on_the_line_not_overlapping() -> None:
    def off(d: dict[str, Any]) -> None:
        d["speed_limits"][0]["end_m"] = 6000.0

    _fails(off, "speed_limits[0]", "not on the line")

    def overlap(d: dict[str, Any]) -> None:
        d["speed_limits"].append({"start_m": 3300.0, "end_m": 3500.0, "limit_kmh": 50.0})

    _fails(overlap, "speed_limits[1].start_m", "overlap")


def test_a_line_without_layout_still_loads() -> None:
    def bare(d: dict[str, Any]) -> None:
        del d["segments"], d["signalling"], d["speed_limits"]

    line = _line(bare)
    assert line.segments == [] and line.signalling is None and line.speed_limits == []


# ---------------------------------------------------------------- operation


def _op(tmp_path: Path, text: str) -> Operation:
    path = tmp_path / "op.toml"
    path.write_text(text, encoding="utf-8")
    return load_operation(path, default_line())


def test_the_default_operation() -> None:
    op = load_operation(None, default_line())
    assert op.trains == 12 and op.headway_s == 120.0 and op.controller == "tasc-pwm"
    assert op.entry_times_s() == [120.0 * k for k in range(12)]
    assert op.dwell_at_s("Hillcrest") == 40.0 and op.dwell_at_s("Museum") == 30.0


def test_a_timetable_replaces_the_headway(tmp_path: Path) -> None:
    op = _op(tmp_path, "trains = 3\nentries_s = [0.0, 90.0, 300.0]\n")
    assert op.entry_times_s() == [0.0, 90.0, 300.0]


@pytest.mark.parametrize(
    ("text", "field", "words", "value"),
    [
        ("trains = 3\nentries_s = [0.0, 100.0]\n", "entries_s", "one entry time per train", [0.0, 100.0]),
        ("trains = 2\nentries_s = [100.0, 50.0]\n", "entries_s", "must increase", [100.0, 50.0]),
        (
            'stations = [{ name = "Nowhere", dwell_s = 20.0 }]\n',
            "stations[0].name",
            "no such station",
            "Nowhere",
        ),
        (
            'stations = [{ name = "Museum", dwell_s = 20.0 }, { name = "Museum", dwell_s = 25.0 }]\n',
            "stations[1].name",
            "twice",
            "Museum",
        ),
        (
            # Station names match in any case: the second dwell would be silently ignored.
            'stations = [{ name = "Museum", dwell_s = 20.0 }, { name = "museum", dwell_s = 25.0 }]\n',
            "stations[1].name",
            "given twice: also stations[0] 'Museum' (names match in any case)",
            "museum",
        ),
        ("headway_s = 10\n", "headway_s", "greater than or equal to 30", 10),
        ("trainz = 3\n", "trainz", "unknown key", None),
        ('controller = "magic"\n', "controller", "unknown controller", "magic"),
        ("entry_m = 1100.0\n", "entry_m", "before the first station's platform", 1100.0),
        ("entry_speed_kmh = 95.0\n", "entry_speed_kmh", "speed limit", 95.0),
        ("dwell_s = 2.0\n", "dwell_s", "greater than or equal to 5", 2.0),
    ],
)
def test_a_bad_operation_file_names_field_and_value(
    tmp_path: Path, text: str, field: str, words: str, value: object
) -> None:
    with pytest.raises(ConfigError) as info:
        _op(tmp_path, text)
    err = info.value
    assert err.source == str(tmp_path / "op.toml")
    assert err.field == field, str(err)
    assert words in err.message, str(err)
    if value is not None:
        assert err.value == value


def test_check_validates_the_operation_file(tmp_path: Path) -> None:
    good = subprocess.run(
        [str(Path(sys.executable).with_name("railstop")), "check"],
        capture_output=True,
        text=True,
        check=False,
    )
    assert good.returncode == 0, good.stderr
    assert "58 segments, 20 blocks" in good.stdout and "operation: 12 trains every 120 s" in good.stdout
    bad = tmp_path / "op.toml"
    bad.write_text("trains = 0\n", encoding="utf-8")
    p = subprocess.run(
        [str(Path(sys.executable).with_name("railstop")), "check", "--operation", str(bad)],
        capture_output=True,
        text=True,
        check=False,
    )
    assert p.returncode == 2
    lines = (p.stdout + p.stderr).strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in p.stderr
    assert f"{bad}: trains:" in lines[0] and "(got 0)" in lines[0]
