"""SPEC §2's GNSS time and repeaters compared on identical paths: what each setting alone changes.

    python benchmarks/position_same_path.py [--runs 20] [--seed 1]

Each run is ``railstop position-run --same-path --run r`` (one train over the whole line, cold,
2 % odometer error, 3 slide and 2 slip patches): the train is driven by the line's own chain
(GNSS time, repeaters, the line data's holdover) and every setting's chain is fed the same path
(the same devices, clocks and radio draws). Printed per setting: the median and worst over the
runs of the corrected (SPEC §2 method) and calibrated p99 |error| over the whole line, and of the
corrected one inside the tunnels the line data gives a repeater (where the setting acts), and
the paired difference to
the line's own chain (mean, and in how many runs the setting was worse / better by more than
1 cm). The paired difference is what the setting costs on the same path; before the comparison
on one path, each setting drove its own train and the paths' differences hid it.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from railstop.config import load_line, load_vehicle
from railstop.sim.position_run import SAME_PATH_CHAINS, PositionRunSettings, run_position

METRICS = {
    "corrected": "corrected_p99_abs_m",
    "calibrated": "calibrated_p99_abs_m",
    "after stop 1": "calibrated_p99_abs_after_first_stop_m",
}
NOISE_M = 0.01  # a paired difference under this is "the same"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=20)
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    line, vehicle = load_line(None), load_vehicle(None)
    t0 = time.perf_counter()
    result = run_position(line, vehicle, PositionRunSettings(seed=args.seed, same_path=True), n=args.runs)
    wall = time.perf_counter() - t0
    rows = [result.summary(r)["same_path"] for r in range(args.runs)]
    names = list(SAME_PATH_CHAINS)
    # values[metric][setting] = (runs,)
    values = {
        m: {name: np.array([rows[r][k][key] for r in range(args.runs)]) for k, name in enumerate(names)}
        for m, key in METRICS.items()
    }
    # Inside the tunnels with a repeater, and the 300 m after each (a fix's telegram comes late).
    covered = [(a, b + 300.0) for a, b, repeater in result.tunnels if repeater]
    values["in repeaters' tunnels"] = {}
    for k, name in enumerate(names):
        p99 = []
        for r in range(args.runs):
            grid = result.on_grid(r, {"corrected": result.same_path_corrected_m[k]})
            x = grid["chainage_m"]
            inside = np.zeros(x.size, dtype=bool)
            for a, b in covered:
                inside |= (x >= a) & (x <= b)
            p99.append(float(np.percentile(np.abs(grid["corrected"][inside]), 99)))
        values["in repeaters' tunnels"][name] = np.array(p99)
    print(f"{args.runs} runs (seed {args.seed}, runs 0..{args.runs - 1}) in {wall:.0f} s; p99 |error| in m")
    print(
        f"{'setting':30s} {'metric':22s} {'median':>7s} {'worst':>7s} {'paired Δ mean':>14s} "
        f"{'worse':>6s} {'better':>7s}"
    )
    base = names[0]
    for name in names:
        for m in values:
            v = values[m][name]
            d = v - values[m][base]
            print(
                f"{name:30s} {m:22s} {np.median(v):7.2f} {np.max(v):7.2f} {np.mean(d):+14.2f} "
                f"{int(np.sum(d > NOISE_M)):6d} {int(np.sum(d < -NOISE_M)):7d}"
            )


if __name__ == "__main__":
    main()
