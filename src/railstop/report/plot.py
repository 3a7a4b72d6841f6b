"""The picture of one stop: speed over distance, decelerations over time.

Top panel: the braking curve against distance to the stopping point, with the
detectors, the stopping point and its platform-screen-door tolerance, and
where the train came to rest. Bottom panel: what the wayside unit commanded
at each detector, what the ECU was asked for, what the brakes gave and what
the train did, so a stop error can be traced to the command that caused it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import matplotlib

# Agg before pyplot: plots are written on servers and in CI with no display.
matplotlib.use("Agg")

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.axes import Axes
from matplotlib.transforms import blended_transform_factory

from railstop.config.platform import LAMP_NAMES
from railstop.errors import RailstopError
from railstop.onboard.driver import (
    ACT_BRAKE,
    ACT_COAST,
    ACT_CREEP_FORWARD,
    ACT_HOLD,
    ACT_POWER,
    ACT_REVERSE,
    ACT_WAIT,
)
from railstop.quantities import KMH_PER_MPS
from railstop.report.figures import write_figure
from railstop.sim.engine import Trace

_FIGSIZE_IN = (10.0, 8.0)
_DPI = 120
_REST_MPS = 0.01  # below this the last trace sample counts as "at rest"


def plot_stop(
    trace: Trace,
    *,
    run: int,
    station_name: str,
    stop_point_m: float,
    detector_positions_m: Sequence[float],
    passage_times_s: Sequence[float],
    commands: list[dict[str, Any]],
    title: str,
    path: str | Path,
    tolerance_m: float,
    footer: str = "",
) -> Path:
    """Write the two-panel PNG of run ``run`` of ``trace`` to ``path``; return the path.

    ``tolerance_m``: the station's PSD tolerance (the green band); ``footer``: a
    small line at the bottom saying where the plot comes from (version, date,
    seed, input hash: see ``railstop.provenance.footer``).

    ``passage_times_s[i]`` is when detector i was passed (NaN if never).
    ``commands`` are command records (``BatchResult.commands``: the wayside
    unit's ``CR_*`` columns as dicts); rows of other runs of the batch (their
    ``"run"`` differs) are left out.
    """
    out = Path(path)
    n_runs = trace.t_s.shape[1] if trace.t_s.ndim == 2 else 0
    if not 0 <= run < n_runs:
        raise RailstopError(f"run: no column {run} in a trace of {n_runs} runs")
    if not out.parent.is_dir():
        raise RailstopError(f"{out}: directory {str(out.parent)!r} does not exist")
    mine = [c for c in commands if int(c.get("run", run)) == run]

    # The zoom on the last metres gets its own axes beside the speed panel: an
    # inset would always sit on some detector line or the braking curve.
    fig = plt.figure(figsize=_FIGSIZE_IN, dpi=_DPI, layout="constrained")
    grid = fig.add_gridspec(2, 2, width_ratios=(4.0, 1.0))
    top = fig.add_subplot(grid[0, 0])
    zoom = fig.add_subplot(grid[0, 1])
    bottom = fig.add_subplot(grid[1, :])
    try:
        _speed_panel(
            top,
            zoom,
            trace,
            run=run,
            station_name=station_name,
            stop_point_m=stop_point_m,
            detector_positions_m=detector_positions_m,
            tolerance_m=tolerance_m,
        )
        _decel_panel(bottom, trace, run=run, passage_times_s=passage_times_s, commands=mine)
        fig.suptitle(title, fontsize=13, fontweight="bold")
        if footer:
            fig.text(0.005, 0.002, footer, fontsize=7, color="0.4", ha="left", va="bottom")
        out = write_figure(fig, out, _DPI)
    finally:
        # pyplot keeps every figure alive until closed; a campaign plots many.
        plt.close(fig)
    return out


def _speed_panel(
    ax: Axes,
    zoom: Axes,
    trace: Trace,
    *,
    run: int,
    station_name: str,
    stop_point_m: float,
    detector_positions_m: Sequence[float],
    tolerance_m: float,
) -> None:
    x = trace.position_m[:, run] - stop_point_m
    v_kmh = trace.speed_mps[:, run] * KMH_PER_MPS
    det_x = np.asarray(detector_positions_m, dtype=np.float64) - stop_point_m
    final_x = float(x[-1])
    at_rest = abs(float(trace.speed_mps[-1, run])) < _REST_MPS

    ax.plot(x, v_kmh, color="tab:blue", lw=1.8, label="speed")
    limit_kmh = trace.limit_mps[:, run] * KMH_PER_MPS
    if np.isfinite(limit_kmh).any():
        # SPEC §3 driver controllers: the held ATS code / the ATC indicated speed.
        ax.step(x, limit_kmh, where="post", color="tab:orange", ls="-.", lw=1.5, label="speed code (ADU)")
    band = ax.axvspan(
        -tolerance_m, tolerance_m, color="tab:green", alpha=0.25, label=f"PSD tolerance ±{tolerance_m:g} m"
    )
    band.set_zorder(0)
    ax.axvline(0.0, color="tab:green", lw=1.5, label="stopping point")
    # One legend entry for all detectors; each line is named at the top of the axes.
    top_label = blended_transform_factory(ax.transData, ax.transAxes)
    lo = min(float(np.min(x)), float(np.min(det_x, initial=0.0)))
    hi = max(final_x, 0.0)
    span = hi - lo
    for i, dx in enumerate(det_x):
        ax.axvline(dx, color="0.35", ls="--", lw=1.0, label="detectors" if i == 0 else None)
        # A name right of its line unless the next line (detector or stopping
        # point) is too close, as for the last detector a few metres out.
        following = [d for d in (*det_x, 0.0) if d > dx]
        crowded = bool(following) and min(following) - dx < 0.05 * span
        ax.text(
            dx,
            0.98,
            f"D{i + 1} " if crowded else f" D{i + 1}",
            transform=top_label,
            va="top",
            ha="right" if crowded else "left",
            fontsize=9,
        )
    ax.plot(
        [final_x],
        [v_kmh[-1]],
        marker="o",
        ms=7,
        color="tab:red",
        ls="none",
        zorder=5,
        label="train at rest" if at_rest else "end of trace",
    )
    ax.annotate(
        f"stop error {final_x:+.3f} m" if at_rest else f"not at rest ({v_kmh[-1]:.1f} km/h)",
        xy=(final_x, float(v_kmh[-1])),
        xytext=(-12, 28),
        textcoords="offset points",
        ha="right",
        fontsize=9,
        color="tab:red",
        arrowprops={"arrowstyle": "->", "color": "tab:red", "lw": 1.0},
    )
    ax.set_xlim(lo - 0.02 * span, hi + 0.06 * span)
    top_kmh = np.nanmax(np.concatenate([v_kmh, limit_kmh[np.isfinite(limit_kmh)]]))
    ax.set_ylim(0.0, max(float(top_kmh), 1.0) * 1.12)
    ax.set_xlabel("distance to the stopping point (m)")
    ax.set_ylabel("speed (km/h)")
    ax.set_title(f"{station_name}: speed over distance", fontsize=11)
    ax.grid(True, alpha=0.4)
    ax.legend(loc="lower left", fontsize=9, framealpha=0.9)
    _stop_zoom(zoom, x, v_kmh, final_x, tolerance_m)


def _stop_zoom(inset: Axes, x: np.ndarray, v_kmh: np.ndarray, final_x: float, tolerance_m: float) -> None:
    """The last metres: at 250 m full scale the tolerance band is a few pixels wide."""
    left = min(-3.0, final_x - 1.0)
    right = max(1.0, final_x + 1.0)
    window = (x >= left) & (x <= right)
    inset.axvspan(-tolerance_m, tolerance_m, color="tab:green", alpha=0.25, zorder=0)
    inset.axvline(0.0, color="tab:green", lw=1.2)
    inset.plot(x, v_kmh, color="tab:blue", lw=1.5)
    inset.plot([final_x], [v_kmh[-1]], marker="o", ms=6, color="tab:red", ls="none", zorder=5)
    inset.set_xlim(left, right)
    v_top = float(np.max(v_kmh[window])) if window.any() else 1.0
    inset.set_ylim(0.0, max(v_top, 1.0) * 1.15)
    inset.set_title("last metres", fontsize=11)
    inset.set_xlabel("to stopping point (m)", fontsize=9)
    inset.set_ylabel("speed (km/h)", fontsize=9)
    inset.tick_params(labelsize=8)
    inset.grid(True, alpha=0.4)


# SPEC §3 driver actions: name and colour of the band under the curves.
_ACTIONS = {
    ACT_HOLD: ("holds speed", "0.75"),
    ACT_COAST: ("coasts", "0.9"),
    ACT_POWER: ("takes power", "tab:orange"),
    ACT_BRAKE: ("brakes", "tab:blue"),
    ACT_CREEP_FORWARD: ("creeps forward", "tab:green"),
    ACT_REVERSE: ("reverses", "tab:red"),
    ACT_WAIT: ("waits at the stand", "gold"),
}


def _driver_timeline(ax: Axes, trace: Trace, run: int) -> None:
    """The driver's actions as a band at the foot of the axes, the lamps lit at each stand and
    the supervision's emergency brake (SPEC §3)."""
    t = trace.t_s[:, run]
    action = trace.driver_action[:, run]
    foot = blended_transform_factory(ax.transData, ax.transAxes)
    shown: set[int] = set()
    start = 0
    for i in range(1, t.size + 1):
        if i < t.size and action[i] == action[start]:
            continue
        code = int(action[start]) if np.isfinite(action[start]) else -1
        if code in _ACTIONS:
            name, colour = _ACTIONS[code]
            ax.axvspan(
                t[start],
                t[min(i, t.size - 1)],
                ymin=0.0,
                ymax=0.04,
                color=colour,
                alpha=0.8,
                label=f"driver {name}" if code not in shown else None,
            )
            shown.add(code)
        start = i
    lamp = trace.lamp[:, run]
    for j in np.flatnonzero(np.isfinite(lamp) & (lamp > 0)):
        if j > 0 and lamp[j - 1] == lamp[j]:
            continue
        name = LAMP_NAMES.get(int(lamp[j]), "?")
        ax.text(t[j], 0.06, f"lamp {name}", transform=foot, fontsize=8, rotation=90, va="bottom", ha="right")
    eb = np.flatnonzero(trace.supervision[:, run] == 2.0)
    if eb.size:
        ax.axvline(t[eb[0]], color="tab:red", lw=2.0, label="emergency brake (supervision)")


def _decel_panel(
    ax: Axes,
    trace: Trace,
    *,
    run: int,
    passage_times_s: Sequence[float],
    commands: list[dict[str, Any]],
) -> None:
    t = trace.t_s[:, run]
    target = trace.target_decel_mps2[:, run]
    demand = trace.demand_decel_mps2[:, run]
    brake = trace.brake_decel_mps2[:, run]
    total = -trace.accel_mps2[:, run]

    driver = bool(np.isfinite(trace.driver_action[:, run]).any())
    # The target is drawn wide and underneath: the demand often equals it exactly.
    ax.step(
        t,
        target,
        where="post",
        color="tab:orange",
        lw=3.5,
        alpha=0.7,
        zorder=1,
        label="needed, as the driver judges" if driver else "commanded (target)",
    )
    if driver:
        _driver_timeline(ax, trace, run)
    ax.plot(t, demand, color="tab:purple", lw=1.2, ls="--", zorder=3, label="ECU demand")
    ax.plot(t, brake, color="tab:blue", lw=1.4, label="brake deceleration")
    ax.plot(t, total, color="tab:red", lw=1.0, alpha=0.8, label="train deceleration (−accel)")

    top_label = blended_transform_factory(ax.transData, ax.transAxes)
    first = True
    for i, tp in enumerate(passage_times_s):
        if not math.isfinite(tp):
            continue  # never passed: nothing to mark
        ax.axvline(tp, color="0.35", ls="--", lw=1.0, label="detector passage" if first else None)
        ax.text(tp, 0.98, f" D{i + 1}", transform=top_label, va="top", ha="left", fontsize=9)
        first = False
    if commands:
        ct = [float(c["t_s"]) for c in commands]
        cy = [float(c["command_decel_mps2"]) for c in commands]
        ax.plot(
            ct,
            cy,
            marker="D",
            ms=6,
            color="black",
            mfc="gold",
            ls="none",
            zorder=5,
            label="command sent",
        )
        for c, xx, yy in zip(commands, ct, cy, strict=True):
            det = c.get("detector")
            if det is None or int(det) < 0:
                continue
            ax.annotate(
                f"D{int(det) + 1}",
                xy=(xx, yy),
                xytext=(4, -13),
                textcoords="offset points",
                fontsize=8,
                # A light box keeps the name readable where it crosses the curves.
                bbox={"boxstyle": "round,pad=0.1", "fc": "white", "ec": "none", "alpha": 0.75},
            )

    values = np.concatenate([a[np.isfinite(a)] for a in (target, demand, brake, total)])
    hi = max(float(values.max()) if values.size else 0.0, 0.1)
    lo = min(float(values.min()) if values.size else 0.0, 0.0)
    # Head-room for the detector names at the top, foot-room for the legend.
    ax.set_ylim(lo - 0.45 * (hi - lo), hi + 0.18 * (hi - lo))
    ax.set_xlim(float(t[0]) - 0.5, float(t[-1]) + 0.5)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("deceleration (m/s²)")
    ax.set_title("commanded, demanded and actual deceleration over time", fontsize=11)
    ax.grid(True, alpha=0.4)
    ax.legend(loc="lower center", ncol=3, fontsize=9, framealpha=0.9)
