"""Robustness beyond the standard set: each disturbance pushed to k x its standard range, one at a time.

    python benchmarks/robustness.py [--controllers tasc-pwm,tasc-step,ato] [--station NAME]
                                    [--runs 2000] [--seed 1] [--scales 2,3] [--json]
                                    [--detectors-only]

The controllers are tuned to the disturbances of the standard set
(``railstop/data/disturbances/standard.toml``). This benchmark takes one
disturbance at a time to k times its standard range, every other one standard,
and prints per controller the share of stops within the station's PSD
tolerance (±0.35 m by default) and within ±0.30 m, and the count of emergency
brakes, so that a reader sees where a controller has a cliff (issue 36's target,
measured here and not asserted: no setting below 99 % within ±0.35 m up to
twice the standard noise). Each setting below the target at k=2 is split into
the runs that drew beyond the zone's envelope (``railstop check``'s zone-length
rule at the run's own entry speed and steepest downhill), those inside it whose
odometer errs by more than the vehicle declares (``vehicle.atp``, the error the
onboard overrun guard counts), and the others, with their emergency brakes and
silent misses off the low-adhesion patches, and the runs past the platform end.
``--detectors-only`` runs the station's detectors-only variant (SPEC §1 claim 6: no Doppler
radar, its zone's ``detectors_only_before_stop_m``).

How a distribution is taken to k x its range:

* a noise given by its standard deviation (``doppler_noise_pct``,
  ``sensor_jitter_ms``, a fixed value that is an sd): the sd times k;
* a normal with clip (``brake_gain``, ``load_weighing_error_pct``): the sd times k
  and the clip interval widened about its centre by k;
* a uniform [lo, hi] of a physical parameter (brake dead time and time
  constant, gradients, radio latency, odometer error, ...): widened about its
  centre by k;
* a probability (radio loss, detector miss, low adhesion): times k, at most 1.

A widened value the parameter's physical range (the disturbance file's schema)
refuses is clipped to that range (to just inside an open bound, by 1 % of the
standard width) and the cell is marked ``*``; the settings list says what each
cell ran. Every cell of a controller runs runs ``0 .. N - 1`` of the same seed:
the draws of the parameters left standard are the same in every cell (each
parameter has its own random counters), so the cells differ only by the
setting. A parameter the controller does not use (the wayside's sensors and
radio for ``ato``) gives the standard figures again.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from railstop.config import default_line, default_vehicle
from railstop.config import disturbances as dist_module
from railstop.config.disturbances import Distribution, DisturbanceSet, load_disturbances
from railstop.config.loader import with_detectors_only
from railstop.config.plausibility import beyond_envelope, envelope_note
from railstop.controllers import known_controllers
from railstop.sim.campaign import simulate_runs
from railstop.stats.summary import summary_stats

DEFAULT_CONTROLLERS = "tasc-pwm,tasc-step,ato"
TARGET = 0.99  # issue 36: no setting below 99 % within the tolerance up to twice the standard noise
# Runs per call of the kernel (memory stays small whatever --runs).
BLOCK = 5_000
# Just inside an open bound of a parameter's physical range: this share of the standard width.
OPEN_MARGIN = 0.01

# The swept parameters, in the order of the tables, with the group they belong to. "noise": a
# disturbance the controllers must tolerate; "operating range": the train's own conditions (not
# noise: pushing them widens what the station was laid out for), not in "all at once".
NOISE = "noise"
OPERATING = "operating range"
SWEPT: tuple[tuple[str, str], ...] = (
    ("doppler_noise_pct", NOISE),
    ("sensor_jitter_ms", NOISE),
    ("sensor_miss_probability", NOISE),
    ("radio_latency_ms", NOISE),
    ("radio_loss_probability", NOISE),
    ("brake_dead_time_s", NOISE),
    ("brake_time_constant_s", NOISE),
    ("brake_gain", NOISE),
    ("load_weighing_error_pct", NOISE),
    ("approach_gradient_permille", NOISE),
    ("platform_gradient_permille", NOISE),
    ("odometer_diameter_error_pct", NOISE),
    ("low_adhesion_probability", "hazard"),
    ("entry_speed_kmh", OPERATING),
    ("wheel_diameter_mm", OPERATING),
)
# Parameters of the standard set that are not swept, and why.
NOT_SWEPT: dict[str, str] = {
    "load_factor": "uniform 0-1 is already the whole physical range (empty to crush)",
    "low_adhesion_mu": "a property of the patch (its probability is swept)",
    "low_adhesion_length_m": "a property of the patch (its probability is swept)",
    "radio_jitter_ms": "0 in the standard set: k x 0 is still 0",
    "radio_bit_error_rate": "0 in the standard set: k x 0 is still 0",
    "radio_outage_start_s": "a fault, not a service disturbance (no outage in the standard set)",
    "radio_outage_duration_s": "a fault, not a service disturbance (no outage in the standard set)",
    "radio_burst_enter_probability": "0 in the standard set: k x 0 is still 0",
    "radio_burst_exit_probability": "no bursts in the standard set (their entry is 0)",
    "radio_burst_loss_probability": "0 in the standard set: k x 0 is still 0",
    "radio_reorder_probability": "0 in the standard set: k x 0 is still 0",
}
STANDARD_ROW = "standard set"
NO_ADHESION_ROW = "standard without low-adhesion patches"
ALL_ROW = "all noise rows at once"


@dataclass(frozen=True, slots=True)
class Cell:
    """One setting at one k: what goes into the set's dict, how it reads, and any clipping."""

    value: Any  # a number for a *_probability, else a distribution table
    text: str
    clipped: str = ""  # why the cell is not exactly k x the standard range ("" if it is)


@dataclass(frozen=True, slots=True)
class Row:
    name: str
    group: str
    cells: dict[float, Cell]  # k -> cell (k = 1: the standard set or the row's own baseline)
    build: Callable[[float], DisturbanceSet]


def _num(x: float) -> str:
    return f"{x:.6g}"


def _range_of(name: str) -> tuple[float, float, bool, bool]:
    """The parameter's physical range as the disturbance file's schema checks it."""
    rng = dist_module._SPECS[name].range
    return rng.lo, rng.hi, rng.lo_open, rng.hi_open


def _clip_to_range(name: str, lo: float, hi: float, width: float) -> tuple[float, float, str]:
    """[lo, hi] clipped into the parameter's physical range; the reason when it had to be."""
    r_lo, r_hi, lo_open, hi_open = _range_of(name)
    inside_lo = r_lo + OPEN_MARGIN * width if lo_open else r_lo
    inside_hi = r_hi - OPEN_MARGIN * width if hi_open else r_hi
    new_lo, new_hi = max(lo, inside_lo), min(hi, inside_hi)
    if (new_lo, new_hi) == (lo, hi):
        return lo, hi, ""
    return new_lo, new_hi, f"widened to {_num(lo)}..{_num(hi)}, clipped to the schema's {_range_text(name)}"


def _range_text(name: str) -> str:
    r_lo, r_hi, lo_open, hi_open = _range_of(name)
    return f"{_num(r_lo)} {'<' if lo_open else '<='} x {'<' if hi_open else '<='} {_num(r_hi)}"


def describe(name: str, value: Any) -> str:
    """A cell's distribution as it reads in the settings list."""
    if name.endswith("_probability"):
        return _num(value)
    d = Distribution.model_validate(value)
    if d.fixed is not None:
        return f"fixed {_num(d.fixed)}"
    if d.uniform is not None:
        return f"uniform [{_num(d.uniform[0])}, {_num(d.uniform[1])}]"
    if d.normal is not None:
        clip = f", clip [{_num(d.clip[0])}, {_num(d.clip[1])}]" if d.clip is not None else ""
        return f"normal mean {_num(d.normal[0])} sd {_num(d.normal[1])}{clip}"
    assert d.choice is not None
    return "choice [" + ", ".join(_num(v) for v in d.choice) + "]"


def scaled(name: str, standard: DisturbanceSet, k: float) -> Cell:
    """The standard distribution of ``name`` taken to k x its range (see the module docstring)."""
    d = standard.params[name]
    if name.endswith("_probability"):
        p = float(d.fixed or 0.0) * k
        why = f"{_num(p)} capped at 1" if p > 1.0 else ""
        value = min(p, 1.0)
        return Cell(value, describe(name, value), why)
    if d.fixed is not None:  # a noise given by its standard deviation
        sd = d.fixed * k
        lo, hi, why = _clip_to_range(name, sd, sd, max(d.fixed, 1e-9))
        value = {"fixed": hi}
        return Cell(value, describe(name, value), why)
    if d.uniform is not None:
        lo, hi = d.uniform
        centre, half = (lo + hi) / 2.0, (hi - lo) / 2.0
        new_lo, new_hi, why = _clip_to_range(name, centre - k * half, centre + k * half, hi - lo)
        value = {"uniform": [new_lo, new_hi]}
        return Cell(value, describe(name, value), why)
    if d.normal is not None and d.clip is not None:
        mean, sd = d.normal
        lo, hi = d.clip
        centre, half = (lo + hi) / 2.0, (hi - lo) / 2.0
        new_lo, new_hi, why = _clip_to_range(name, centre - k * half, centre + k * half, hi - lo)
        value = {"normal": [mean, sd * k], "clip": [new_lo, new_hi]}
        return Cell(value, describe(name, value), why)
    raise ValueError(f"{name}: no rule to scale a {d.kind} distribution")


def _with(standard: DisturbanceSet, label: str, **changes: Any) -> DisturbanceSet:
    """The standard set with ``changes`` (parameter -> file value; None removes it), validated."""
    data = standard.to_dict()
    for name, value in changes.items():
        if value is None:
            data.pop(name, None)
        else:
            data[name] = value
    return DisturbanceSet.from_dict(data, name=label, source=f"(benchmarks/robustness.py: {label})")


def settings(standard: DisturbanceSet, scales: Sequence[float]) -> list[Row]:
    """The rows of the tables: the standard set, without low adhesion, each swept parameter, all at once."""
    base = Cell(None, "the standard set")
    rows = [
        Row(STANDARD_ROW, "baseline", {1.0: base}, lambda k: standard),
        Row(
            NO_ADHESION_ROW,
            "baseline",
            {1.0: Cell(None, "low_adhesion_probability removed (no patch)")},
            lambda k: _with(standard, NO_ADHESION_ROW, low_adhesion_probability=None),
        ),
    ]
    noise: list[str] = []
    for name, group in SWEPT:
        if name not in standard.params:
            continue
        cells = {1.0: Cell(standard.to_dict()[name], describe(name, standard.to_dict()[name]))}
        cells.update({k: scaled(name, standard, k) for k in scales})

        def build(k: float, name: str = name, cells: dict[float, Cell] = cells) -> DisturbanceSet:
            if k == 1.0:
                return standard
            return _with(standard, f"{name} x{k:g}", **{name: cells[k].value})

        rows.append(Row(name, group, cells, build))
        if group == NOISE:
            noise.append(name)

    def build_all(k: float) -> DisturbanceSet:
        if k == 1.0:
            return standard
        return _with(standard, f"{ALL_ROW} x{k:g}", **{n: scaled(n, standard, k).value for n in noise})

    all_cells = {1.0: base}
    for k in scales:
        clipped = [n for n in noise if scaled(n, standard, k).clipped]
        all_cells[k] = Cell(
            None,
            f"every row of group {NOISE!r} at its x{k:g} setting together",
            f"includes the clipped {', '.join(clipped)}" if clipped else "",
        )
    rows.append(Row(ALL_ROW, NOISE, all_cells, build_all))
    return rows


def measure(
    *, station: Any, vehicle: Any, track: Any, controller: str, dset: DisturbanceSet, runs: int, seed: int
) -> dict[str, Any]:
    """Runs 0 .. runs - 1 of ``dset``: the shares within the tolerance and ±0.30 m, emergency brakes."""
    parts: dict[str, list[np.ndarray]] = {
        k: []
        for k in (
            "error",
            "jerk",
            "time",
            "stopped",
            "slid",
            "eb",
            "patch",
            "speed",
            "approach",
            "platform",
            "odometer",
        )
    }
    for first in range(0, runs, BLOCK):
        n = min(BLOCK, runs - first)
        res, drawn = simulate_runs(
            station=station,
            vehicle=vehicle,
            controller=controller,
            disturbances=dset,
            seed=seed,
            first_run=first,
            n=n,
            track=track,
        )
        parts["error"].append(res.stop_error_m)
        parts["jerk"].append(res.max_jerk_mps3)
        parts["time"].append(res.stop_time_s)
        parts["stopped"].append(res.stopped)
        parts["slid"].append(res.slid)
        parts["eb"].append(res.emergency_brake)
        parts["patch"].append(drawn[dist_module.LOW_ADHESION])
        parts["speed"].append(drawn["entry_speed_kmh"])
        parts["approach"].append(drawn["approach_gradient_permille"])
        parts["platform"].append(drawn["platform_gradient_permille"])
        parts["odometer"].append(drawn["odometer_diameter_error_pct"])
    col = {k: np.concatenate(v) for k, v in parts.items()}
    s = summary_stats(
        col["error"],
        col["jerk"],
        col["time"],
        col["stopped"],
        col["slid"],
        tolerance_m=station.psd_tolerance_m,
        emergency_brake=col["eb"],
        platform_end_m=station.platform_end - station.stop_point_m,
        low_adhesion=col["patch"],
    )
    keys = (
        "runs",
        "within_tolerance",
        "within_0_30",
        "within_0_35",
        "emergency_brakes",
        "slid",
        "not_stopped",
        "overruns",
        "low_adhesion_runs",
        "mean_m",
        "std_m",
        "p99_abs_m",
        "max_abs_m",
        "silent_misses",
        "past_platform_end",
    )
    out = {k: (None if isinstance(s[k], float) and not math.isfinite(s[k]) else s[k]) for k in keys}
    out.update(envelope_split(station, vehicle, col))
    return out


def envelope_split(station: Any, vehicle: Any, col: dict[str, np.ndarray]) -> dict[str, Any]:
    """The runs that drew beyond the zone's envelope (``railstop check``'s zone-length rule at the
    run's own entry speed and steepest downhill: ``config.plausibility.beyond_envelope``), those
    inside it whose odometer errs by more than the vehicle declares (``vehicle.atp``'s
    ``odometer_uncertainty_pct``, which the onboard overrun guard counts), and the others: for
    each, the share within the tolerance, the emergency brakes and the runs outside the tolerance
    with no emergency brake (silent misses), the latter off the patches."""
    beyond = beyond_envelope(station, vehicle, col["speed"], col["approach"], col["platform"])
    odometer = ~beyond & (np.abs(col["odometer"]) > vehicle.atp.odometer_uncertainty_pct)
    within = np.abs(col["error"]) <= station.psd_tolerance_m  # NaN (never stood): not within
    eb = col["eb"] != 0
    silent_off_patch = ~within & ~eb & ~col["patch"].astype(bool)

    def part(mask: np.ndarray) -> dict[str, Any]:
        n = int(mask.sum())
        return {
            "runs": n,
            "within_tolerance": float(within[mask].mean()) if n else None,
            "emergency_brakes": int(eb[mask].sum()),
            "silent_misses_off_patches": int(silent_off_patch[mask].sum()),
        }

    return {
        "inside_envelope": part(~beyond & ~odometer),
        "beyond_odometer": part(odometer),
        "beyond_zone": part(beyond),
    }


def _scales(text: str) -> list[float]:
    values = [float(t) for t in text.split(",") if t.strip()]
    if not values or any(not math.isfinite(v) or v <= 1.0 for v in values):
        raise argparse.ArgumentTypeError("give factors above 1, e.g. 2,3")
    return sorted(set(values))


def _controllers(text: str) -> list[str]:
    names = [t.strip() for t in text.split(",") if t.strip()]
    unknown = [n for n in names if n not in known_controllers()]
    if not names or unknown:
        raise argparse.ArgumentTypeError(
            f"unknown controller {', '.join(unknown) or '(none)'}; known: {', '.join(known_controllers())}"
        )
    return names


def _cell_text(r: dict[str, Any] | None, mark: str) -> str:
    if r is None:
        return f"{'-':>7} {'-':>7} {'-':>4} "
    return (
        f"{100 * r['within_tolerance']:6.2f}% {100 * r['within_0_30']:6.2f}% "
        f"{r['emergency_brakes']:4d}{mark or ' '}"
    )


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        description=__doc__.splitlines()[0], formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--controllers", type=_controllers, default=_controllers(DEFAULT_CONTROLLERS))
    ap.add_argument("--station", default=None, help="default: the line's first")
    ap.add_argument("--runs", type=int, default=2000, help="runs per cell (default 2000)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--scales", type=_scales, default=_scales("2,3"), help="k values (default 2,3)")
    ap.add_argument("--json", action="store_true", help="print one JSON object instead of the tables")
    ap.add_argument("--detectors-only", action="store_true", help="the station without its Doppler radar")
    args = ap.parse_args(argv)
    if args.runs < 1:
        ap.error("--runs must be at least 1")
    t0 = time.perf_counter()
    line, vehicle = default_line(), default_vehicle()
    if args.detectors_only:
        line = with_detectors_only(line, args.station)
    station = line.station(args.station)
    standard = load_disturbances("standard")
    tol = station.psd_tolerance_m
    ks = [1.0, *args.scales]
    rows = settings(standard, args.scales)

    if not args.json:
        print(
            f"{station.name}{' (detectors only)' if args.detectors_only else ''}, {args.runs:,} runs per "
            f"cell, seed {args.seed}; one disturbance at a time at "
            f"k x its standard range (k = {', '.join(f'{k:g}' for k in args.scales)}), every other one "
            f"standard; PSD tolerance ±{tol:g} m"
        )
        note = envelope_note(station, vehicle, standard)
        if note is not None:  # the standard set already reaches beyond the zone's layout
            print(f"note: {note}")
        print("settings (* = clipped to the parameter's physical range):")
        for row in rows:
            print(f"  {row.name} [{row.group}]")
            for k, cell in row.cells.items():
                mark = f"  * {cell.clipped}" if cell.clipped else ""
                print(f"    k={k:g}: {cell.text}{mark}")
        print("  not swept: " + "; ".join(f"{n} ({why})" for n, why in NOT_SWEPT.items()))
        sys.stdout.flush()

    results: dict[str, dict[str, dict[str, Any]]] = {}
    times: dict[str, float] = {}
    for controller in args.controllers:
        tc = time.perf_counter()
        per_row: dict[str, dict[str, Any]] = {}
        standard_result: dict[str, Any] | None = None
        for row in rows:
            per_k: dict[str, Any] = {}
            for k in ks:
                if k not in row.cells:
                    continue
                if k == 1.0 and row.name != NO_ADHESION_ROW and standard_result is not None:
                    per_k["1"] = standard_result  # the same set and runs: measured once
                    continue
                r = measure(
                    station=station,
                    vehicle=vehicle,
                    track=line.track,
                    controller=controller,
                    dset=row.build(k),
                    runs=args.runs,
                    seed=args.seed,
                )
                if k == 1.0 and row.name == STANDARD_ROW:
                    standard_result = r
                per_k[f"{k:g}"] = r
            per_row[row.name] = per_k
        results[controller] = per_row
        times[controller] = time.perf_counter() - tc
        if not args.json:
            _print_table(controller, station.name, rows, ks, per_row, tol, args.runs, times[controller])

    below = {
        c: [
            row.name
            for row in rows
            if 2.0 in row.cells and results[c][row.name]["2"]["within_tolerance"] < TARGET
        ]
        for c in args.controllers
    }
    wall = time.perf_counter() - t0
    if args.json:
        out = {
            "station": station.name,
            "detectors_only": args.detectors_only,
            "runs_per_cell": args.runs,
            "seed": args.seed,
            "scales": args.scales,
            "tolerance_m": tol,
            "target_within_tolerance": TARGET,
            "settings": [
                {
                    "name": row.name,
                    "group": row.group,
                    "cells": {
                        f"{k:g}": {"distribution": c.text, "value": c.value, "clipped": c.clipped}
                        for k, c in row.cells.items()
                    },
                }
                for row in rows
            ],
            "not_swept": NOT_SWEPT,
            "results": results,
            "below_target_at_2x": below if 2.0 in args.scales else None,
            "wall_s": {"total": round(wall, 2), **{c: round(t, 2) for c, t in times.items()}},
        }
        print(json.dumps(out, indent=1))
        return 0
    if 2.0 in args.scales:
        print(f"settings below {100 * TARGET:g} % within ±{tol:g} m at k=2:")
        for c in args.controllers:
            std = results[c][STANDARD_ROW]["1"]["within_tolerance"]
            print(f"  {c} (standard set {100 * std:.2f} %): {', '.join(below[c]) or 'none'}")
            if std < TARGET:  # every setting is below the target already: no split is telling
                continue
            for name in below[c]:
                print(f"    {name}: {_split_text(results[c][name]['2'], tol)}")
    else:
        print("k=2 not among --scales: no summary at twice the standard range")
    print(f"wall time {wall:.1f} s")
    return 0


def _split_text(r: dict[str, Any], tol: float) -> str:
    """A cell's runs inside the zone's envelope and beyond it, as one line."""

    def one(part: dict[str, Any], where: str) -> str:
        if not part["runs"]:
            return f"no run {where}"
        return (
            f"{part['runs']:,} runs {where} {100 * part['within_tolerance']:.2f} % within ±{tol:g} m "
            f"({part['emergency_brakes']} EB, {part['silent_misses_off_patches']} silent off the patches)"
        )

    return (
        f"{one(r['inside_envelope'], 'inside the envelope')}; "
        f"{one(r['beyond_odometer'], 'inside the zone with an odometer beyond its declared accuracy')}; "
        f"{one(r['beyond_zone'], 'beyond the zone')}; {r['past_platform_end']} past the platform end"
    )


def _print_table(
    controller: str,
    station: str,
    rows: list[Row],
    ks: list[float],
    per_row: dict[str, dict[str, Any]],
    tol: float,
    runs: int,
    seconds: float,
) -> None:
    print()
    print(
        f"{controller} at {station}: share within ±{tol:g} m, within ±0.30 m, emergency brakes "
        f"({runs:,} runs per cell; * clipped)"
    )
    width = 22
    head = f"{'setting':38}" + "".join(
        f"{('k=1 (standard)' if k == 1.0 else f'k={k:g}'):^{width}}" for k in ks
    )
    print(head)
    print(f"{'':38}" + "".join(f"{f'±{tol:g}':>7} {'±0.30':>7} {'EB':>4}  " for _ in ks))
    for row in rows:
        cells = []
        for k in ks:
            r = per_row[row.name].get(f"{k:g}")
            mark = "*" if k in row.cells and row.cells[k].clipped else ""
            cells.append(_cell_text(r, mark) + " ")
        print(f"{row.name:38}" + "".join(cells))
    print(f"({controller}: {seconds:.1f} s wall)", flush=True)


if __name__ == "__main__":
    raise SystemExit(main())
