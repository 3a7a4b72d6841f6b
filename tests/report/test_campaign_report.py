"""The campaign report, written from synthetic campaign directories with known stop errors."""

from __future__ import annotations

import base64
import html
import json
import math
import re
import statistics
from collections.abc import Callable
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from scipy.stats import beta

from railstop.errors import RailstopError
from railstop.report.campaign_report import (
    REPORT_FILES_DIR,
    RESULT_COLUMNS,
    find_campaigns,
    load_campaign,
    parameter_columns,
    summary_stats,
    write_report,
)

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
CONTROLLERS = ("tasc-pwm", "tasc-step", "ato")
RUN_OFFSET = 5_000  # run ids differ from row indices, so a mix-up shows
# Planted misses of every controller: row -> stop error (m); the rest is normal(0, 0.1) clipped to ±0.3.
PLANTED = {10: 0.9, 20: 0.6, 30: 0.45, 40: -0.7, 50: 0.41, 60: -0.38}


def _write_campaign(
    c: Path,
    controller: str,
    error: np.ndarray,
    *,
    seed: int = 0,
    stopped: np.ndarray | None = None,
    slid: np.ndarray | None = None,
    manifest: dict[str, object] | None = None,
) -> Path:
    """A campaign directory as the campaign code writes it (a subset of the parameters suffices)."""
    n = error.size
    rng = np.random.default_rng(seed)
    stopped = np.ones(n, dtype=bool) if stopped is None else stopped
    columns = {
        "run": np.arange(RUN_OFFSET, RUN_OFFSET + n, dtype=np.int64),
        "stop_error_m": error,
        "stop_time_s": np.where(stopped, rng.normal(32.0, 1.0, n), np.nan),
        "max_jerk_mps3": rng.gamma(4.0, 0.2, n),
        "notch_changes": rng.integers(0, 12, n),
        "commands_sent": np.full(n, 5, dtype=np.int64),
        "commands_received": rng.integers(3, 6, n),
        "stopped": stopped,
        "slid": np.zeros(n, dtype=bool) if slid is None else slid,
        "entry_speed_kmh": rng.normal(60.0, 1.0, n),
        "load_factor": rng.uniform(0.0, 1.0, n),
        "brake_gain": rng.normal(1.0, 0.05, n),
        "platform_gradient_permille": np.zeros(n),  # constant: no panel, no table column
        "low_adhesion": rng.random(n) < 0.1,
        "radio_latency_ms": rng.choice([50.0, 100.0], n),
    }
    c.mkdir(parents=True, exist_ok=True)
    pq.write_table(pa.table(columns), c / "runs.parquet")
    base: dict[str, object] = {
        "kind": "railstop-campaign",
        "version": 1,
        "station": "Riverside",
        "controller": controller,
        "seed": 7,
        "runs": n,
        "chunk_size": 10_000,
        "disturbances": {"name": "standard", "entry_speed_kmh": {"sigma": 1.0}},
        "line": "railstop demo line",
        "vehicle": "6-car metro EMU (4M2T)",
    }
    (c / "campaign.json").write_text(json.dumps(base | (manifest or {})))
    return c


def _errors(n: int, seed: int) -> np.ndarray:
    error = np.clip(np.random.default_rng(seed).normal(0.0, 0.1, n), -0.3, 0.3)
    for row, value in PLANTED.items():
        error[row] = value
    return error


@pytest.fixture(scope="module")
def compare_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """What ``compare`` writes: one campaign per controller under one directory."""
    d = tmp_path_factory.mktemp("compare")
    for i, name in enumerate(CONTROLLERS):
        _write_campaign(d / name, name, _errors(1_000, seed=i), seed=i)
    (d / "notes").mkdir()  # not a campaign: ignored
    return d


class _Images(HTMLParser):
    def __init__(self) -> None:
        super().__init__()
        self.images: list[tuple[str, str]] = []  # (src, data-file)

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        if tag == "img":
            a = dict(attrs)
            self.images.append((a.get("src") or "", a.get("data-file") or ""))


def _assert_pngs(report: Path) -> list[Path]:
    """Every image of the report is embedded (the page is one self-contained file) as a PNG data
    URI, and the same bytes are in report-files/ for reuse; return the paths of those copies."""
    parser = _Images()
    parser.feed(report.read_text(encoding="utf-8"))
    assert parser.images
    images = []
    prefix = "data:image/png;base64,"
    for src, name in parser.images:
        assert src.startswith(prefix), src[:40]
        data = base64.b64decode(src[len(prefix) :], validate=True)
        assert data[:8] == PNG_MAGIC
        copy = report.parent / REPORT_FILES_DIR / name
        assert copy.is_file(), copy
        assert copy.read_bytes() == data
        images.append(copy)
    return images


def _summary_rows(text: str) -> tuple[list[str], dict[str, list[str]]]:
    """The summary table as (controllers, {row label: cells, one per controller})."""
    table = text[text.index('<table class="summary">') :]
    table = table[: table.index("</table>")]
    lines = [ln for ln in table.splitlines() if ln.startswith("<tr>")]
    names = re.findall(r"</span>([^<]*)</th>", lines[0])
    rows = {}
    for ln in lines[1:]:
        label = re.match(r"<tr><th>([^<]*)</th>", ln)
        assert label, ln
        rows[html.unescape(label.group(1))] = [
            html.unescape(c) for c in re.findall(r'<td class="num">([^<]*)</td>', ln)
        ]
    return names, rows


# --------------------------------------------------------------------------- summary_stats


def test_summary_stats_hand_computed() -> None:
    error = np.array([0.0, 0.1, -0.29, 0.30, 0.32, -0.35, 0.40, -0.45, 0.6, 0.2])
    stopped = np.ones(10, dtype=bool)
    stopped[1] = False  # |error| 0.1 but still moving: outside every band
    slid = np.zeros(10, dtype=bool)
    slid[[6, 8]] = True
    jerk = np.arange(1.0, 11.0)
    stop_time = np.array([30.0, math.nan, 31.0, 32.0, 33.0, 34.0, 35.0, 36.0, 37.0, 38.0])

    s = summary_stats(error, jerk, stop_time, stopped, slid, tolerance_m=0.35)

    assert s["runs"] == 10
    assert s["within_0_30"] == pytest.approx(0.4)  # 0.0, -0.29, 0.30 (inclusive), 0.2
    assert s["within_0_35"] == pytest.approx(0.6)  # + 0.32, -0.35
    assert s["within_0_50"] == pytest.approx(0.8)  # + 0.40, -0.45
    assert s["mean_m"] == pytest.approx(0.083)
    assert s["std_m"] == pytest.approx(statistics.stdev(error.tolist()))
    # Sorted |error|: 0 .1 .2 .29 .30 .32 .35 .40 .45 .60; the 99th percentile is 91 % from .45 to .60.
    assert s["p99_abs_m"] == pytest.approx(0.45 + 0.91 * 0.15)
    assert s["max_abs_m"] == pytest.approx(0.6)
    assert s["overruns"] == 2  # 0.40 and 0.6; -0.45 is short, not over
    assert s["overrun_ci95_upper"] == pytest.approx(beta.ppf(0.95, 3, 8))
    assert s["overrun_ci95_upper"] >= 2 / 10
    assert s["p99_max_jerk_mps3"] == pytest.approx(9.91)
    assert s["mean_stop_time_s"] == pytest.approx(34.0)  # 30 and 31..38, without the moving run
    assert s["not_stopped"] == 1
    assert s["slid"] == 2
    assert isinstance(s["runs"], int) and isinstance(s["overruns"], int)


def test_summary_stats_without_overruns_bound_is_rule_of_three_exact() -> None:
    n = 20
    error = np.linspace(-0.25, 0.25, n)
    ones = np.ones(n)
    s = summary_stats(
        error, ones, ones * 30.0, np.ones(n, dtype=bool), np.zeros(n, dtype=bool), tolerance_m=0.35
    )
    assert s["overruns"] == 0
    assert s["within_0_30"] == s["within_0_35"] == s["within_0_50"] == 1.0
    assert s["overrun_ci95_upper"] == pytest.approx(1.0 - 0.05 ** (1.0 / n))
    assert s["overrun_ci95_upper"] == pytest.approx(beta.ppf(0.95, 1, n))


def test_summary_stats_all_overrun_bound_is_one() -> None:
    n = 5
    s = summary_stats(
        np.full(n, 1.0),
        np.ones(n),
        np.ones(n),
        np.ones(n, dtype=bool),
        np.zeros(n, dtype=bool),
        tolerance_m=0.35,
    )
    assert s["overruns"] == n
    assert s["overrun_ci95_upper"] == 1.0
    assert s["within_0_50"] == 0.0


def test_summary_stats_bound_matches_beta_on_a_campaign() -> None:
    error = _errors(1_000, seed=3)
    ones = np.ones(error.size)
    s = summary_stats(
        error, ones, ones, np.ones(error.size, dtype=bool), np.zeros(error.size, dtype=bool), tolerance_m=0.35
    )
    k = sum(1 for v in PLANTED.values() if v > 0.35)
    assert s["overruns"] == k == 4
    assert s["overrun_ci95_upper"] == pytest.approx(beta.ppf(0.95, k + 1, 1_000 - k))
    assert s["overrun_ci95_upper"] > k / 1_000
    assert s["max_abs_m"] == pytest.approx(0.9)
    assert s["within_0_35"] == pytest.approx((1_000 - 6) / 1_000)


def test_summary_stats_reports_the_low_adhesion_runs_apart() -> None:
    """Overruns split by whether the run met a low-adhesion patch; the bound over the others."""
    error = np.array([0.5, 0.9, 0.1, -0.2, 0.4, 0.0, 0.1, 0.2])
    patch = np.array([True, True, True, False, False, False, False, False])
    n = error.size
    ones = np.ones(n)
    s = summary_stats(
        error,
        ones,
        ones,
        np.ones(n, dtype=bool),
        np.zeros(n, dtype=bool),
        tolerance_m=0.35,
        low_adhesion=patch,
    )
    assert s["overruns"] == 3
    assert (s["low_adhesion_runs"], s["overruns_low_adhesion"], s["overruns_no_low_adhesion"]) == (3, 2, 1)
    assert s["overrun_ci95_upper_no_low_adhesion"] == pytest.approx(beta.ppf(0.95, 2, 4))
    assert "low_adhesion_runs" not in summary_stats(
        error, ones, ones, np.ones(n, dtype=bool), np.zeros(n, dtype=bool), tolerance_m=0.35
    )
    with pytest.raises(RailstopError, match="low_adhesion"):
        summary_stats(
            error,
            ones,
            ones,
            np.ones(n, dtype=bool),
            np.zeros(n, dtype=bool),
            tolerance_m=0.35,
            low_adhesion=patch[:2],
        )


def test_summary_stats_rejects_mismatched_columns() -> None:
    with pytest.raises(RailstopError, match="stopped"):
        summary_stats(
            np.zeros(3),
            np.zeros(3),
            np.zeros(3),
            np.ones(2, dtype=bool),
            np.zeros(3, dtype=bool),
            tolerance_m=0.35,
        )


# --------------------------------------------------------------------------- loading


def test_find_and_load_campaigns(compare_dir: Path) -> None:
    found = find_campaigns(compare_dir)
    assert found == sorted(compare_dir / name for name in CONTROLLERS)
    assert find_campaigns(compare_dir / "ato") == [compare_dir / "ato"]

    manifest, columns = load_campaign(compare_dir / "ato")
    assert manifest["controller"] == "ato"
    assert isinstance(columns["stop_error_m"], np.ndarray)
    assert columns["stop_error_m"].dtype == np.float64
    assert columns["stopped"].dtype == bool
    assert columns["run"][0] == RUN_OFFSET
    params = parameter_columns(columns)
    assert "load_factor" in params and "low_adhesion" in params
    assert not set(params) & set(RESULT_COLUMNS)


@pytest.mark.parametrize("make", ["empty", "missing", "file"])
def test_no_campaign_is_a_one_line_error(tmp_path: Path, make: str) -> None:
    target = tmp_path / "nothing-here"
    if make == "empty":
        (target / "sub").mkdir(parents=True)
    elif make == "file":
        target.write_text("x")
    with pytest.raises(RailstopError) as info:
        write_report(target)
    message = str(info.value)
    assert str(target) in message
    assert "\n" not in message
    assert not (tmp_path / "nothing-here" / "report.html").exists()


def test_missing_result_column_names_the_file(tmp_path: Path) -> None:
    c = _write_campaign(tmp_path / "c", "tasc-pwm", _errors(100, seed=0))
    table = pq.read_table(c / "runs.parquet").drop_columns(["slid"])
    pq.write_table(table, c / "runs.parquet")
    with pytest.raises(RailstopError, match=r"runs\.parquet: missing column\(s\) slid"):
        load_campaign(c)


# --------------------------------------------------------------------------- the report


def test_report_of_several_controllers(compare_dir: Path) -> None:
    report = write_report(compare_dir)
    assert report == compare_dir / "report.html"
    text = report.read_text(encoding="utf-8")

    images = _assert_pngs(report)
    names = {p.name for p in images}
    assert {"stop-error-histogram.png", "abs-error-cdf.png", "what-drives-the-misses-1.png"} <= names
    assert not any(n.startswith("worst-runs") for n in names)  # no replay, no profiles
    assert "without a replay function" in text

    for field in ("Riverside", "railstop demo line", "6-car metro EMU (4M2T)", "standard", "1,000"):
        assert field in text
    names, rows = _summary_rows(text)
    assert sorted(names) == sorted(CONTROLLERS)
    assert rows["PSD tolerance"] == ["±0.35 m"] * len(names)  # no summary.json: the default
    for i, name in enumerate(names):
        _, columns = load_campaign(compare_dir / name)
        s = summary_stats(
            columns["stop_error_m"],
            columns["max_jerk_mps3"],
            columns["stop_time_s"],
            columns["stopped"],
            columns["slid"],
            tolerance_m=0.35,
        )
        assert rows["within the PSD tolerance (±0.35 m)"][i] == f"{100 * s['within_tolerance']:.2f} %"
        assert rows["within ±0.30 m"][i] == f"{100 * s['within_0_30']:.2f} %"
        assert rows["within ±0.50 m"][i] == f"{100 * s['within_0_50']:.2f} %"
        assert rows["mean (m)"][i] == f"{s['mean_m']:+.3f}"
        assert rows["std (m)"][i] == f"{s['std_m']:.3f}"
        assert rows["p99 |error| (m)"][i] == f"{s['p99_abs_m']:.3f}"
        assert rows["max |error| (m)"][i] == "0.900"  # the planted +0.9 m is everyone's largest miss
        assert rows["overruns > +0.35 m"][i] == f"{s['overruns']}"
        assert rows["P(overrun > +0.35 m), 95 % upper bound"][i] == _pct(s["overrun_ci95_upper"])
        assert rows["p99 max jerk (m/s³)"][i] == f"{s['p99_max_jerk_mps3']:.2f}"
    # Varying parameters get a worst-run column; the constant one is left out everywhere.
    assert "load_factor" in text
    assert "platform_gradient_permille" not in text


Replay = Callable[[Path, int], tuple[np.ndarray, np.ndarray]]


def _pct(fraction: float) -> str:
    """A probability as the report prints it: two decimals from 1 %, three significant digits below."""
    value = 100.0 * fraction
    return f"{value:.2f} %" if value >= 1.0 else f"{value:#.3g} %"


def _replay_recorder() -> tuple[list[tuple[Path, int]], Replay]:
    calls: list[tuple[Path, int]] = []

    def replay(campaign: Path, run: int) -> tuple[np.ndarray, np.ndarray]:
        calls.append((campaign, run))
        error = PLANTED.get(run - RUN_OFFSET, 0.0)
        # Remaining distance, positive before the stopping point, ending at -error.
        distance = np.linspace(220.0, -error, 400)
        speed = 60.0 * np.sqrt((distance + error) / (220.0 + error))
        return distance, speed

    return calls, replay


def test_replay_is_called_for_the_worst_runs(compare_dir: Path) -> None:
    calls, replay = _replay_recorder()
    worst = 5
    report = write_report(compare_dir, replay=replay, worst=worst)

    # |error| order of the planted misses: 0.9, -0.7, 0.6, 0.45, 0.41 (then -0.38).
    expected = [RUN_OFFSET + row for row in (10, 40, 20, 30, 50)]
    for name in CONTROLLERS:
        mine = [run for campaign, run in calls if campaign == compare_dir / name]
        assert mine == expected, name
    assert len(calls) == worst * len(CONTROLLERS)

    names = {p.name for p in _assert_pngs(report)}
    assert sum(n.startswith("worst-runs") for n in names) == len(CONTROLLERS)
    text = report.read_text(encoding="utf-8")
    assert "without a replay function" not in text
    assert f">{RUN_OFFSET + 10}<" in text and ">+0.900<" in text


def test_single_campaign_directory(tmp_path: Path) -> None:
    c = _write_campaign(tmp_path / "one", "tasc-pwm", _errors(1_000, seed=0))
    calls, replay = _replay_recorder()
    report = write_report(c, replay=replay, worst=2)
    assert report == c / "report.html"
    _assert_pngs(report)
    assert [run for _, run in calls] == [RUN_OFFSET + 10, RUN_OFFSET + 40]
    text = report.read_text(encoding="utf-8")
    assert "tasc-pwm" in text
    assert "tasc-step" not in text


def test_tiny_campaign_without_overruns(tmp_path: Path) -> None:
    n = 20
    error = np.random.default_rng(5).uniform(-0.2, 0.2, n)
    c = _write_campaign(tmp_path / "tiny", "tasc-step", error, manifest={"seed": 123})
    calls, replay = _replay_recorder()
    report = write_report(c, replay=replay, worst=50)  # more than there are runs
    assert len(calls) == n
    assert sorted(run for _, run in calls) == list(range(RUN_OFFSET, RUN_OFFSET + n))
    _assert_pngs(report)
    text = report.read_text(encoding="utf-8")
    bound = 1.0 - 0.05 ** (1.0 / n)
    assert _pct(bound) == "13.91 %"
    assert f">{_pct(bound)}<" in text
    assert ">100.00 %<" in text
    assert ">123<" in text


def test_campaigns_with_unequal_sizes_and_a_missing_parameter(tmp_path: Path) -> None:
    _write_campaign(tmp_path / "a", "tasc-pwm", _errors(400, seed=1))
    b = _write_campaign(tmp_path / "b", "ato", _errors(100, seed=2), seed=2)
    table = pq.read_table(b / "runs.parquet")
    pq.write_table(
        table.drop_columns(["brake_gain"]).append_column("new_knob", pa.array(np.arange(100.0))),
        b / "runs.parquet",
    )
    report = write_report(tmp_path, worst=0)
    _assert_pngs(report)
    text = report.read_text(encoding="utf-8")
    assert "tasc-pwm: 400, ato: 100" in text
    assert "new_knob" in text


def test_hundred_thousand_runs_report(tmp_path: Path) -> None:
    """A full-size campaign goes through the binned plots (speed is a benchmark, not a test)."""
    n = 100_000
    error = np.random.default_rng(9).normal(0.0, 0.1, n)
    error[:40] += 1.0
    c = _write_campaign(tmp_path / "big", "tasc-pwm", error, seed=9)
    calls, replay = _replay_recorder()
    report = write_report(c, replay=replay)
    _assert_pngs(report)
    assert len(calls) == 5
