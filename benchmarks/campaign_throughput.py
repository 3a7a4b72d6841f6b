"""Campaign throughput: stop runs per second of the campaign engine and of the single-run path.

    python benchmarks/campaign_throughput.py [--runs 20000] [--controller tasc-pwm] [--workers K]

Runs a real campaign (standard disturbance set, default station, chunks of
10,000) into a temporary folder and a few detailed single stops (the
``railstop stop`` path: n = 1 with recording), and prints both rates and
their ratio. Every number is measured here; nothing is skipped.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

from railstop.config import default_line, default_vehicle
from railstop.config.disturbances import load_disturbances
from railstop.sim.campaign import CampaignSpec, run_campaign
from railstop.sim.single import run_stop


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--runs", type=int, default=20_000)
    parser.add_argument("--chunk-size", type=int, default=10_000)
    parser.add_argument("--controller", default="tasc-pwm")
    parser.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    parser.add_argument("--single", type=int, default=5, help="single stops to time")
    args = parser.parse_args()

    line, vehicle = default_line(), default_vehicle()
    station = line.stations[0]
    dist = load_disturbances("standard")
    spec = CampaignSpec(
        line=line,
        vehicle=vehicle,
        station=station.name,
        controller=args.controller,
        runs=args.runs,
        seed=1,
        disturbances=dist,
        chunk_size=args.chunk_size,
    )
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        outcome = run_campaign(spec, Path(tmp) / "c", workers=args.workers)
        campaign_s = time.perf_counter() - t0
    campaign_rate = args.runs / campaign_s

    t0 = time.perf_counter()
    for run in range(args.single):
        run_stop(
            line=line,
            station=station,
            vehicle=vehicle,
            controller=args.controller,
            seed=1,
            disturbances=dist,
            run=run,
        )
    single_s = time.perf_counter() - t0
    single_rate = args.single / single_s

    print(
        f"machine: {os.cpu_count()} CPUs; controller {args.controller}; station {station.name}; standard set"
    )
    print(
        f"campaign engine: {args.runs} runs in {campaign_s:.1f} s with {args.workers} workers, "
        f"chunks of {args.chunk_size}: {campaign_rate:,.0f} runs/s "
        f"(within ±0.35 m: {100 * outcome.summary['within_0_35']:.2f} %)"
    )
    print(f"single-run path: {args.single} detailed stops in {single_s:.2f} s: {single_rate:.2f} runs/s")
    print(f"ratio campaign / single: {campaign_rate / single_rate:,.0f}x")
    print("targets: >= 10,000 runs/s and >= 1000x the single-run path")


if __name__ == "__main__":
    main()
