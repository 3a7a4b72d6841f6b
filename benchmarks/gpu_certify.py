"""Rare events on the GPU: the stratified certification and a campaign, end to end, in one process.

    python benchmarks/gpu_certify.py [--controller tasc-pwm] [--certify-runs 5000000]
                                     [--campaign-runs 2000000] [--device gpu]

One process, so that the kernel is compiled once (the first call, timed
apart). Then it times three things: ``stratified_certify`` for P(front past
the platform end), the hazard an operator cares about; the same for P(stop
error > the PSD tolerance); and ``run_campaign`` (chunks of 500,000 runs,
Parquet, summary) on the standard set at the default station. Each prints
what ``railstop certify --method stratified --json`` and ``railstop campaign``
would. ``--device cpu`` runs the same on the CPU's threads (with far fewer
runs).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

from railstop.config import default_line, default_vehicle
from railstop.config.disturbances import load_disturbances
from railstop.sim.campaign import CampaignSpec, run_campaign
from railstop.sim.certify import CertifySpec
from railstop.sim.strata import stratified_certify

sys.path.insert(0, str(Path(__file__).resolve().parent))
from gpu_throughput import gpu_lock


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--controller", default="tasc-pwm")
    ap.add_argument("--certify-runs", type=int, default=5_000_000)
    ap.add_argument("--campaign-runs", type=int, default=2_000_000)
    ap.add_argument("--chunk-size", type=int, default=500_000)
    ap.add_argument("--device", default="gpu")
    ap.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    ap.add_argument("--lock", type=Path, default=None, help="a lock file: the timed part alone on the GPU")
    a = ap.parse_args()
    line, vehicle = default_line(), default_vehicle()
    station = line.stations[0]
    dist = load_disturbances("standard")
    spec = CertifySpec(
        line=line,
        vehicle=vehicle,
        station=station.name,
        controller=a.controller,
        disturbances=dist,
        threshold_m=station.platform_end - station.stop_point_m,
        seed=1,
    )
    t = time.perf_counter()
    stratified_certify(
        spec, runs=1_000, target=1e-6, hazard="platform-end", device=a.device, workers=a.workers
    )
    print(f"first call (compiles the {a.device} model): {time.perf_counter() - t:.1f} s", flush=True)
    with gpu_lock(a.lock):  # other benchmarks' timing not on the GPU meanwhile
        for hazard, s in (
            ("platform-end", spec),
            ("overrun", replace(spec, threshold_m=station.psd_tolerance_m)),
        ):
            r = stratified_certify(
                s, runs=a.certify_runs, target=1e-6, hazard=hazard, device=a.device, workers=a.workers
            ).to_dict()
            strata = ", ".join(
                f"{x['stratum']}: {x['hits']:,} hits of {x['runs']:,} (max {x['max_error_m']:+.2f} m)"
                for x in r["strata"]
            )
            print(
                f"certify {hazard} ({r['threshold_m']:.2f} m): estimate {r['estimate']:.3e}, 95 % bound "
                f"{r['upper_bound']:.3e}, {r['runs']:,} runs in {r['elapsed_s']:.1f} s "
                f"({r['runs_per_s']:,.0f} runs/s); {strata}",
                flush=True,
            )
            print("  " + json.dumps(r), flush=True)
        if a.campaign_runs:
            cspec = CampaignSpec(
                line=line,
                vehicle=vehicle,
                station=station.name,
                controller=a.controller,
                runs=a.campaign_runs,
                seed=1,
                disturbances=dist,
                chunk_size=a.chunk_size,
                device=a.device,
            )
            with tempfile.TemporaryDirectory() as tmp:
                t = time.perf_counter()
                outcome = run_campaign(cspec, Path(tmp) / "c", workers=a.workers)
                wall = time.perf_counter() - t
            sm = outcome.summary
            print(
                f"campaign {a.controller} {a.campaign_runs:,} runs on {a.device}: {wall:.1f} s end to end "
                f"({a.campaign_runs / wall:,.0f} runs/s; simulation {sm['runs_per_s']:,.0f} runs/s); "
                f"within the PSD tolerance {sm['within_tolerance']:.4%}",
                flush=True,
            )
            print(
                "  " + json.dumps({k: v for k, v in sm.items() if not isinstance(v, dict | list)}), flush=True
            )


if __name__ == "__main__":
    main()
