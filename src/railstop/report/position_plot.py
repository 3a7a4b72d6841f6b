"""The picture of a position run (SPEC §2): position error against chainage.

Three panels over the line's chainage: the train's speed (the detection
delay costs speed × delay), the raw odometer error (it grows with distance),
and the errors of the corrected position (SPEC §2 method) and of the
corrected position with the learned calibration. Track-circuit boundaries
are thin vertical lines, tunnels are shaded (blue: a satellite-signal
repeater covers it; red hatching: a GNSS shadow), stations are marked, and
the low-adhesion patches are bars on the speed panel (slide: braking zone,
slip: traction zone).
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

# Agg before pyplot: plots are written on servers and in CI with no display.
matplotlib.use("Agg")

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.axes import Axes
from matplotlib.patches import Patch

from railstop.errors import RailstopError
from railstop.quantities import KMH_PER_MPS
from railstop.report.figures import write_figure
from railstop.sim.position_run import PositionRunResult

_FIGSIZE_IN = (12.0, 9.0)
_DPI = 110
_SHADOW_FACE = (1.0, 0.9, 0.9, 1.0)
_SHADOW_HATCH = (0.85, 0.45, 0.45, 0.6)


def plot_position_run(result: PositionRunResult, path: str | Path, *, run: int = 0, footer: str = "") -> Path:
    """Write the three-panel PNG of run ``run`` to ``path``; return the path. ``footer``: where the
    plot comes from (``railstop.provenance.footer``), small at the bottom."""
    out = Path(path)
    if not 0 <= run < result.n:
        raise RailstopError(f"run: no run {run} in a result of {result.n} runs")
    if not out.parent.is_dir():
        raise RailstopError(f"{out}: directory {str(out.parent)!r} does not exist")
    summary = result.summary(run)
    grid = result.errors_vs_chainage(run)
    x = grid["chainage_m"]

    fig, (ax_v, ax_raw, ax_err) = plt.subplots(
        3,
        1,
        figsize=_FIGSIZE_IN,
        dpi=_DPI,
        sharex=True,
        layout="constrained",
        gridspec_kw={"height_ratios": (1.0, 1.6, 2.4)},
    )
    try:
        for ax in (ax_v, ax_raw, ax_err):
            _line_features(ax, result)
        true_x = result.true_m[:, run]
        ax_v.plot(true_x, result.speed_mps[:, run] * KMH_PER_MPS, color="tab:blue", lw=1.3)
        _patches(ax_v, result, run)
        ax_v.set_ylabel("speed (km/h)")
        ax_v.set_ylim(bottom=0.0)
        _station_names(ax_v, result)

        ax_raw.plot(x, grid["raw"], color="tab:red", lw=1.5, label="raw odometer")
        ax_raw.plot(x, grid["corrected"], color="tab:orange", lw=1.0, label="corrected (SPEC §2)")
        ax_raw.plot(x, grid["calibrated"], color="tab:green", lw=1.0, label="corrected + learned calibration")
        ax_raw.axhline(0.0, color="0.3", lw=0.8)
        ax_raw.set_ylabel("error (m)")
        ax_raw.legend(loc="upper left", fontsize=9, framealpha=0.9)
        ax_raw.set_title(
            f"raw odometer: {summary['raw_final_m']:+.1f} m at the end, max |error| "
            f"{summary['raw_max_abs_m']:.1f} m (diameter error {summary['diameter_error_pct']:g} %, "
            f"{summary['slide_patches']} slide and {summary['slip_patches']} slip patches)",
            fontsize=10,
        )

        ax_err.plot(x, grid["corrected"], color="tab:orange", lw=1.3, label="corrected (SPEC §2)")
        ax_err.plot(x, grid["calibrated"], color="tab:green", lw=1.3, label="corrected + learned calibration")
        ax_err.axhline(0.0, color="0.3", lw=0.8)
        lim = max(5.0, 1.15 * float(np.max(np.abs(np.concatenate([grid["corrected"], grid["calibrated"]])))))
        ax_err.set_ylim(-lim, lim)
        ax_err.set_ylabel("error (m)")
        ax_err.set_xlabel("chainage (m)")
        s = summary
        ax_err.set_title(
            f"corrected: p99 |error| {s['corrected_p99_abs_m']:.2f} m, max {s['corrected_max_abs_m']:.2f} m; "
            f"calibrated: p99 {s['calibrated_p99_abs_m']:.2f} m, max {s['calibrated_max_abs_m']:.2f} m  "
            f"({s['corrections']} corrections; learned scale error {s['learned_scale_error_pct']:+.2f} %, "
            f"delay {s['learned_delay_s']:.3f} s)",
            fontsize=10,
        )
        handles, _ = ax_err.get_legend_handles_labels()
        handles += [
            Patch(facecolor="tab:blue", alpha=0.15, label="tunnel with repeater"),
            Patch(facecolor=_SHADOW_FACE, edgecolor=_SHADOW_HATCH, hatch="//", label="tunnel, GNSS shadow"),
        ]
        ax_err.legend(handles=handles, loc="lower left", fontsize=9, framealpha=0.9, ncol=2)
        ax_err.set_xlim(float(x[0]) - 20.0, float(x[-1]) + 20.0)

        gnss = "GNSS time" if summary["gnss"] else "no GNSS (clocks free-run)"
        rep = "repeaters" if summary["repeaters"] else "no repeaters"
        fig.suptitle(
            f"Position error against chainage: {summary['line']}, seed {summary['seed']}, "
            f"{summary['distance_m']:.0f} m, {gnss}, {rep}",
            fontsize=12,
            fontweight="bold",
        )
        if footer:
            fig.text(0.005, 0.002, footer, fontsize=7, color="0.4", ha="left", va="bottom")
        out = write_figure(fig, out, _DPI)
    finally:
        plt.close(fig)
    return out


def _line_features(ax: Axes, result: PositionRunResult) -> None:
    for b in result.circuits_m:
        ax.axvline(float(b), color="0.75", lw=0.5, zorder=0)
    for start, end, repeater in result.tunnels:
        if repeater:
            ax.axvspan(start, end, color="tab:blue", alpha=0.15, lw=0, zorder=0)
        else:
            ax.axvspan(
                start, end, facecolor=_SHADOW_FACE, edgecolor=_SHADOW_HATCH, hatch="//", lw=0, zorder=0
            )
    for s in result.stops_m:
        ax.axvline(float(s), color="0.2", ls="--", lw=0.9, zorder=1)
    ax.grid(True, axis="y", alpha=0.4)


def _station_names(ax: Axes, result: PositionRunResult) -> None:
    top = ax.get_xaxis_transform()
    for name, s in zip(result.station_names, result.stops_m, strict=False):
        ax.text(float(s), 1.02, name, transform=top, ha="center", va="bottom", fontsize=9)


def _patches(ax: Axes, result: PositionRunResult, run: int) -> None:
    ymax = ax.get_ylim()[1]
    y = 0.06 * ymax
    for z in range(result.patch_start_m.shape[1]):
        a, b = float(result.patch_start_m[run, z]), float(result.patch_end_m[run, z])
        if not np.isfinite(a):
            continue
        braking = bool(result.patch_is_braking[z])
        ax.plot(
            [a, b],
            [y, y],
            color="tab:red" if braking else "tab:purple",
            lw=5,
            solid_capstyle="butt",
        )
        ax.text((a + b) / 2, y * 1.6, "slide" if braking else "slip", ha="center", fontsize=8)
