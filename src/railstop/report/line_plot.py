"""The time-distance (string-line) diagram of a line run: every train, stations, signals, stops.

Time runs left to right, chainage upwards (the R direction). Each train is
one line; where it stands at a platform the line is flat. Stations are
labelled bands, signals thin lines at their blocks' entries (fixed block);
under CBTC a lost train's protection zone is an orange box over the time it
stood (SPEC §4). A stop outside the PSD tolerance is a red cross, an
emergency brake a red triangle.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

# Agg before pyplot: plots are written on servers and in CI with no display.
matplotlib.use("Agg")

import matplotlib.pyplot as plt
from matplotlib.patches import Rectangle

from railstop.report.figures import write_figure
from railstop.sim.line import LineResult

_DPI = 120


def plot_line(result: LineResult, path: str | Path, *, title: str, footer: str = "") -> Path:
    """Write the string-line PNG of ``result`` to ``path``; return the path."""
    fig, ax = plt.subplots(figsize=(13, 7.5), layout="constrained")
    try:
        if result.signalling == "fixed-block":
            for y in result.signal_m:
                ax.axhline(y, color="0.85", lw=0.6, zorder=0)
        # SPEC §4: the protection zones of lost trains, over the time they stood.
        for i, z in enumerate(result.zones):
            end_s = min(z.released_s, result.duration_s)
            ax.add_patch(
                Rectangle(
                    (z.set_s / 60.0, z.start_m),
                    (end_s - z.set_s) / 60.0,
                    z.end_m - z.start_m,
                    facecolor="#fdae6b",
                    edgecolor="#e6550d",
                    alpha=0.6,
                    lw=0.8,
                    zorder=1,
                    label="protection zone (lost train)" if i == 0 else None,
                )
            )
        for name, y in result.station_m:
            ax.axhspan(y - 120.0, y, color="#deebf7", zorder=0)
            ax.text(0.0, y - 60.0, f" {name}", va="center", ha="left", fontsize=8, color="#08519c")
        cmap = plt.get_cmap("tab20")
        for k, (ts, xs) in enumerate(result.samples):
            if ts:
                ax.plot([t / 60.0 for t in ts], xs, lw=1.1, color=cmap(k % 20), label=f"train {k}")
        stop_m = dict(result.station_m)
        marks = (
            ([s for s in result.stops if not s.within_tolerance], "x", "stop outside the PSD tolerance"),
            ([s for s in result.stops if s.emergency_brake is not None], "^", "emergency brake"),
        )
        for stops, marker, label in marks:
            if stops:
                ax.plot(
                    [s.arrive_s / 60.0 for s in stops],
                    [stop_m[s.station] + s.error_m for s in stops],
                    marker,
                    color="#d62728",
                    ms=8,
                    label=label,
                )
        ax.set_xlabel("time (min)")
        ax.set_ylabel("chainage (m), trains run upwards")
        ax.set_xlim(0.0, result.duration_s / 60.0)
        ax.grid(True, axis="x", alpha=0.3)
        if len(result.samples) <= 20:
            ax.legend(loc="upper left", fontsize=7, ncol=2, frameon=False, bbox_to_anchor=(1.0, 1.0))
        ax.set_title(title, fontsize=11, fontweight="bold")
        if footer:
            fig.text(0.005, 0.002, footer, fontsize=7, color="0.4", ha="left", va="bottom")
        return write_figure(fig, Path(path), _DPI)
    finally:
        plt.close(fig)
