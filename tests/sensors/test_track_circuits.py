"""SPEC §2 track circuits: line data (validation, the default division) and occupancy detection.

A bad ``[track]`` section must give one line naming the file, the field and
the bad value (DESIGN rule 6). The default line is divided into contiguous
circuits of tens to a few hundred metres from chainage 0 to its end, shorter
in stations. The detector reports an entry when the train front crosses a
circuit's electrical boundary (surveyed start + boundary uncertainty), and
the occupancy a detection delay later.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from railstop.config import default_line, load_line
from railstop.config.schema import TrackCircuit, TrackCircuitDetection
from railstop.errors import ConfigError
from railstop.sensors.track_circuit import TrackCircuitDetector
from railstop.streams import RunStreams

LINE = default_line()

BASE = """\
[line]
name = "tc line"
length_m = 1200.0

[[stations]]
name = "Alpha"
stop_point_m = 1000.0
platform_length_m = 130.0
platform_side = "R"
[stations.tasc]
detectors_before_stop_m = [220.0, 150.0, 90.0, 40.0, 6.0]
doppler = { beyond_stop_m = 10.0 }

[track]
circuits = [
  { id = 1, start_m = 0.0, end_m = 300.0 },
  { id = 2, start_m = 300.0, end_m = 600.0 },
  { id = 3, start_m = 600.0, end_m = 870.0 },
  { id = 4, start_m = 870.0, end_m = 1005.0, kind = "insulated" },
  { id = 5, start_m = 1005.0, end_m = 1200.0 },
]
tunnels = [{ start_m = 200.0, end_m = 500.0, repeater = true }]
"""


def _load(tmp_path: Path, old: str, new: str) -> ConfigError:
    assert BASE.count(old) == 1, old
    path = tmp_path / "line.toml"
    path.write_text(BASE.replace(old, new), encoding="utf-8")
    with pytest.raises(ConfigError) as info:
        load_line(path)
    text = str(info.value)
    assert "\n" not in text and text.startswith(f"{path}: ")
    return info.value


def test_base_file_is_valid(tmp_path: Path) -> None:
    path = tmp_path / "ok.toml"
    path.write_text(BASE, encoding="utf-8")
    line = load_line(path)
    assert [c.id for c in line.track_circuits] == [1, 2, 3, 4, 5]
    assert line.track_circuits[3].kind == "insulated" and line.track_circuits[0].kind == "jointless"
    assert line.tunnels[0].repeater


@pytest.mark.parametrize(
    ("old", "new", "field", "value"),
    [
        # a gap
        ("{ id = 3, start_m = 600.0,", "{ id = 3, start_m = 610.0,", "track.circuits[2].start_m", "610.0"),
        # an overlap
        ("{ id = 3, start_m = 600.0,", "{ id = 3, start_m = 590.0,", "track.circuits[2].start_m", "590.0"),
        # a repeated ID
        ("{ id = 4, start_m", "{ id = 2, start_m", "track.circuits[3].id", "2"),
        # not from chainage 0
        ("{ id = 1, start_m = 0.0,", "{ id = 1, start_m = 5.0,", "track.circuits[0].start_m", "5.0"),
        # end before start
        (
            "start_m = 1005.0, end_m = 1200.0",
            "start_m = 1005.0, end_m = 1000.0",
            "track.circuits[4].end_m",
            "1000.0",
        ),
        # not reaching the line's end
        ("length_m = 1200.0", "length_m = 1300.0", "track.circuits[4].end_m", "1200.0"),
        # an ID that does not fit the telegram
        ("{ id = 5, start_m", "{ id = 70000, start_m", "track.circuits[4].id", "70000"),
        # an unknown kind
        ('kind = "insulated"', 'kind = "magnetic"', "track.circuits[3].kind", "magnetic"),
        # a tunnel off the line
        (
            "tunnels = [{ start_m = 200.0, end_m = 500.0",
            "tunnels = [{ start_m = 200.0, end_m = 1500.0",
            "track.tunnels[0]",
            "1500.0",
        ),
        # detection data out of range
        (
            "tunnels = [",
            "detection = { delay_mean_s = -0.1 }\ntunnels = [",
            "track.detection.delay_mean_s",
            "-0.1",
        ),
    ],
)
def test_bad_track_data_names_field_and_value(
    tmp_path: Path, old: str, new: str, field: str, value: str
) -> None:
    err = _load(tmp_path, old, new)
    assert err.field == field, str(err)
    assert value in str(err)


def test_unknown_key_in_a_circuit(tmp_path: Path) -> None:
    err = _load(
        tmp_path,
        "{ id = 1, start_m = 0.0, end_m = 300.0 }",
        "{ id = 1, start_m = 0.0, end_m = 300.0, lenght = 3 }",
    )
    assert err.field == "track.circuits[0].lenght" and "unknown key" in str(err)


def test_tunnels_must_not_overlap(tmp_path: Path) -> None:
    err = _load(
        tmp_path,
        "tunnels = [{ start_m = 200.0, end_m = 500.0, repeater = true }]",
        "tunnels = [{ start_m = 200.0, end_m = 500.0 }, { start_m = 450.0, end_m = 700.0 }]",
    )
    assert err.field == "track.tunnels[1].start_m" and "450.0" in str(err)


def test_line_without_track_section_still_loads(tmp_path: Path) -> None:
    path = tmp_path / "plain.toml"
    path.write_text(BASE.split("[track]")[0], encoding="utf-8")
    line = load_line(path)
    assert line.track_circuits == [] and line.tunnels == [] and line.track.end_m is None


# --------------------------------------------------------------------------
# The default division


def test_default_division_covers_the_line() -> None:
    circuits = LINE.track_circuits
    starts = np.array([c.start_m for c in circuits])
    ends = np.array([c.end_m for c in circuits])
    assert starts[0] == 0.0 and ends[-1] == LINE.line.length_m
    assert np.array_equal(starts[1:], ends[:-1])  # contiguous, no overlap
    assert len({c.id for c in circuits}) == len(circuits)
    lengths = ends - starts
    assert lengths.min() >= 50.0 and lengths.max() <= 300.0
    for s in LINE.stations:
        # The platform is one circuit of its own, shorter than the open-line ones, with sharp joints.
        (plat,) = [c for c in circuits if c.start_m == s.platform_start]
        assert plat.end_m == s.platform_end and plat.kind == "insulated"
        assert plat.end_m - plat.start_m < np.median(lengths[[c.kind == "jointless" for c in circuits]])
    # A GNSS shadow without a repeater exists (what --no-repeaters compares against).
    assert any(not t.repeater for t in LINE.tunnels) and any(t.repeater for t in LINE.tunnels)


# --------------------------------------------------------------------------
# Detection


def _circuits() -> list[TrackCircuit]:
    return [
        TrackCircuit(id=1, start_m=0.0, end_m=100.0),
        TrackCircuit(id=2, start_m=100.0, end_m=250.0),
        TrackCircuit(id=3, start_m=250.0, end_m=400.0, kind="insulated"),
    ]


def test_detector_exact_entry_times_and_delay() -> None:
    det = TrackCircuitDetector.create(
        _circuits(),
        TrackCircuitDetection(
            delay_mean_s=0.3, delay_spread_s=0.0, boundary_sd_jointless_m=0.0, boundary_sd_insulated_m=0.0
        ),
        RunStreams.for_runs(1, 0, 2),
        start_position_m=np.array([50.0, 120.0]),
    )
    assert det.next_index.tolist() == [1, 2]  # circuits already occupied give no event
    v, dt = 20.0, 0.05
    x = np.array([50.0, 120.0])
    found: list[tuple[int, int, float, float]] = []
    for k in range(400):
        x1 = x + v * dt
        ev = det.detect(x0_m=x, v0_mps=np.full(2, v), accel_mps2=np.zeros(2), x1_m=x1, t0_s=k * dt)
        found += list(
            zip(
                ev.run.tolist(),
                ev.circuit_index.tolist(),
                ev.entry_time_s.tolist(),
                ev.occupied_time_s.tolist(),
                strict=True,
            )
        )
        x = x1
    assert [(r, c) for r, c, _, _ in found] == [(0, 1), (1, 2), (0, 2)]
    for r, c, t_entry, t_occ in found:
        start = [0.0, 100.0, 250.0][c]
        x0 = [50.0, 120.0][r]
        assert t_entry == pytest.approx((start - x0) / v, abs=1e-9)
        assert t_occ == pytest.approx(t_entry + 0.3, abs=1e-12)


def test_detector_boundary_and_delay_statistics() -> None:
    data = TrackCircuitDetection(
        delay_mean_s=0.3, delay_spread_s=0.05, boundary_sd_jointless_m=1.5, boundary_sd_insulated_m=0.2
    )
    n = 4000
    det = TrackCircuitDetector.create(
        _circuits(), data, RunStreams.for_runs(3, 0, n), start_position_m=np.zeros(n)
    )
    off = det.boundary_m - np.array([0.0, 100.0, 250.0])
    assert np.std(off[:, 1]) == pytest.approx(1.5, rel=0.06)
    assert np.std(off[:, 2]) == pytest.approx(0.2, rel=0.06)
    assert abs(np.mean(off[:, 1])) < 0.1
    assert np.mean(det.delay_s) == pytest.approx(0.3, abs=0.005)
    assert np.std(det.delay_s) == pytest.approx(0.05, rel=0.06)
    assert det.delay_s.min() >= 0.0
    # Run i's draws do not depend on the batch it is drawn in (DESIGN rule 4).
    alone = TrackCircuitDetector.create(
        _circuits(), data, RunStreams.for_runs(3, 1234, 1), start_position_m=np.zeros(1)
    )
    assert np.array_equal(alone.boundary_m[0], det.boundary_m[1234])
    assert np.array_equal(alone.delay_s[0], det.delay_s[1234])


def test_detector_needs_circuits() -> None:
    with pytest.raises(ValueError, match="no track circuits"):
        TrackCircuitDetector.create(
            [], TrackCircuitDetection(), RunStreams.for_runs(1, 0, 1), start_position_m=np.zeros(1)
        )
