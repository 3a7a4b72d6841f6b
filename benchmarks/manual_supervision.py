"""SPEC §3 ATS / ATC supervision, measured: a driver who ignores the codes.

    python benchmarks/manual_supervision.py [--runs 10000] [--station NAME] [--seed 1]

Every driver controller runs the standard disturbance set with an
*incapacitated* driver (``onboard.driver``: he never brakes, the train keeps
its speed; SPEC §3: ATS "stops a driver who is unconscious ..."). Printed per
mode: the share of runs the supervision stopped by the emergency brake (and
by which rule), where the front came to rest against the stopping point and
the platform end, and the share that stopped inside the station (past the
home signal and short of the stopping point; SPEC §3 ATC option 1: "even
with the 3 s grace and the emergency brake the train stops within the
station").
"""

from __future__ import annotations

import argparse

import numpy as np

from railstop.config import default_line, default_vehicle
from railstop.config.disturbances import load_disturbances
from railstop.config.platform import default_platform
from railstop.control.supervision import EB_CAUSES
from railstop.controllers import DRIVER_CONTROLLERS
from railstop.sim.campaign import simulate_runs

BLOCK = 5_000


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=10_000)
    ap.add_argument("--station", default=None)
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    line, vehicle = default_line(), default_vehicle()
    station = line.station(args.station)
    standard = load_disturbances("standard")
    platform = default_platform()
    home = platform.home_signal_m(station.stop_point_m)
    end = station.platform_end - station.stop_point_m
    print(
        f"{args.runs:,} runs per mode at {station.name}, standard set, seed {args.seed}; a driver who "
        f"ignores the codes (the home signal {station.stop_point_m - home:.2f} m before the stopping "
        f"point, the platform end {end:g} m beyond it)"
    )
    cols = f"{'controller':16s} {'EB':>8s}  {'by rule':44s} {'front at rest (m)':>20s}"
    print(f"{cols} {'inside':>8s} {'past end':>9s}")
    for controller in DRIVER_CONTROLLERS:
        eb, error, stopped = [], [], []
        for first in range(0, args.runs, BLOCK):
            n = min(BLOCK, args.runs - first)
            batch, _ = simulate_runs(
                station=station,
                vehicle=vehicle,
                controller=controller,
                disturbances=standard,
                seed=args.seed,
                first_run=first,
                n=n,
                track=line.track,
                incapacitated=True,
            )
            eb.append(batch.emergency_brake)
            error.append(batch.stop_error_m)
            stopped.append(batch.stopped)
        cause = np.concatenate(eb)
        err = np.concatenate(error)
        halted = np.concatenate(stopped)
        n = cause.size
        rules = ", ".join(
            f"{name} {np.count_nonzero(cause == code) / n:.1%}"
            for code, name in EB_CAUSES.items()
            if (cause == code).any()
        )
        at_rest = err[halted]
        where = f"{at_rest.min():+8.1f} .. {at_rest.max():+8.1f}" if at_rest.size else "never stopped"
        inside = halted & (err < 0.0) & (err > home - station.stop_point_m)
        print(
            f"{controller:16s} {np.count_nonzero(cause) / n:8.2%}  {rules or '-':44s} {where:>20s} "
            f"{np.count_nonzero(inside) / n:8.2%} {np.count_nonzero(halted & (err > end)) / n:9.2%}"
        )


if __name__ == "__main__":
    main()
