"""The location uncertainty the line's CBTC trains report, measured against where they truly are.

    python benchmarks/location_uncertainty.py [--seeds 1 2] [--duration-s 3600]

Each train reports, with its position, the bound of its own positioning unit
(``railstop.onboard.positioning.unit_uncertainty_m``: k standard deviations of
its dead reckoning since the last fix, the bound of the slides it could not
bridge, and without the learner the detection delay of the last fix). The
line (``railstop.sim.line``, CBTC signalling, 12 trains, the standard
disturbance set) counts every step at which a train's true front lay outside
that bound. Printed per setting of the position chain and seed: those steps
(0 is the target), the least margin (bound - |error|), the largest bound
reported, the largest position error, and the trains per hour (the price of
the bound: a wider one holds the trains further apart).
"""

from __future__ import annotations

import argparse
import time

from railstop.config import load_line, load_vehicle
from railstop.config.disturbances import load_disturbances
from railstop.config.operation import load_operation
from railstop.nodes.occupancy_chain import ChainSettings
from railstop.sim.line import LineSettings, LineSimulation, PositionSettings

SETTINGS = {
    "default (carried calibration)": LineSettings(signalling="cbtc"),
    "cold calibration": LineSettings(signalling="cbtc", calibration="cold"),
    "cold, odometer +5 %": LineSettings(signalling="cbtc", calibration="cold", odometer_error_pct=5.0),
    "slides (p = 0.5)": LineSettings(signalling="cbtc", slide_probability=0.5),
    "slides, no accelerometer": LineSettings(
        signalling="cbtc", slide_probability=0.5, position=PositionSettings(accelerometer=False)
    ),
    "no learner (SPEC §2 method)": LineSettings(signalling="cbtc", position=PositionSettings(learn=False)),
    "no GNSS": LineSettings(signalling="cbtc", position=PositionSettings(chain=ChainSettings(gnss=False))),
    "no repeaters, week holdover": LineSettings(
        signalling="cbtc",
        position=PositionSettings(chain=ChainSettings(repeaters=False, holdover_s=7 * 86400.0)),
    ),
}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--duration-s", type=float, default=3600.0)
    args = ap.parse_args()
    line, vehicle = load_line(None), load_vehicle(None)
    operation = load_operation(None, line)
    dist = load_disturbances("standard")
    print(
        f"{'setting':30s} {'seed':>4s} {'outside':>8s} {'margin min':>11s} {'bound max':>10s} "
        f"{'error max':>10s} {'trains/h':>9s} {'wall':>6s}"
    )
    worst_margin, outside = float("inf"), 0
    for name, settings in SETTINGS.items():
        for seed in args.seeds:
            t0 = time.perf_counter()
            sim = LineSimulation(
                line=line,
                vehicle=vehicle,
                operation=operation,
                disturbances=dist,
                seed=seed,
                settings=settings,
            )
            summary = sim.run(args.duration_s).summary()
            c = summary["cbtc"]
            margin = c["uncertainty_margin_min_m"]
            worst_margin = min(worst_margin, margin)
            outside += c["uncertainty_exceeded"]
            print(
                f"{name:30s} {seed:4d} {c['uncertainty_exceeded']:8d} {margin:9.3f} m "
                f"{c['uncertainty_max_m']:8.2f} m "
                f"{summary['position_error_max_m']:8.2f} m {summary['trains_per_hour']:9.2f} "
                f"{time.perf_counter() - t0:5.1f}s",
                flush=True,
            )
    print(f"over every run: {outside} steps outside the reported bound, least margin {worst_margin:.3f} m")


if __name__ == "__main__":
    main()
