"""The report of a campaign: how often, how far and why a controller misses the stop.

A campaign directory holds ``campaign.json`` (the manifest) and ``runs.parquet``
(one row per randomised stop: the results and the disturbances drawn for it).
``write_report`` turns one campaign, or a directory of campaigns (one per
controller, as ``compare`` writes them), into ``report.html``: one
self-contained file (the figures are embedded; copies of them as PNG files are
written to ``report-files/`` for slides) with where the numbers come from
(railstop version, date, seed, disturbance set, input hashes), a summary per
controller against the station's PSD tolerance, the stop-error histogram, the
empirical CDF of |error|, the stop error against every disturbance parameter
("what drives the misses") and, given a replay function, the speed profiles of
the worst runs with the commands they received and the detectors.

Everything works on whole numpy columns: 10^5 runs per controller take a few
seconds, almost all of it drawing.
"""

from __future__ import annotations

import base64
import html
import json
import math
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

from railstop.errors import RailstopError
from railstop.provenance import footer, manifest_sha256, stamp
from railstop.report.figures import write_figure
from railstop.stats.summary import BANDS_M, DEFAULT_TOLERANCE_M, RESULT_COLUMNS, summary_stats

if TYPE_CHECKING:
    # matplotlib is imported where a figure is drawn: the campaign code imports summary_stats.
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

__all__ = [
    "BANDS_M",
    "MANIFEST_NAME",
    "REPORT_FILES_DIR",
    "REPORT_NAME",
    "RESULT_COLUMNS",
    "RUNS_NAME",
    "Replay",
    "find_campaigns",
    "load_campaign",
    "parameter_columns",
    "summary_stats",
    "write_report",
]

MANIFEST_NAME = "campaign.json"
RUNS_NAME = "runs.parquet"
REPORT_NAME = "report.html"
REPORT_FILES_DIR = "report-files"

# The report cannot be written without these.
_REQUIRED_COLUMNS: tuple[str, ...] = (
    "run",
    "stop_error_m",
    "stop_time_s",
    "max_jerk_mps3",
    "stopped",
    "slid",
)
SUMMARY_NAME = "summary.json"

# replay(campaign_dir, run) -> (distance_to_stop_m, speed_kmh) of that run.
Replay = Callable[[Path, int], tuple[np.ndarray, np.ndarray]]

_DPI = 110
_BINNED_ABOVE = 20_000  # points in one parameter panel above which it shows binned percentiles
_SCATTER_SAMPLE = 1_500  # faint points per controller behind the binned percentiles
_MAX_BINS = 20
_DISCRETE_MAX_VALUES = 12  # a parameter with at most this many values is binned per value
_PANELS_PER_FIGURE = 12
_PANEL_COLUMNS = 4
_ECDF_POINTS = 4_000
_ECDF_TAIL_POINTS = 2_000
# One colour per controller; no green, which marks the PSD tolerance band.
#: Controllers side by side in one summary table (more: another table below).
SUMMARY_COLUMNS = 5

# One colour and line style per controller, the same in every report (green is the tolerance
# band's): ten distinct colours for the ten built-in controllers, the line style by family (TASC
# solid, ATO dashed, drivers dotted); a law or an unknown controller takes the next free colour.
_CONTROLLER_COLORS = (
    "tab:blue", "tab:orange", "tab:red", "tab:purple", "tab:brown",
    "tab:pink", "tab:gray", "tab:olive", "tab:cyan", "black",
)  # fmt: skip
_EXTRA_COLORS = ("#393b79", "#8c6d31", "#843c39", "#7b4173", "#17becf", "#bcbd22", "#637939", "#e7969c")


def controller_style(name: str, index: int) -> tuple[str, str]:
    """(colour, line style) of a controller in the report's figures (``index``: its place among
    the report's campaigns, for a controller that is not built in)."""
    from railstop.controllers import CONTROLLERS

    known = list(CONTROLLERS)
    if name in known:
        k = known.index(name)
        family = "-" if name.startswith("tasc") else "--" if name.startswith("ato") else ":"
        return _CONTROLLER_COLORS[k % len(_CONTROLLER_COLORS)], family
    return _EXTRA_COLORS[index % len(_EXTRA_COLORS)], "-."


_PROFILE_COLORS = (*_CONTROLLER_COLORS, "tab:olive", "tab:gray", "black")


# --------------------------------------------------------------------------- loading


def _is_campaign(d: Path) -> bool:
    return (d / MANIFEST_NAME).is_file() and (d / RUNS_NAME).is_file()


def find_campaigns(d: Path) -> list[Path]:
    """``[d]`` if ``d`` is a campaign directory, else its campaign subdirectories, sorted by name.

    Raises ``RailstopError`` if there is none.
    """
    d = Path(d)
    if not d.is_dir():
        raise RailstopError(f"{d}: not a directory")
    if _is_campaign(d):
        return [d]
    found = sorted(sub for sub in d.iterdir() if sub.is_dir() and _is_campaign(sub))
    if not found:
        raise RailstopError(
            f"{d}: no campaign found (neither it nor any subdirectory holds {MANIFEST_NAME} and {RUNS_NAME})"
        )
    return found


CSV_NAME = "runs.csv"


def export_csv(directory: Path) -> list[Path]:
    """Write each campaign's ``runs.parquet`` as ``runs.csv`` beside it (one row per run, the
    same columns, a header line); return the files written. For a spreadsheet or a tool that
    reads no Parquet."""
    import pyarrow.csv as pacsv

    written = []
    for c in find_campaigns(directory):
        target = c / CSV_NAME
        pacsv.write_csv(_read_runs(c / RUNS_NAME), target)
        written.append(target)
    return written


def _to_numpy(column: pa.ChunkedArray) -> np.ndarray:
    """A parquet column as numpy: nulls become False in booleans and NaN in numbers."""
    kind = column.type
    if pa.types.is_boolean(kind):
        return np.asarray(pc.fill_null(column, False).to_numpy(), dtype=bool)
    if pa.types.is_integer(kind) and column.null_count == 0:
        return np.asarray(column.to_numpy(), dtype=np.int64)
    if pa.types.is_integer(kind) or pa.types.is_floating(kind) or pa.types.is_decimal(kind):
        filled = pc.fill_null(column.cast(pa.float64()), math.nan)
        return np.asarray(filled.to_numpy(), dtype=np.float64)
    return np.asarray(column.to_numpy(), dtype=object)


def _read_runs(runs_path: Path) -> pa.Table:
    """A campaign's ``runs.parquet`` as a table, or one RailstopError naming the file."""
    try:
        return pq.read_table(runs_path)
    except (OSError, pa.ArrowException) as exc:
        message = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise RailstopError(f"{runs_path}: cannot read: {message}") from None


def load_campaign(c: Path) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """The manifest and the columns of ``runs.parquet`` (name -> numpy array) of campaign ``c``."""
    c = Path(c)
    manifest_path = c / MANIFEST_NAME
    runs_path = c / RUNS_NAME
    try:
        manifest = json.loads(manifest_path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise RailstopError(f"{manifest_path}: cannot read: {exc.strerror or exc}") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise RailstopError(f"{manifest_path}: not valid JSON: {exc}") from None
    if not isinstance(manifest, dict):
        raise RailstopError(f"{manifest_path}: expected a JSON object (got {type(manifest).__name__})")
    kind = manifest.get("kind", "railstop-campaign")
    if kind != "railstop-campaign":
        raise RailstopError(f"{manifest_path}: kind: not a railstop campaign (got {kind!r})")
    table = _read_runs(runs_path)
    missing = [name for name in _REQUIRED_COLUMNS if name not in table.column_names]
    if missing:
        raise RailstopError(f"{runs_path}: missing column(s) {', '.join(missing)}")
    columns = {name: _to_numpy(table.column(name)) for name in table.column_names}
    return manifest, columns


def parameter_columns(columns: dict[str, np.ndarray]) -> list[str]:
    """The disturbance parameters of a campaign: every numeric or boolean column that is not a result."""
    return [
        name
        for name, values in columns.items()
        if name not in RESULT_COLUMNS and (values.dtype == bool or np.issubdtype(values.dtype, np.number))
    ]


# --------------------------------------------------------------------------- the report


@dataclass
class _Campaign:
    path: Path
    name: str  # the controller, made unique among the campaigns of the report
    slug: str  # the name as a file-name part
    controller: str  # the manifest's controller (the folder's name without one)
    color: str
    linestyle: str
    manifest: dict[str, Any]
    columns: dict[str, np.ndarray]
    stats: dict[str, float | int]
    tolerance: float
    provenance: dict[str, Any]

    @property
    def error(self) -> np.ndarray:
        return np.asarray(self.columns["stop_error_m"], dtype=np.float64)

    @property
    def runs(self) -> int:
        return int(self.error.size)

    def worst_rows(self, count: int) -> np.ndarray:
        """Row indices of the ``count`` largest |error|, largest first (a NaN error ranks first)."""
        size = self.error.size
        count = min(max(count, 0), size)
        if count == 0:
            return np.zeros(0, dtype=np.int64)
        key = np.where(np.isfinite(self.error), np.abs(self.error), np.inf)
        rows = np.argpartition(-key, count - 1)[:count] if count < size else np.arange(size)
        # Largest first; equal errors in run order, so the choice does not depend on the sort.
        order = np.lexsort((np.asarray(self.columns["run"])[rows], -key[rows]))
        return rows[order]


def _summary_file(path: Path) -> dict[str, Any]:
    """The campaign's summary.json, or {} if it has none or it is unreadable (the report
    recomputes every statistic from runs.parquet; it only takes the tolerance and provenance)."""
    try:
        data = json.loads((path / SUMMARY_NAME).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}
    return data if isinstance(data, dict) else {}


def _load_all(paths: list[Path], tolerance_m: float | None) -> list[_Campaign]:
    campaigns: list[_Campaign] = []
    seen: dict[str, int] = {}
    for i, path in enumerate(paths):
        manifest, columns = load_campaign(path)
        summary = _summary_file(path)
        tol = tolerance_m
        if tol is None:
            written = summary.get("tolerance_m")
            ok = isinstance(written, (int, float)) and math.isfinite(written) and written > 0
            tol = float(written) if ok and written is not None else DEFAULT_TOLERANCE_M
        base = str(manifest.get("controller") or path.name)
        color, linestyle = controller_style(base, i)
        seen[base] = seen.get(base, 0) + 1
        name = base if seen[base] == 1 else f"{base} ({path.name})"
        slug = re.sub(r"[^A-Za-z0-9_.-]+", "-", name).strip("-.") or "campaign"
        stats = summary_stats(
            columns["stop_error_m"],
            columns["max_jerk_mps3"],
            columns["stop_time_s"],
            columns["stopped"],
            columns["slid"],
            tolerance_m=tol,
            emergency_brake=columns.get("emergency_brake"),
        )
        prov = summary.get("provenance")
        campaigns.append(
            _Campaign(
                path=path,
                name=name,
                slug=f"{i + 1}-{slug}",
                controller=base,
                color=color,
                linestyle=linestyle,
                manifest=manifest,
                columns=columns,
                stats=stats,
                tolerance=tol,
                provenance=prov if isinstance(prov, dict) else {},
            )
        )
    return campaigns


ReportProgress = Callable[[int, int], None]  # (figures done, figures in all)


def write_report(
    directory: Path,
    *,
    replay: Replay | None = None,
    worst: int = 5,
    tolerance_m: float | None = None,
    progress: ReportProgress | None = None,
    controllers: Sequence[str] | None = None,
) -> Path:
    """Write ``directory/report.html`` (figures embedded; PNG copies in ``directory/report-files/``)
    and return its path. ``controllers``: only the campaigns of these controllers (None: all).

    ``directory`` is a campaign directory or holds campaign directories, one per
    controller. ``replay(campaign_dir, run)`` re-simulates one run and returns
    ``(distance_to_stop_m, speed_kmh)``; it is called for the ``worst`` runs by
    |error| of each controller. The distance may be the remaining distance
    (positive before the stopping point) or position minus stopping point
    (negative before it): the profile starts far out, and its first value tells
    which. Without ``replay`` the profiles are left out and the report says so.
    ``tolerance_m``: the PSD tolerance to judge against (None: each campaign's,
    from its summary.json, i.e. its station's ``psd_tolerance_m``).
    """
    directory = Path(directory)
    if worst < 0:
        raise RailstopError(f"worst: must be at least 0 (got {worst})")
    if tolerance_m is not None and not (math.isfinite(tolerance_m) and tolerance_m > 0.0):
        raise RailstopError(f"--tolerance-m: must be a positive number of metres (got {tolerance_m})")
    campaigns = _load_all(find_campaigns(directory), tolerance_m)
    if controllers is not None:
        names = [c.controller for c in campaigns]
        unknown = [n for n in controllers if n not in names]
        if unknown:
            raise RailstopError(
                f"--controllers: no campaign of {', '.join(unknown)} in {directory} "
                f"(it has: {', '.join(names)})"
            )
        campaigns = [c for c in campaigns if c.controller in controllers]
    campaigns = _in_controller_order(campaigns)
    files = directory / REPORT_FILES_DIR
    try:
        files.mkdir(exist_ok=True)
    except OSError as exc:
        raise RailstopError(f"{files}: cannot create the directory: {exc.strerror or exc}") from None

    parameters = _varying_parameters(campaigns)
    n_driver = 0 if not parameters else (1 if len(parameters) <= _PANELS_PER_FIGURE else 2)
    total = 2 + n_driver + (len(campaigns) if replay is not None and worst > 0 else 0)
    done = 0

    def saved(fig: Figure, name: str) -> Path:
        nonlocal done
        path = _save(fig, files / name)
        done += 1
        if progress:
            progress(done, total)
        return path

    if progress:
        progress(0, total)
    figures: dict[str, Path] = {}
    figures["errors"] = saved(_error_histogram(campaigns), "stop-error-histogram.png")
    figures["cdf"] = saved(_abs_error_cdf(campaigns), "abs-error-cdf.png")
    driver_pngs = [
        saved(fig, f"what-drives-the-misses-{i + 1}.png")
        for i, fig in enumerate(_driver_figures(campaigns, parameters))
    ]
    worst_rows = {c.name: c.worst_rows(worst) for c in campaigns}
    profile_pngs: dict[str, Path] = {}
    if replay is not None:
        for c in campaigns:
            rows = worst_rows[c.name]
            if rows.size:
                fig = _worst_profiles(c, rows, replay)
                profile_pngs[c.name] = saved(fig, f"worst-runs-{c.slug}.png")

    page = _html(
        directory,
        campaigns,
        figures=figures,
        driver_pngs=driver_pngs,
        parameters=parameters,
        worst_rows=worst_rows,
        profile_pngs=profile_pngs,
        replayed=replay is not None,
        worst=worst,
        written=stamp(),
    )
    out = directory / REPORT_NAME
    try:
        out.write_text(page, encoding="utf-8")
    except OSError as exc:
        raise RailstopError(f"{out}: cannot write the report: {exc.strerror or exc}") from None
    return out


def _save(fig: Figure, path: Path) -> Path:
    return write_figure(fig, path, _DPI)


def _figure(figsize: tuple[float, float]) -> Figure:
    import matplotlib  # lazy (start-up), see the note on matplotlib at the top

    # Agg before any drawing: reports are written on servers and in CI with no display.
    matplotlib.use("Agg")
    from matplotlib.figure import Figure  # lazy (start-up)

    return Figure(figsize=figsize, dpi=_DPI, layout="constrained")


# --------------------------------------------------------------------------- plots


def _tolerances(campaigns: list[_Campaign]) -> list[float]:
    return sorted({c.tolerance for c in campaigns})


def _psd_band(ax: Axes, tolerances: list[float], *, vertical: bool = True) -> None:
    """The PSD tolerance band (one per distinct tolerance of the campaigns shown)."""
    span = ax.axvspan if vertical else ax.axhspan
    for tol in tolerances or [DEFAULT_TOLERANCE_M]:
        band = span(-tol, tol, color="tab:green", alpha=0.18, label=f"PSD tolerance ±{tol:g} m")
        band.set_zorder(0)


def _error_histogram(campaigns: list[_Campaign]) -> Figure:
    """Overlaid step histograms; the far tails are gathered in the outermost bins and counted."""
    fig = _figure((10.0, 4.8))
    ax = fig.add_subplot()
    finite = [c.error[np.isfinite(c.error)] for c in campaigns]
    pooled = np.concatenate(finite) if finite else np.zeros(0)
    if pooled.size == 0:
        ax.text(0.5, 0.5, "no finite stop errors", transform=ax.transAxes, ha="center")
        return fig
    lo_all, hi_all = float(pooled.min()), float(pooled.max())
    lo_core, hi_core = (float(q) for q in np.quantile(pooled, (0.0005, 0.9995)))
    lo = min(-0.6, lo_core)
    hi = max(0.6, hi_core)
    # Far outliers would squeeze the core into a few bins: clip them unless they are close.
    margin = 0.5 * (hi - lo)
    lo = min(lo, lo_all) if lo_all >= lo - margin else lo
    hi = max(hi, hi_all) if hi_all <= hi + margin else hi
    n_max = max(e.size for e in finite)
    edges = np.linspace(lo, hi, int(np.clip(math.sqrt(n_max), 20, 100)) + 1)
    _psd_band(ax, _tolerances(campaigns))
    ax.axvline(0.0, color="tab:green", lw=1.2)
    notes: list[str] = []
    for c, e in zip(campaigns, finite, strict=True):
        below, above = int(np.count_nonzero(e < lo)), int(np.count_nonzero(e > hi))
        ax.hist(
            np.clip(e, lo, hi),
            bins=edges.tolist(),
            histtype="step",
            lw=1.6,
            color=c.color,
            label=f"{c.name} (n = {c.runs:,})",
        )
        if below or above:
            notes.append(f"{c.name}: {below} below {lo:+.2f} m, {above} beyond {hi:+.2f} m (in the end bins)")
    if n_max >= 1000:
        ax.set_yscale("log")
        ax.set_ylabel("runs per bin (log scale)")
    else:
        ax.set_ylabel("runs per bin")
    ax.set_xlim(lo, hi)
    ax.set_xlabel("stop error (m, + = overrun)")
    ax.set_title("stop error", fontsize=11)
    ax.grid(True, alpha=0.4)
    ax.legend(loc="upper left", fontsize=9, framealpha=0.9)
    if notes:
        ax.text(
            0.99,
            0.98,
            "\n".join(notes),
            transform=ax.transAxes,
            ha="right",
            va="top",
            fontsize=8,
            bbox={"boxstyle": "round,pad=0.3", "fc": "white", "ec": "0.7", "alpha": 0.9},
        )
    return fig


def _ecdf_points(abs_error: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Sorted |error| and F = i/n, thinned to a few thousand points but complete in the tail."""
    x = np.sort(abs_error)
    n = x.size
    f = np.arange(1, n + 1, dtype=np.float64) / n
    if n > _ECDF_POINTS + _ECDF_TAIL_POINTS:
        keep = np.unique(
            np.concatenate(
                [np.linspace(0, n - 1, _ECDF_POINTS).astype(np.int64), np.arange(n - _ECDF_TAIL_POINTS, n)]
            )
        )
        x, f = x[keep], f[keep]
    return x, f


def _abs_error_cdf(campaigns: list[_Campaign]) -> Figure:
    """Left the CDF of |error| over the bulk of the runs; right its complement on a log scale, to the
    largest miss."""
    fig = _figure((10.0, 4.4))
    cdf_ax, tail_ax = fig.subplots(1, 2)
    bulk_max = 0.6  # the CDF panel: up to the 99.5th percentile, where the bands are read
    tail_max = 0.6
    n_max = 1
    for c in campaigns:
        e = np.abs(c.error[np.isfinite(c.error)])
        if e.size == 0:
            continue
        x, f = _ecdf_points(e)
        n_max = max(n_max, e.size)
        bulk_max = max(bulk_max, 1.25 * float(np.percentile(e, 99.5)))
        tail_max = max(tail_max, float(x[-1]) * 1.05)
        cdf_ax.step(x, f, where="post", color=c.color, ls=c.linestyle, lw=1.6, label=c.name)
        # P(|error| > x) is 0 from the largest |error| on: end the log-scale curve there at 1/n.
        exceed = 1.0 - f
        shown = exceed > 0.0
        if shown.any():
            tx = np.append(x[shown], x[-1])
            ty = np.append(exceed[shown], exceed[shown][-1])
            tail_ax.step(tx, ty, where="post", color=c.color, ls=c.linestyle, lw=1.6, label=c.name)
    for ax, right in ((cdf_ax, min(bulk_max, tail_max)), (tail_ax, tail_max)):
        ax.axvline(0.30, color="tab:green", ls=":", lw=1.4, label="0.30 m")
        for tol in _tolerances(campaigns):
            ax.axvline(tol, color="tab:green", ls="--", lw=1.4, label=f"{tol:g} m (PSD)")
        ax.set_xlim(0.0, right)
        ax.set_xlabel("|stop error| (m)")
        ax.grid(True, alpha=0.4)
    cdf_ax.set_ylim(0.0, 1.02)
    cdf_ax.set_ylabel("fraction of runs with |error| ≤ x")
    cdf_ax.set_title("empirical CDF of |stop error|", fontsize=11)
    cdf_ax.legend(loc="lower right", fontsize=9, framealpha=0.9)
    tail_ax.set_yscale("log")
    tail_ax.set_ylim(0.5 / n_max, 1.5)
    tail_ax.set_ylabel("fraction of runs with |error| > x")
    tail_ax.set_title("tail: 1 − CDF (log scale), to the largest miss", fontsize=11)
    return fig


def _as_float(values: np.ndarray) -> np.ndarray:
    return np.asarray(values, dtype=np.float64)


def _varying_parameters(campaigns: list[_Campaign]) -> list[str]:
    """Parameter columns, in first-seen order, that take more than one value over all campaigns."""
    names: list[str] = []
    for c in campaigns:
        names.extend(p for p in parameter_columns(c.columns) if p not in names)
    varying = []
    for name in names:
        lo, hi = math.inf, -math.inf
        for c in campaigns:
            if name in c.columns:
                x = _as_float(c.columns[name])
                x = x[np.isfinite(x)]
                if x.size:
                    lo, hi = min(lo, float(x.min())), max(hi, float(x.max()))
        if hi > lo:
            varying.append(name)
    return varying


def _binned(x: np.ndarray, y: np.ndarray, discrete: bool) -> tuple[np.ndarray, np.ndarray]:
    """Bin centres and the 1st, 50th and 99th percentiles of y per bin (shape (3, bins)).

    A discrete parameter gets one bin per value, a continuous one equal-count bins.
    """
    if discrete:
        centres, index = np.unique(x, return_inverse=True)
    else:
        bins = int(np.clip(x.size // 200, 3, _MAX_BINS))
        edges = np.quantile(x, np.linspace(0.0, 1.0, bins + 1)[1:-1])
        index = np.searchsorted(edges, x, side="right")
    # Small integer keys: the stable sort is a radix sort, much cheaper than sorting x itself.
    order = np.argsort(index.astype(np.int16), kind="stable")
    counts = np.bincount(index, minlength=int(index.max()) + 1)
    keep = counts > 0
    cuts = np.cumsum(counts)[:-1]
    groups = [g for g in np.split(y[order], cuts) if g.size]
    if not discrete:
        centres = np.array([np.median(g) for g in np.split(x[order], cuts) if g.size])
    else:
        centres = centres[keep]
    stats = np.array([np.percentile(g, (1.0, 50.0, 99.0)) for g in groups]).T
    return centres, stats


def _distinct_values(arrays: list[np.ndarray]) -> np.ndarray:
    """The distinct values of the arrays if there are at most a few, else the first few of them."""
    head = np.unique(np.concatenate([a[:2_000] for a in arrays])) if arrays else np.zeros(0)
    if head.size > _DISCRETE_MAX_VALUES:
        return head  # clearly continuous: no need to sort everything
    return np.unique(np.concatenate(arrays))


def _driver_figures(campaigns: list[_Campaign], parameters: list[str]) -> list[Figure]:
    """Stop error against each varying parameter, one panel each, one or two figures."""
    from matplotlib.lines import Line2D  # lazy (start-up)

    if not parameters:
        return []
    parts = 1 if len(parameters) <= _PANELS_PER_FIGURE else 2
    # Full rows in the first figure, the rest in the second.
    per_figure = math.ceil(len(parameters) / parts / _PANEL_COLUMNS) * _PANEL_COLUMNS
    groups = [parameters[i : i + per_figure] for i in range(0, len(parameters), per_figure)]
    rng = np.random.default_rng(0)  # the same faint sample every time the report is written
    figures = []
    for number, names in enumerate(groups, start=1):
        cols = min(_PANEL_COLUMNS, len(names))
        rows = math.ceil(len(names) / cols)
        fig = _figure((3.4 * cols, 2.7 * rows + 0.9))
        axes = np.atleast_1d(fig.subplots(rows, cols, squeeze=False)).ravel()
        for ax, name in zip(axes, names, strict=False):
            _driver_panel(ax, campaigns, name, rng)
        for ax in axes[len(names) :]:
            ax.set_visible(False)
        suffix = f" ({number}/{len(groups)})" if len(groups) > 1 else ""
        fig.suptitle(f"what drives the misses{suffix}: stop error against each disturbance", fontsize=12)
        handles = [Line2D([], [], color=c.color, ls=c.linestyle, lw=2.0, label=c.name) for c in campaigns]
        if len(campaigns) > 1:
            fig.legend(handles=handles, loc="outside lower center", ncol=min(len(campaigns), 6), fontsize=9)
        figures.append(fig)
    return figures


def _driver_panel(ax: Axes, campaigns: list[_Campaign], name: str, rng: np.random.Generator) -> None:
    pairs = []
    for c in campaigns:
        if name not in c.columns:
            continue
        x, y = _as_float(c.columns[name]), c.error
        ok = np.isfinite(x) & np.isfinite(y)
        pairs.append((c, x[ok], y[ok]))
    total = sum(x.size for _, x, _ in pairs)
    values = _distinct_values([x for _, x, _ in pairs])
    discrete = values.size <= _DISCRETE_MAX_VALUES
    step = float(np.min(np.diff(values))) if values.size > 1 else 1.0
    binned = total > _BINNED_ABOVE
    _psd_band(ax, sorted({c.tolerance for c, _, _ in pairs}), vertical=False)
    ax.axhline(0.0, color="tab:green", lw=1.0)
    # The widest cloud first, the narrowest last (on top): a wide ato cloud must not hide the
    # TASC points. The spread is the 1st-99th percentile range of the error.
    spread = [float(np.subtract(*np.percentile(y, (99.0, 1.0)))) if y.size else 0.0 for _, _, y in pairs]
    order = sorted(range(len(pairs)), key=lambda j: -spread[j])
    for rank, i in enumerate(order):
        c, x, y = pairs[i]
        z = 2 + rank
        # Discrete values: spread the points (and the controllers) a little so they do not hide each other.
        shift = (i - (len(pairs) - 1) / 2) * 0.12 * step if discrete and len(pairs) > 1 else 0.0
        if binned and x.size >= 100:
            sample = rng.choice(x.size, size=min(_SCATTER_SAMPLE, x.size), replace=False)
            xs = x[sample] + shift
            if discrete:
                xs = xs + rng.uniform(-0.04, 0.04, xs.size) * step
            ax.scatter(xs, y[sample], s=2, color=c.color, alpha=0.12, linewidths=0, rasterized=True, zorder=z)
            centres, (p1, p50, p99) = _binned(x, y, discrete)
            if discrete:
                ax.errorbar(
                    centres + shift,
                    p50,
                    yerr=(p50 - p1, p99 - p50),
                    fmt="o",
                    ms=4,
                    color=c.color,
                    capsize=3,
                    lw=1.2,
                    zorder=z + 0.5,
                )
            else:
                ax.plot(centres, p50, color=c.color, ls=c.linestyle, lw=1.8, zorder=z + 0.5)
                ax.plot(centres, p1, color=c.color, lw=1.0, ls="--", zorder=z + 0.5)
                ax.plot(centres, p99, color=c.color, lw=1.0, ls="--", zorder=z + 0.5)
        else:
            xs = x + shift
            if discrete:
                xs = xs + rng.uniform(-0.04, 0.04, xs.size) * step
            alpha = 0.6 if x.size <= 2_000 else 0.25
            ax.scatter(
                xs, y, s=6 if x.size <= 2_000 else 2, color=c.color, alpha=alpha, linewidths=0, zorder=z
            )
    if discrete and values.size <= 3 and np.all(np.isin(values, (0.0, 1.0))):
        ax.set_xticks([0.0, 1.0], ["no", "yes"])
    ax.set_title(name, fontsize=9)
    ax.set_ylabel("stop error (m)", fontsize=8)
    ax.tick_params(labelsize=7)
    ax.grid(True, alpha=0.4)
    if binned:
        ax.text(
            0.02,
            0.97,
            "median (1st, 99th percentile dashed)",
            transform=ax.transAxes,
            ha="left",
            va="top",
            fontsize=7,
            color="0.3",
        )


def _profile(replay: Replay, c: _Campaign, run: int) -> tuple[np.ndarray, np.ndarray]:
    """The replayed profile as (position − stopping point, km/h), as in the single-stop plot."""
    distance, speed = replay(c.path, run)
    d = np.asarray(distance, dtype=np.float64)
    v = np.asarray(speed, dtype=np.float64)
    if d.ndim != 1 or v.shape != d.shape or d.size == 0:
        raise RailstopError(
            f"replay of {c.name} run {run}: expected two 1-D arrays of one length "
            f"(got shapes {d.shape} and {v.shape})"
        )
    first = d[np.isfinite(d)]
    # A remaining distance is positive before the stop: turn it into position − stopping point.
    x = -d if first.size and first[0] > 0.0 else d
    return x, v


def _worst_profiles(c: _Campaign, rows: np.ndarray, replay: Replay) -> Figure:
    fig = _figure((10.0, 4.6))
    grid = fig.add_gridspec(1, 2, width_ratios=(4.0, 1.0))
    ax = fig.add_subplot(grid[0, 0])
    zoom = fig.add_subplot(grid[0, 1])
    _psd_band(ax, [c.tolerance])
    zoom.axvspan(-c.tolerance, c.tolerance, color="tab:green", alpha=0.18, zorder=0)
    for a in (ax, zoom):
        a.axvline(0.0, color="tab:green", lw=1.3)
    # The wheel detectors of the station (where the wayside measures the train and commands).
    detectors = c.manifest.get("detectors_before_stop_m")
    if isinstance(detectors, list):
        for j, d in enumerate(detectors):
            if isinstance(d, (int, float)):
                ax.axvline(-float(d), color="0.45", ls="--", lw=0.9, label="detectors" if j == 0 else None)
    run_ids = np.asarray(c.columns["run"])
    received = c.columns.get("commands_received")
    sent = c.columns.get("commands_sent")
    finals: list[float] = []
    v_top = 1.0
    profiles = []
    for k, row in enumerate(rows):
        run = int(run_ids[row])
        x, v = _profile(replay, c, run)
        profiles.append((x, v))
        colour = _PROFILE_COLORS[k % len(_PROFILE_COLORS)]
        label = f"run {run}: {float(c.error[row]):+.3f} m"
        if received is not None and sent is not None:
            label += f", {int(received[row])} of {int(sent[row])} commands received"
        ax.plot(x, v, color=colour, lw=1.4, label=label)
        zoom.plot(x, v, color=colour, lw=1.3)
        for a in (ax, zoom):
            a.plot([x[-1]], [v[-1]], marker="o", ms=5, color=colour, ls="none", zorder=5, clip_on=False)
        finals.append(float(x[-1]))
        if np.isfinite(v).any():
            v_top = max(v_top, float(np.nanmax(v)))
    left = min(-3.0, min(finals) - 1.0)
    right = max(1.0, max(finals) + 1.0)
    z_top = 1.0
    for x, v in profiles:
        window = (x >= left) & (x <= right) & np.isfinite(v)
        if window.any():
            z_top = max(z_top, float(np.max(v[window])))
    zoom.set_xlim(left, right)
    zoom.set_ylim(0.0, z_top * 1.15)
    zoom.set_title("last metres", fontsize=11)
    zoom.set_xlabel("to stopping point (m)", fontsize=9)
    zoom.set_ylabel("speed (km/h)", fontsize=9)
    zoom.tick_params(labelsize=8)
    zoom.grid(True, alpha=0.4)
    ax.set_ylim(0.0, v_top * 1.12)
    ax.set_xlabel("distance to the stopping point (m)")
    ax.set_ylabel("speed (km/h)")
    ax.set_title(f"{c.name}: speed over distance of the {rows.size} worst runs", fontsize=11)
    if c.provenance:
        fig.text(0.005, 0.005, footer(c.provenance), fontsize=6.5, color="0.4", ha="left", va="bottom")
    ax.grid(True, alpha=0.4)
    ax.legend(loc="lower left", fontsize=8, framealpha=0.9)
    return fig


# --------------------------------------------------------------------------- HTML

_CSS = """
body { font-family: system-ui, -apple-system, "Segoe UI", sans-serif; margin: 1.5em auto; max-width: 1150px;
       padding: 0 1em; color: #222; }
h1 { font-size: 1.5em; margin-bottom: 0.2em; }
h2 { font-size: 1.2em; margin-top: 1.6em; border-bottom: 1px solid #ccc; padding-bottom: 0.2em; }
h3 { font-size: 1.05em; }
table { border-collapse: collapse; font-size: 0.88em; margin: 0.6em 0; }
th, td { border: 1px solid #ccc; padding: 0.25em 0.5em; }
th { background: #f2f2f2; text-align: left; }
td.num { text-align: right; font-variant-numeric: tabular-nums; }
table.meta th { width: 17em; }
table.summary th, table.worst th { white-space: nowrap; }
.wide { overflow-x: auto; }
figure { margin: 1em 0; }
figure img { max-width: 100%; height: auto; }
figcaption, .note { color: #555; font-size: 0.88em; }
.swatch { display: inline-block; width: 0.9em; height: 0.9em; margin-right: 0.4em; vertical-align: -0.1em; }
"""


def _e(value: object) -> str:
    return html.escape(str(value), quote=True)


def _num(value: float, spec: str, unit: str = "") -> str:
    if not math.isfinite(value):
        return "—"
    return f"{value:{spec}}{unit}"


def _pct(fraction: float) -> str:
    return _num(100.0 * fraction, ".2f", " %")


def _small_pct(fraction: float) -> str:
    """A percentage that may be tiny: two decimals from 1 % up, three significant digits below."""
    value = 100.0 * fraction
    return _num(value, ".2f" if abs(value) >= 1.0 else "#.3g", " %")


def _stat_rows(tolerances: list[float]) -> list[tuple[str, Callable[[dict[str, Any]], str]]]:
    """The summary's rows: (label, the cell of one controller's statistics)."""
    tol = f"±{tolerances[0]:g} m" if len(tolerances) == 1 else "± its tolerance"
    over = f"+{tolerances[0]:g} m" if len(tolerances) == 1 else "+ its tolerance"
    return [
        ("runs", lambda s: f"{int(s['runs']):,}"),
        ("PSD tolerance", lambda s: f"±{float(s['tolerance_m']):g} m"),
        (f"within the PSD tolerance ({tol})", lambda s: _pct(float(s["within_tolerance"]))),
        ("within ±0.30 m", lambda s: _pct(float(s["within_0_30"]))),
        ("within ±0.50 m", lambda s: _pct(float(s["within_0_50"]))),
        ("mean (m)", lambda s: _num(float(s["mean_m"]), "+.3f")),
        ("std (m)", lambda s: _num(float(s["std_m"]), ".3f")),
        ("p99 |error| (m)", lambda s: _num(float(s["p99_abs_m"]), ".3f")),
        ("max |error| (m)", lambda s: _num(float(s["max_abs_m"]), ".3f")),
        (f"overruns > {over}", lambda s: f"{int(s['overruns']):,}"),
        (f"P(overrun > {over}), 95 % upper bound", lambda s: _small_pct(float(s["overrun_ci95_upper"]))),
        ("p99 max jerk (m/s³)", lambda s: _num(float(s["p99_max_jerk_mps3"]), ".2f")),
        ("mean stop time (s)", lambda s: _num(float(s["mean_stop_time_s"]), ".1f")),
        ("not stopped", lambda s: f"{int(s['not_stopped']):,}"),
        ("slid", lambda s: f"{int(s['slid']):,}"),
    ]


def _manifest_values(campaigns: list[_Campaign], getter: Callable[[dict[str, Any]], object]) -> str:
    values: list[str] = []
    for c in campaigns:
        value = getter(c.manifest)
        text = "—" if value is None or value == "" else str(value)
        if text not in values:
            values.append(text)
    return ", ".join(values)


def _disturbance_name(manifest: dict[str, Any]) -> object:
    d = manifest.get("disturbances")
    return d.get("name") if isinstance(d, dict) else d


def _img(path: Path, alt: str, caption: str) -> str:
    """The figure embedded in the page (a data URI): the report is one self-contained file."""
    data = base64.b64encode(path.read_bytes()).decode("ascii")
    return (
        f'<figure><img src="data:image/png;base64,{data}" alt="{_e(alt)}" data-file="{_e(path.name)}">'
        f"<figcaption>{_e(caption)}</figcaption></figure>"
    )


def _param_cell(values: np.ndarray, row: int) -> str:
    v = values[row]
    if values.dtype == bool:
        return "yes" if bool(v) else "no"
    if np.issubdtype(values.dtype, np.integer):
        return str(int(v))
    return _num(float(v), ".4g")


def _html(
    directory: Path,
    campaigns: list[_Campaign],
    *,
    figures: dict[str, Path],
    driver_pngs: list[Path],
    parameters: list[str],
    worst_rows: dict[str, np.ndarray],
    profile_pngs: dict[str, Path],
    replayed: bool,
    worst: int,
    written: dict[str, Any],
) -> str:
    station = _manifest_values(campaigns, lambda m: m.get("station"))
    sizes = {c.runs for c in campaigns}
    runs = (
        f"{next(iter(sizes)):,}" if len(sizes) == 1 else ", ".join(f"{c.name}: {c.runs:,}" for c in campaigns)
    )
    tolerances = _tolerances(campaigns)
    ran = ", ".join(
        sorted(
            {
                f"railstop {c.provenance.get('railstop', '?')}, {c.provenance.get('written_utc', '?')}"
                for c in campaigns
                if c.provenance
            }
        )
    )
    meta = [
        ("station", station),
        ("line", _manifest_values(campaigns, lambda m: m.get("line"))),
        ("vehicle", _manifest_values(campaigns, lambda m: m.get("vehicle"))),
        ("disturbance set", _manifest_values(campaigns, _disturbance_name)),
        ("seed", _manifest_values(campaigns, lambda m: m.get("seed"))),
        ("runs per controller", runs),
        ("controllers", ", ".join(c.name for c in campaigns)),
        ("PSD tolerance", ", ".join(f"±{t:g} m" for t in tolerances)),
        ("stop model version", _manifest_values(campaigns, lambda m: m.get("model_version"))),
        (
            "line and vehicle data (SHA-256)",
            _manifest_values(campaigns, lambda m: str(m.get("data_sha256", ""))[:16]),
        ),
        (
            "campaigns (SHA-256 of the manifest)",
            ", ".join(f"{c.name}: {manifest_sha256(c.manifest)[:16]}" for c in campaigns),
        ),
        ("campaigns run by", ran or "—"),
        ("report written by", f"railstop {written['railstop']}, {written['written_utc']}"),
        ("folder", str(directory)),
    ]
    out: list[str] = [
        "<!DOCTYPE html>",
        '<html lang="en"><head><meta charset="utf-8">',
        f"<title>railstop campaign report: {_e(station)}</title>",
        f"<style>{_CSS}</style></head><body>",
        f"<h1>Stopping campaign at {_e(station)}</h1>",
        '<table class="meta">',
        *(f"<tr><th>{_e(k)}</th><td>{_e(v)}</td></tr>" for k, v in meta),
        "</table>",
        "<h2>Summary</h2>",
    ]
    # At most SUMMARY_COLUMNS controllers side by side: with ten, two tables one under the other
    # instead of one behind a horizontal scroll.
    for k in range(0, len(campaigns), SUMMARY_COLUMNS):
        group = campaigns[k : k + SUMMARY_COLUMNS]
        out += [
            '<div class="wide"><table class="summary">',
            "<tr><th></th>"
            + "".join(
                f'<th><span class="swatch" style="background:{_e(_hex(c.color))}"></span>{_e(c.name)}</th>'
                for c in group
            )
            + "</tr>",
        ]
        for label, cell in _stat_rows(tolerances):
            cells = "".join(f'<td class="num">{_e(cell(c.stats))}</td>' for c in group)
            out.append(f"<tr><th>{_e(label)}</th>{cells}</tr>")
        out.append("</table></div>")
    out += [
        '<p class="note">A run that did not come to rest counts as outside every band; its error is the '
        "distance to the stopping point at the time limit. Mean, std and percentiles are over all runs. "
        "The bound on P(overrun) is the one-sided 95 % Clopper–Pearson upper bound "
        "from the overrun count.</p>",
        "<h2>Stop error</h2>",
        _img(
            figures["errors"],
            "stop-error histogram",
            "Stop error per controller; the shaded band is the PSD tolerance "
            f"({', '.join(f'±{t:g} m' for t in tolerances)}).",
        ),
        _img(
            figures["cdf"],
            "empirical CDF of |stop error|",
            "Empirical CDF of |stop error| (left) and its complement on a log scale (right), "
            f"with the 0.30 m reference and the PSD tolerance ({', '.join(f'{t:g} m' for t in tolerances)}).",
        ),
        "<h2>What drives the misses</h2>",
    ]
    if driver_pngs:
        out.append(
            f'<p class="note">Stop error against each disturbance parameter that varies in the campaign '
            f"({len(parameters)}: {_e(', '.join(parameters))}); panels with more than {_BINNED_ABOVE:,} "
            "points show the median (solid) and the 1st and 99th percentiles (dashed) per bin over a faint "
            "sample of the runs. The controller with the widest spread is drawn first, the narrowest on "
            "top, so that no controller hides another.</p>"
        )
        out += [
            _img(png, f"what drives the misses ({i + 1})", "Stop error against the disturbances.")
            for i, png in enumerate(driver_pngs)
        ]
    else:
        out.append('<p class="note">No disturbance parameter varies in these campaigns.</p>')

    out.append(f"<h2>Worst runs (the {worst} largest |error| per controller)</h2>")
    if worst == 0:
        out.append('<p class="note">No worst runs were asked for (worst = 0).</p>')
        out.append("</body></html>")
        return "\n".join(out) + "\n"
    if not replayed:
        out.append(
            '<p class="note">Speed profiles of the worst runs are not shown: the report was written '
            "without a replay function, so the runs were not re-simulated.</p>"
        )
    for c in campaigns:
        rows = worst_rows[c.name]
        out.append(f"<h3>{_e(c.name)}</h3>")
        if rows.size == 0:
            out.append('<p class="note">The campaign has no runs.</p>')
            continue
        # The parameters that vary in this campaign (a TASC run has no driver level: -1 in all).
        out += _worst_table(c, rows, [p for p in parameters if p in c.columns and _varies(c.columns[p])])
        if c.name in profile_pngs:
            out.append(
                _img(
                    profile_pngs[c.name],
                    f"{c.name}: worst runs",
                    f"{c.name}: speed over distance of the worst runs, re-simulated, with the detectors "
                    "and the commands each run received.",
                )
            )
    out.append(f'<p class="note">{_e(footer_text(written))}</p>')
    out.append("</body></html>")
    return "\n".join(out) + "\n"


def _in_controller_order(campaigns: list[_Campaign]) -> list[_Campaign]:
    """The built-in controllers in their own order (TASC, ATO, drivers), then the others by name."""
    from railstop.controllers import CONTROLLERS

    known = list(CONTROLLERS)

    def key(c: _Campaign) -> tuple[int, str]:
        return (known.index(c.controller) if c.controller in known else len(known), c.name)

    return sorted(campaigns, key=key)


def _varies(values: np.ndarray) -> bool:
    """Whether a column takes more than one value (NaN counted as one)."""
    if values.size == 0:
        return False
    if values.dtype.kind == "f":
        finite = values[np.isfinite(values)]
        distinct = np.unique(finite).size + (1 if finite.size < values.size else 0)
        return distinct > 1
    return np.unique(values).size > 1


def _worst_table(c: _Campaign, rows: np.ndarray, shown: list[str]) -> list[str]:
    """One column per run, one row per quantity: fits the page however many parameters vary."""
    cols = c.columns
    table: list[tuple[str, list[str]]] = [
        ("stop error (m)", [_num(float(c.error[r]), "+.3f") for r in rows]),
        ("stop time (s)", [_num(float(cols["stop_time_s"][r]), ".1f") for r in rows]),
        ("stopped", ["yes" if bool(cols["stopped"][r]) else "no" for r in rows]),
        ("slid", ["yes" if bool(cols["slid"][r]) else "no" for r in rows]),
    ]
    if "commands_received" in cols and "commands_sent" in cols:
        got, sent = cols["commands_received"], cols["commands_sent"]
        table.append(("commands received / sent", [f"{int(got[r])} / {int(sent[r])}" for r in rows]))
    table += [(p, [_param_cell(cols[p], int(r)) for r in rows]) for p in shown]
    head = "".join(f'<th class="num">{int(cols["run"][r])}</th>' for r in rows)
    out = ['<div class="wide"><table class="worst">', f"<tr><th>run</th>{head}</tr>"]
    for label, cells in table:
        out.append(
            f"<tr><th>{_e(label)}</th>" + "".join(f'<td class="num">{_e(v)}</td>' for v in cells) + "</tr>"
        )
    out.append("</table></div>")
    return out


def footer_text(written: dict[str, Any]) -> str:
    return footer(written)


def _hex(color: str) -> str:
    from matplotlib.colors import to_hex  # lazy (start-up)

    return str(to_hex(color))
