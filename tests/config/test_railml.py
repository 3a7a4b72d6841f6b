"""railML import (issue 38 item 3): railML 2.x and 3.x files of our own making into line files.

The two files in tests/data/railml describe the same two-station line, one in railML 2.3 (tracks
with pos) and one in railML 3.1 (net elements, pos and linear-coordinate measures): both readers
must give the same line. The round trip runs the real command: import, `railstop check`, a stop.
"""

from __future__ import annotations

import subprocess
import tomllib
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bad_inputs import RAILML_HEAD, RAILML_TAIL, railml_track
from railstop.config.loader import default_vehicle, load_line
from railstop.config.plausibility import stopping_distance_m
from railstop.config.railml import detector_layout, import_railml, to_toml
from railstop.config.schema import Station
from railstop.errors import ConfigError
from zygote import run_cli

DATA = Path(__file__).parents[1] / "data" / "railml"
V2 = DATA / "two-stations-2.xml"
V3 = DATA / "two-stations-3.xml"


def run(*args: str, cwd: Path, timeout: float = 120.0) -> subprocess.CompletedProcess[str]:
    return run_cli(*args, cwd=cwd, timeout=timeout)  # forked from a warm zygote (tests/zygote.py)


def one_error(r: subprocess.CompletedProcess[str], *needles: str) -> str:
    assert r.returncode == 2, (r.returncode, r.stdout, r.stderr)
    lines = r.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), r.stderr
    for n in needles:
        assert n in lines[0], (n, lines[0])
    return lines[0]


@pytest.fixture(scope="module")
def both() -> tuple[dict, dict, list[str], list[str]]:
    veh = default_vehicle()
    a = import_railml(V2, veh, tracks=["t1", "t2"])
    b = import_railml(V3, veh, tracks=["trk1", "trk2"])
    return a.data, b.data, a.report, b.report


def test_railml_2_and_3_of_one_line_give_the_same_line(both: tuple[dict, dict, list[str], list[str]]) -> None:
    v2, v3, _, _ = both
    for key in ("stations", "segments", "speed_limits", "signalling"):
        assert v2[key] == v3[key], key
    assert v2["track"]["circuits"] == v3["track"]["circuits"]
    assert v2["line"]["length_m"] == v3["line"]["length_m"] == 3000.0
    # railML 2 has tunnels; railML 3 has no tunnel element the reader maps
    assert v2["track"]["tunnels"] == [{"start_m": 1200.0, "end_m": 1500.0, "name": "North cutting"}]
    assert v3["track"]["tunnels"] == []


def test_the_mapping_of_the_two_station_line(both: tuple[dict, dict, list[str], list[str]]) -> None:
    data, _, report, _ = both
    circuits = data["track"]["circuits"]
    starts = [c["start_m"] for c in circuits]
    # the line's start, 8 borders on t1 (from 0 m), 5 on t2 (from 1600 m) and the axle counter
    assert starts == [0, 200, 420, 650, 790, 865, 1005, 1100, 1300, 1600, 1900, 2200, 2465, 2605, 2800]
    insulated = [c["start_m"] for c in circuits if c["kind"] == "insulated"]
    assert insulated == [790, 865, 1005, 1100, 2465, 2605]  # the joints and the axle counter
    assert circuits[-1]["end_m"] == 3000.0
    blocks = data["signalling"]["blocks"]
    # entry block, then one per forward main signal snapped to the border after it
    assert [b["signal"] for b in blocks] == ["ENTRY", "N1", "N3", "N4", "N5", "S1", "S2", "S3"]
    first_circuit = {b["signal"]: b["circuits"][0] for b in blocks}
    by_id = {c["id"]: c["start_m"] for c in circuits}
    assert [by_id[first_circuit[s]] for s in ("N1", "N3", "N4", "N5", "S1", "S2", "S3")] == [
        200,
        650,
        865,
        1100,
        1600,
        2465,
        2800,
    ]
    north, south = data["stations"]
    assert (north["name"], north["stop_point_m"], north["platform_end_m"], north["platform_side"]) == (
        "Northgate",
        1000.0,
        1005.0,
        "R",
    )
    assert (south["name"], south["stop_point_m"], south["platform_side"]) == ("Southpark", 2600.0, "L")
    assert north["tasc"]["detectors_before_stop_m"] == [320.0, 225.0, 135.0, 55.0, 6.0]  # w1..w5
    assert north["gradient"] == [{"start_m": 400.0, "end_m": 880.0, "permille": -8.0}]
    assert south["gradient"] == [{"start_m": 1800.0, "end_m": 2500.0, "permille": 5.0}]
    assert data["speed_limits"] == [
        {"start_m": 1150.0, "end_m": 1700.0, "limit_kmh": 60.0, "reason": "railML speed section"}
    ]
    skipped = " ".join(r for r in report if r.startswith("not mapped"))
    for ident in ("'sc3'", "'sc4'", "'s2'", "'s3'", "'sp3'", "'sp1'"):
        assert ident in skipped, ident
    assert any("laid out by railstop" in r and "Southpark" in r for r in report)


def test_the_written_file_is_a_valid_line_with_the_report_as_its_head(tmp_path: Path) -> None:
    imported = import_railml(V3, default_vehicle(), tracks=["trk1", "trk2"])
    text = to_toml(imported, str(V3))
    path = tmp_path / "line.toml"
    path.write_text(text, encoding="utf-8")
    line = load_line(path)
    assert [s.name for s in line.stations] == ["Northgate", "Southpark"]
    head = [ln for ln in text.splitlines() if ln.startswith("#")]
    assert any("not mapped: signalIS 's3'" in ln for ln in head)
    assert any("101=(line start)" in ln for ln in head)
    assert tomllib.loads(text)["line"]["name"] == "Two-station test line"


@settings(max_examples=60, deadline=None)
@given(speed=st.floats(25.0, 90.0), grade=st.floats(-25.0, 25.0))
def test_a_laid_out_zone_is_long_enough_for_the_plausibility_check(speed: float, grade: float) -> None:
    veh = default_vehicle()
    detectors = detector_layout(veh, speed, grade)
    assert detectors == sorted(detectors, reverse=True) and detectors[-1] == 6.0
    station = Station.model_validate(
        {
            "name": "X",
            "stop_point_m": 2000.0,
            "platform_length_m": 130.0,
            "platform_side": "R",
            "gradient": [{"start_m": 1000.0, "end_m": 2000.0, "permille": grade}],
            "tasc": {"entry_speed_kmh": speed, "detectors_before_stop_m": detectors},
        }
    )
    assert stopping_distance_m(station, veh, speed) <= detectors[0]


def test_round_trip_import_check_and_a_stop(tmp_path: Path) -> None:
    r = run(
        "import", "railml", str(V2), "--track", "t1", "--track", "t2", "--out", "mine/line.toml", cwd=tmp_path
    )
    assert r.returncode == 0, r.stderr
    assert "not mapped: signal 's3'" in r.stdout and "next: railstop check --line mine/line.toml" in r.stdout
    r = run("check", "--line", "mine/line.toml", cwd=tmp_path)
    assert r.returncode == 0 and r.stdout.startswith("ok: mine/line.toml"), r.stderr
    for station in ("Northgate", "Southpark"):
        r = run(
            "stop", "--line", "mine/line.toml", "--station", station, "--no-db", cwd=tmp_path, timeout=300
        )
        assert r.returncode == 0, r.stderr
        assert f"tasc-pwm at {station}: stop error" in r.stdout
        assert "within the PSD tolerance" in r.stdout, r.stdout
    # never over an existing file: the second import is refused and the first file is untouched
    before = (tmp_path / "mine/line.toml").read_bytes()
    one_error(
        run("import", "railml", str(V2), "--track", "t1", "--out", "mine/line.toml", cwd=tmp_path),
        "mine/line.toml",
        "never overwrites",
    )
    assert (tmp_path / "mine/line.toml").read_bytes() == before


def _write(tmp_path: Path, name: str, text: str) -> Path:
    p = tmp_path / name
    p.write_text(text, encoding="utf-8")
    return p


# The small railML 2 texts of the bad-input sweep: a track of 500 m around a body.
V2_HEAD, V2_TAIL = RAILML_HEAD, RAILML_TAIL


EDGE = (
    '<trackElements><platformEdges><platformEdge id="pe" pos="300" length="130" side="right"/>'
    "</platformEdges>"
)


def _import(path: Path, **kw: object) -> None:
    import_railml(path, default_vehicle(), **kw)  # type: ignore[arg-type]


def test_bad_railml_is_one_error_naming_the_element_and_its_line(tmp_path: Path) -> None:
    bad_pos = _write(
        tmp_path,
        "a.xml",
        V2_HEAD
        + railml_track(
            EDGE
            + '</trackElements><ocsElements><signals><signal id="s1"\n pos="twelve"/></signals></ocsElements>'
        )
        + V2_TAIL,
    )
    with pytest.raises(ConfigError) as e:
        _import(bad_pos)
    assert "signal 's1' (line 2) @pos" in str(e.value) and "'twelve'" in str(e.value)
    outside = _write(
        tmp_path,
        "b.xml",
        V2_HEAD
        + railml_track(
            EDGE + '</trackElements><ocsElements><signals><signal id="s1" pos="900"/></signals></ocsElements>'
        )
        + V2_TAIL,
    )
    with pytest.raises(ConfigError, match=r"outside its track \(0 \.\. 500 m\)"):
        _import(outside)
    nan = _write(
        tmp_path,
        "c.xml",
        V2_HEAD
        + railml_track(
            '<trackElements><platformEdges><platformEdge id="pe" pos="300" length="nan"/></platformEdges>'
            "</trackElements>"
        )
        + V2_TAIL,
    )
    with pytest.raises(ConfigError, match="not a finite number"):
        _import(nan)
    two = _write(
        tmp_path,
        "d.xml",
        V2_HEAD + railml_track(EDGE + "</trackElements>") + railml_track("", "t2") + V2_TAIL,
    )
    with pytest.raises(ConfigError, match=r"2 tracks \(t1, t2\): name the ones"):
        _import(two)
    with pytest.raises(ConfigError, match="no such track"):
        _import(two, tracks=["t7"])
    no_station = _write(tmp_path, "e.xml", V2_HEAD + railml_track("") + V2_TAIL)
    with pytest.raises(ConfigError, match="a railstop line needs a station"):
        _import(no_station)
    not_railml = _write(tmp_path, "f.xml", "<svg xmlns='http://www.w3.org/2000/svg'/>")
    with pytest.raises(ConfigError, match="not a railML file"):
        _import(not_railml)
    broken = _write(tmp_path, "g.xml", V2_HEAD + "<track")
    with pytest.raises(ConfigError, match=r"\(xml syntax\)"):
        _import(broken)


def test_a_doctype_is_refused_so_entities_are_never_resolved_nor_expanded(tmp_path: Path) -> None:
    secret = _write(tmp_path, "secret.txt", "Northgate-from-a-file")
    edge = (
        '<trackElements><platformEdges><platformEdge id="pe" name="&{};" pos="300" length="130" '
        'side="right"/>'
    )
    xxe = f'<!DOCTYPE railml [<!ENTITY x SYSTEM "file://{secret}">]>'
    laughs = "".join(f'<!ENTITY l{i} "{f"&l{i - 1};" * 10}">' for i in range(1, 10))
    bomb = f'<!DOCTYPE railml [<!ENTITY l0 "ha">{laughs}]>'
    for name, dtd, ent in (("xxe.xml", xxe, "x"), ("bomb.xml", bomb, "l9")):
        body = V2_HEAD + railml_track(edge.format(ent) + "</platformEdges></trackElements>") + V2_TAIL
        for encoding in ("utf-8", "utf-16"):
            path = tmp_path / f"{encoding}-{name}"
            path.write_bytes(f'<?xml version="1.0" encoding="{encoding}"?>{dtd}{body}'.encode(encoding))
            with pytest.raises(ConfigError, match="DOCTYPE declaration") as e:
                _import(path)
            assert "Northgate-from-a-file" not in str(e.value)


def test_the_command_refuses_bad_files_in_one_line(tmp_path: Path) -> None:
    one_error(run("import", "railml", "missing.xml", cwd=tmp_path), "missing.xml", "no such file")
    one_error(run("import", "railml", "/dev/zero", cwd=tmp_path), "/dev/zero", "not a regular file")
    _write(tmp_path, "x.xml", "not xml at all")
    one_error(run("import", "railml", "x.xml", cwd=tmp_path), "x.xml", "(xml syntax)")
    one_error(run("import", "railml", str(V2), cwd=tmp_path), "--track", "t1, t2, t9")
    assert not (tmp_path / "line.toml").exists()


def test_railml_3_a_track_gives_its_net_elements_length_and_a_temporary_limit_is_reported(
    tmp_path: Path,
) -> None:
    """A net element without a length takes its one-element track's physical length; a temporary
    speed section is mapped (the more restrictive reading) and reported."""
    text = (
        '<railML xmlns="https://www.railml.org/schemas/3.1" version="3.1"><infrastructure>'
        '<topology><netElements><netElement id="ne1"/></netElements></topology>'
        "<functionalInfrastructure>"
        '<platformEdges><platformEdge id="pe1"><name name="Quay" language="en"/>'
        '<linearLocation id="l1"><associatedNetElement netElementRef="ne1" posBegin="300" posEnd="430">'
        '<linearCoordinateBegin positioningSystemRef="x" measure="0" lateralSide="left"/>'
        "</associatedNetElement></linearLocation></platformEdge></platformEdges>"
        '<speeds><speedSection id="tsr" maxSpeed="30" isTemporary="true"><linearLocation id="l2">'
        '<associatedNetElement netElementRef="ne1" posBegin="100" posEnd="200"/></linearLocation>'
        "</speedSection></speeds>"
        '<tracks><track id="t1"><linearLocation id="l3"><associatedNetElement netElementRef="ne1"/>'
        '</linearLocation><length value="800" type="physical"/></track></tracks>'
        "</functionalInfrastructure></infrastructure></railML>"
    )
    imported = import_railml(_write(tmp_path, "one.xml", text), default_vehicle())
    assert imported.data["line"]["length_m"] == 800.0
    (st,) = imported.data["stations"]
    assert (st["name"], st["platform_side"], st["platform_end_m"], st["stop_point_m"]) == (
        "Quay",
        "L",
        430.0,
        425.0,
    )
    assert imported.data["speed_limits"][0]["limit_kmh"] == 30.0
    assert any("'tsr': temporary, mapped as permanent" in r for r in imported.report)
