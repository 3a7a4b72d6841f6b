"""Stop accuracy on the standard disturbance set at the default station, every controller.

    python benchmarks/accuracy_standard.py [--runs 100000] [--seed 1] [--out DIR]

Runs ``railstop compare`` in-process (identical draws for every controller)
and prints the issue's targets next to the measured figures:
tasc-pwm >= 99.9 % within ±0.30 m, tasc-step >= 99.5 % within ±0.35 m,
overrun_ci95_upper <= 1e-4 for tasc-pwm; ato reported beside them.
A finished campaign folder is resumed, not recomputed; one made by another stop model (or
other settings) is refused in one line (exit 2): remove it or pass another --out.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from railstop.config import default_line, default_vehicle
from railstop.config.disturbances import load_disturbances
from railstop.errors import RailstopError
from railstop.sim.campaign import CampaignSpec, run_campaign
from railstop.sim.engine import CONTROLLERS


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--runs", type=int, default=100_000)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--out", type=Path, default=Path("benchmark-accuracy"))
    parser.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    args = parser.parse_args()
    line, vehicle = default_line(), default_vehicle()
    station = line.stations[0]
    dist = load_disturbances("standard")
    print(f"{args.runs} runs per controller at {station.name}, standard set, seed {args.seed}")
    print(
        f"{'controller':22} {'±0.30':>8} {'±0.35':>8} {'±0.50':>8} {'p99|e|':>7} {'max|e|':>7} "
        f"{'>+0.35':>7} {'P>+0.35 95% up':>15}"
    )
    results = {}
    for controller in CONTROLLERS:
        spec = CampaignSpec(
            line=line,
            vehicle=vehicle,
            station=station.name,
            controller=controller,
            runs=args.runs,
            seed=args.seed,
            disturbances=dist,
        )
        out = args.out / controller
        outcome = run_campaign(spec, out, workers=args.workers, resume=(out / "campaign.json").exists())
        s = outcome.summary
        results[controller] = s
        print(
            f"{controller:22} {100 * s['within_0_30']:7.3f}% {100 * s['within_0_35']:7.3f}% "
            f"{100 * s['within_0_50']:7.3f}% {s['p99_abs_m']:7.3f} {s['max_abs_m']:7.3f} "
            f"{s['overruns']:7d} {s['overrun_ci95_upper']:15.2e}",
            flush=True,
        )
    pwm, step = results["tasc-pwm"], results["tasc-step"]
    print("targets:")
    print(f"  tasc-pwm within ±0.30 m >= 99.9 %: {100 * pwm['within_0_30']:.3f} %")
    print(f"  tasc-step within ±0.35 m >= 99.5 %: {100 * step['within_0_35']:.3f} %")
    print(f"  tasc-pwm P(error > +0.35 m) 95 % upper bound <= 1e-4: {pwm['overrun_ci95_upper']:.2e}")
    print(
        f"    apart: {pwm['overruns_low_adhesion']} overruns in the {pwm['low_adhesion_runs']:,} runs that "
        f"met a low-adhesion patch; {pwm['overruns_no_low_adhesion']} in the other "
        f"{args.runs - pwm['low_adhesion_runs']:,}, bound {pwm['overrun_ci95_upper_no_low_adhesion']:.2e}"
    )


if __name__ == "__main__":
    try:
        main()
    except RailstopError as exc:
        print(f"error: {exc}", file=sys.stderr)
        sys.exit(2)
