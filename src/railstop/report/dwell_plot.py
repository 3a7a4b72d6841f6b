"""The picture of one station dwell: one lane per signal over time (SPEC §5).

Binary signals (DMC, DOA, DOC, DCC, PSC, start enable, emergency brake) are
filled bars where they are high; the train doors and the PSD are coloured by
state (labelled where there is room); the creep lane shows the position
corrections with the platform lamp that asked for them (F / R, SPEC §3).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import matplotlib

# Agg before pyplot: plots are written on servers and in CI with no display.
matplotlib.use("Agg")

import matplotlib.pyplot as plt
from matplotlib.axes import Axes
from matplotlib.patches import Patch

from railstop.errors import RailstopError
from railstop.report.figures import write_figure
from railstop.sim.dwell import DwellEvent, DwellResult

_DPI = 120

# Colours of the door states; a group "X except N Y" takes the colour of Y
# when Y is abnormal (the reason start enable is withheld).
_STATE_COLOURS: dict[str, str] = {
    "closed_locked": "#8c8c8c",
    "closed": "#c7c7c7",
    "opening": "#a1d99b",
    "open": "#2ca02c",
    "closing": "#fdae6b",
    "obstructed": "#d62728",
    "jammed": "#a50f15",
    "isolated": "#9467bd",
    "lost": "#d62728",
}
_ABNORMAL = ("obstructed", "jammed", "isolated")
# SPEC §3 platform lamps.
_LAMP_COLOURS: dict[str, str] = {"F": "#ffd92f", "R": "#fc8d62", "OK": "#2ca02c", "S": "#6baed6"}
_BINARY_COLOUR = "#1f77b4"


def _series(timeline: Sequence[DwellEvent], signal: str) -> list[tuple[float, int | float | str]]:
    return [(e.t_s, e.value) for e in timeline if e.signal == signal]


def _segments(
    changes: list[tuple[float, int | float | str]], end_s: float
) -> list[tuple[float, float, int | float | str]]:
    """(start, end, value) for each constant stretch; several changes at one instant keep the last."""
    out: list[tuple[float, float, int | float | str]] = []
    for i, (t, v) in enumerate(changes):
        t_next = changes[i + 1][0] if i + 1 < len(changes) else end_s
        if t_next > t:
            out.append((t, t_next, v))
    return out


def _state_colour(value: str) -> str:
    for word in _ABNORMAL:
        if word in value:
            return _STATE_COLOURS[word]
    return _STATE_COLOURS.get(value.split(" ")[0], "#dddddd")


def plot_dwell(result: DwellResult, path: str | Path, *, footer: str = "") -> Path:
    """Write the timeline PNG of ``result`` to ``path``; return the path. ``footer``: where the
    plot comes from (``railstop.provenance.footer``), small at the bottom."""
    side = result.platform_side
    other = "L" if side == "R" else "R"
    lanes: list[tuple[str, str, str]] = [
        # (label, signal, kind)
        (f"DMC-{side}", f"DMC-{side}", "binary"),
        (f"DMC-{other}", f"DMC-{other}", "binary"),
        (f"DOA-{side}", f"DOA-{side}", "binary"),
        (f"DOA-{other}", f"DOA-{other}", "binary"),
        ("DOC", "DOC", "binary"),
        ("DCC", "DCC", "binary"),
        ("PSC request", "PSC_request", "binary"),
        ("PSC", "PSC", "binary"),
        (f"PSD {side}", "PSD", "state"),
        (f"train doors {side}", f"train_doors-{side}", "state"),
        (f"train doors {other}", f"train_doors-{other}", "state"),
        ("start enable", "start_enable", "binary"),
        ("creep (lamp)", "creep", "creep"),
        ("emergency brake", "emergency_brake", "binary"),
    ]
    outcome = (
        f"start enable at {result.start_enable_s:g} s"
        if result.start_enable_s is not None
        else ("FAULT + emergency brake" if result.fault else result.outcome)
    )
    title = (
        f"Dwell at {result.station} ({result.mode} mode, platform side {side}): {outcome}\n"
        f"stop error {result.stop_error_m:+.2f} m (tolerance ±{result.tolerance_m:g} m), "
        f"{result.psc_attempts} PSC attempt(s), {result.corrections} correction(s)"
    )
    timeline = result.timeline
    marks = _marks(
        timeline, (("PSC", 1, "PSC", 0), ("DCC", 1, "close", 0), ("emergency_brake", 1, "emergency brake", 0))
    )
    if result.start_enable_s is not None:
        marks.append((result.start_enable_s, "start enable"))
    return plot_timeline(
        timeline,
        lanes,
        path,
        title=title,
        marks=marks,
        start_s=0.0,
        end_s=max(result.dwell_total_s, 1.0) * 1.03 + 0.5,
        xlabel="time since the train stopped (s)",
        footer=footer,
    )


def plot_timeline(
    timeline: Sequence[DwellEvent],
    lanes: Sequence[tuple[str, str, str]],
    path: str | Path,
    *,
    title: str,
    marks: Sequence[tuple[float, str]],
    start_s: float,
    end_s: float,
    xlabel: str,
    footer: str = "",
) -> Path:
    """One lane per signal over time (``lanes``: label, signal, kind ``binary`` | ``state`` |
    ``creep`` | ``lamp``), dashed lines at the ``marks`` (time, name); return the path written."""
    out = Path(path)
    if not out.parent.is_dir():
        raise RailstopError(f"{out}: directory {str(out.parent)!r} does not exist")
    height_in = 1.2 + 0.42 * len(lanes)
    fig, ax = plt.subplots(figsize=(12.0, height_in), dpi=_DPI, layout="constrained")
    try:
        for row, (_label, signal, kind) in enumerate(lanes):
            y = len(lanes) - 1 - row
            _lane(ax, y, _segments(_series(timeline, signal), end_s), kind, end_s - start_s)
        ax.set_yticks(range(len(lanes)))
        ax.set_yticklabels([lane[0] for lane in reversed(lanes)], fontsize=9)
        ax.set_ylim(-0.6, len(lanes) + 0.55)  # head-room for the milestone names
        ax.set_xlim(start_s, end_s)
        ax.set_xlabel(xlabel)
        ax.grid(True, axis="x", alpha=0.35)
        for y in range(len(lanes)):
            ax.axhline(y - 0.5, color="0.9", lw=0.6, zorder=0)
        _milestones(ax, sorted(marks), len(lanes), start_s, end_s)
        # The legend names the colours the picture uses.
        seen = {str(e.value).split(" ")[0] for e in timeline if any(e.signal == sig for _, sig, _ in lanes)}
        states = {k: c for k, c in _STATE_COLOURS.items() if k in seen}
        states |= {f"lamp {k}": c for k, c in _LAMP_COLOURS.items() if k in seen}
        handles = [Patch(color=_BINARY_COLOUR, label="signal high")] + [
            Patch(color=c, label=s.replace("_", " ")) for s, c in states.items()
        ]
        fig.legend(handles=handles, loc="outside lower center", ncol=9, fontsize=8, frameon=False)
        fig.suptitle(title, fontsize=11, fontweight="bold")
        if footer:
            fig.text(0.005, 0.002, footer, fontsize=7, color="0.4", ha="left", va="bottom")
        out = write_figure(fig, out, _DPI)
    finally:
        plt.close(fig)
    return out


def _lane(
    ax: Axes, y: int, segments: list[tuple[float, float, int | float | str]], kind: str, span_s: float
) -> None:
    h = 0.62
    for t0, t1, v in segments:
        if kind == "binary":
            if isinstance(v, int | float) and v:
                ax.broken_barh([(t0, t1 - t0)], (y - h / 2, h), color=_BINARY_COLOUR)
                if isinstance(v, int) and v > 1:  # PSC request: the attempt number
                    ax.text((t0 + t1) / 2, y, str(v), ha="center", va="center", fontsize=7, color="white")
            else:
                ax.plot([t0, t1], [y - h / 2, y - h / 2], color=_BINARY_COLOUR, lw=1.0)
        elif kind == "creep":
            if isinstance(v, str) and v in ("F", "R"):
                ax.broken_barh([(t0, t1 - t0)], (y - h / 2, h), color="#17becf")
                ax.text((t0 + t1) / 2, y, v, ha="center", va="center", fontsize=8, fontweight="bold")
            else:
                ax.plot([t0, t1], [y - h / 2, y - h / 2], color="#17becf", lw=1.0)
        elif kind == "lamp":
            if isinstance(v, str) and v in _LAMP_COLOURS:
                ax.broken_barh([(t0, t1 - t0)], (y - h / 2, h), color=_LAMP_COLOURS[v])
                ax.text((t0 + t1) / 2, y, v, ha="center", va="center", fontsize=8, fontweight="bold")
            else:
                ax.plot([t0, t1], [y - h / 2, y - h / 2], color="0.5", lw=1.0)
        else:
            text = str(v)
            ax.broken_barh(
                [(t0, t1 - t0)], (y - h / 2, h), color=_state_colour(text), edgecolor="white", lw=0.5
            )
            # A label where the bar is wide enough for it (about 0.9 % of the axis per character).
            short = text.replace("_", " ")
            if (t1 - t0) > 0.009 * span_s * max(len(short), 4):
                ax.text((t0 + t1) / 2, y, short, ha="center", va="center", fontsize=7, clip_on=True)


def _marks(
    timeline: Sequence[DwellEvent], specs: Sequence[tuple[str, int | str, str, int]]
) -> list[tuple[float, str]]:
    """(time, name) where ``signal`` took ``value``: per (signal, value, name, which), the first
    time (``which`` 0) or the last (-1); nothing where it never did."""
    out = []
    for signal, value, name, which in specs:
        hit = [t for t, v in _series(timeline, signal) if v == value]
        if hit:
            out.append((hit[which], name))
    return out


def _milestones(ax: Axes, marks: list[tuple[float, str]], n_lanes: int, start_s: float, end_s: float) -> None:
    """Dashed lines at the marks, named at the top."""
    span = end_s - start_s
    level = 0
    for i, (t, label) in enumerate(marks):
        ax.axvline(t, color="0.3", ls="--", lw=0.9, zorder=3)
        right = t > start_s + 0.8 * span  # near the right edge: name left of the line
        # Names of marks close together go on alternate heights so they do not overlap.
        level = (level + 1) % 3 if i and t - marks[i - 1][0] < 0.2 * span else 0
        ax.text(
            t,
            n_lanes - 0.42 + 0.3 * level,
            f"{label} {t:g} s " if right else f" {label} {t:g} s",
            fontsize=8,
            va="bottom",
            ha="right" if right else "left",
            color="0.15",
            bbox={"boxstyle": "round,pad=0.15", "fc": "white", "ec": "none", "alpha": 0.85},
        )


def plot_platform_dwell(
    timeline: Sequence[DwellEvent], path: str | Path, *, title: str, xlabel: str, footer: str = ""
) -> Path:
    """The lamp and PSD timeline of a manually driven train (SPEC §3): the lamps at its stands, the
    PSD relay, the driver, the train doors, the camera, the PSD and the departure permission."""
    lanes: list[tuple[str, str, str]] = [
        ("lamp", "lamp", "lamp"),
        ("PSD relay", "psd_relay", "binary"),
        ("driver", "driver", "state"),
        ("train doors", "train_doors", "state"),
        ("camera sees", "camera", "state"),
        ("PSD", "PSD", "state"),
        ("departure permitted", "departure_permitted", "binary"),
        ("moving", "moving", "binary"),
        ("signal-open switch", "signal_open", "binary"),
    ]
    if not timeline:
        raise RailstopError("the timeline is empty: nothing to plot")
    times = [e.t_s for e in timeline]
    start, last = min(times), max(times)
    marks = [(e.t_s, f"stand {float(e.value):+.2f} m") for e in timeline if e.signal == "stand_error_m"]
    marks += _marks(
        timeline,
        (
            ("train_doors", "open", "doors open", 0),
            ("PSD", "open", "PSD open", 0),
            ("moving", 1, "depart", -1),  # the last start: the earlier ones are corrections
        ),
    )
    span = max(last - start, 1.0)
    return plot_timeline(
        timeline,
        lanes,
        path,
        title=title,
        marks=marks,
        start_s=start - 0.02 * span,
        end_s=last + 0.03 * span + 0.5,
        xlabel=xlabel,
        footer=footer,
    )
