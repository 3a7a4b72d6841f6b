"""The stop plot, drawn from a real recorded stop."""

from __future__ import annotations

from pathlib import Path

import pytest

from railstop.config import default_line, default_vehicle
from railstop.config.scenario import Scenario
from railstop.errors import RailstopError
from railstop.report import plot_stop
from railstop.sim.engine import BatchResult, run_batch
from railstop.streams import RunStreams

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def stop() -> BatchResult:
    station = default_line().stations[0]
    vehicle = default_vehicle()
    return run_batch(
        station=station,
        vehicle=vehicle,
        scenario=Scenario.nominal(station, vehicle),
        controller="tasc-pwm",
        streams=RunStreams.for_runs(1, 0, 1),
        record=True,
    )


def _plot(stop: BatchResult, path: Path | str) -> Path:
    station = default_line().stations[0]
    assert stop.trace is not None
    return plot_stop(
        stop.trace,
        run=0,
        station_name=station.name,
        stop_point_m=station.stop_point_m,
        detector_positions_m=station.detector_positions_m(),
        passage_times_s=list(stop.detector_passages_s[0]),
        commands=stop.commands,
        title=f"{station.name}, tasc-pwm",
        path=path,
        tolerance_m=station.psd_tolerance_m,
    )


def test_plot_writes_a_png(stop: BatchResult, tmp_path: Path) -> None:
    target = tmp_path / "stop.png"
    out = _plot(stop, str(target))
    assert out == target
    assert out.is_file()
    data = out.read_bytes()
    assert data[:8] == PNG_MAGIC
    assert len(data) > 20_000  # two panels with curves, not an empty canvas
    # IHDR: 10 x 8 inches at 120 dpi.
    width = int.from_bytes(data[16:20], "big")
    height = int.from_bytes(data[20:24], "big")
    assert (width, height) == (1200, 960)


def test_plot_handles_a_detector_never_passed(stop: BatchResult, tmp_path: Path) -> None:
    station = default_line().stations[0]
    assert stop.trace is not None
    passages = list(stop.detector_passages_s[0])
    passages[-1] = float("nan")
    out = plot_stop(
        stop.trace,
        run=0,
        station_name=station.name,
        stop_point_m=station.stop_point_m,
        detector_positions_m=station.detector_positions_m(),
        passage_times_s=passages,
        commands=[],
        title="no commands",
        path=tmp_path / "partial.png",
        tolerance_m=0.35,
    )
    assert out.read_bytes()[:8] == PNG_MAGIC


def test_plot_into_missing_directory_is_a_railstop_error(stop: BatchResult, tmp_path: Path) -> None:
    bad = tmp_path / "missing" / "stop.png"
    with pytest.raises(RailstopError) as info:
        _plot(stop, bad)
    assert str(bad) in str(info.value)
