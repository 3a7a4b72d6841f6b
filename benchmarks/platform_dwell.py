"""SPEC §3 the PSD following the train doors through the camera, measured over many dwells.

    python benchmarks/platform_dwell.py [--dwells 1000] [--misread 0.01,0.1,0.3] [--confirm 3,5] [--seed 1]

Each dwell stands the train at a front drawn uniformly within ±0.30 m of the
stopping point (inside the OK window: the question here is the camera, not
the stop) and runs ``sim.platform_dwell`` with the platform data's camera,
its misread probability and the PSD control's confirmation (equal frames in a
row) replaced by each pair of values given. Printed per value:
the outcomes, how far the PSD lags the train doors (open: the PSD fully open
after the train doors; close: the PSD closed and locked after the train
doors are), the time from the stand to departure, the frames misread, and
the **unsafe PSD moves**: the PSD starting to close before the train doors
are closed and locked, or opening while the relay is off (the checks of
``platform verify``, counted on the simulated timelines). The figures are what the
camera's detection delay, confirmation and misreads cost a dwell.
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

from railstop.config.doors import load_doors
from railstop.config.platform import default_platform
from railstop.sim.platform_dwell import OUTCOMES, run_platform_dwell


def _first(timeline: tuple, signal: str, value: object) -> float | None:
    return next((e.t_s for e in timeline if e.signal == signal and e.value == value), None)


def _unsafe(timeline: tuple) -> int:
    """PSD moves the interlock forbids, from the timeline's signal values at each change."""
    now: dict[str, object] = {}
    bad = 0
    for e in timeline:
        if e.signal == "PSD" and e.value == "closing" and now.get("train_doors") != "closed_locked":
            bad += 1  # SPEC §5 order: the train doors closed and locked first
        if e.signal == "PSD" and e.value == "opening" and now.get("psd_relay") != 1:
            bad += 1
        now[e.signal] = e.value
    return bad


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dwells", type=int, default=1000)
    ap.add_argument("--misread", default="0.01,0.1,0.3", help="comma-separated per-frame probabilities")
    ap.add_argument("--confirm", default=None, help="comma-separated confirm_frames (default: the data's)")
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    doors = load_doors(None)
    base = default_platform()
    cam = base.camera
    errors = np.random.default_rng(args.seed).uniform(-0.30, 0.30, args.dwells)
    print(
        f"{args.dwells:,} dwells per value, stands within ±0.30 m; camera: a frame every "
        f"{cam.frame_period_s:g} s, {cam.processing_delay_s:g} s detection delay, 'open' from "
        f"{cam.open_fraction:.0%} open, 'closed' only shut, locked after {cam.lock_confirm_s:g} s more; "
        f"train doors "
        f"{doors.timing.train_door_open_s:g} / {doors.timing.train_door_close_s:g} s, PSD "
        f"{doors.timing.psd_open_s:g} / {doors.timing.psd_close_s:g} s (open / close)"
    )
    head = f"{'misread':>8s} {'confirm':>8s} {'outcomes':36s} {'open lag s':>11s} {'close lag s':>12s}"
    print(f"{head} {'departure s':>12s} {'misread':>8s} {'unsafe':>7s} {'dwells/s':>9s}")
    confirms = [cam.confirm_frames] if args.confirm is None else [int(x) for x in args.confirm.split(",")]
    for p, k in ((float(x), c) for c in confirms for x in args.misread.split(",")):
        camera = cam.model_copy(update={"misread_probability": p, "confirm_frames": k})
        platform = base.model_copy(update={"camera": camera})
        outcomes = dict.fromkeys(OUTCOMES, 0)
        open_lag, close_lag, depart, misreads, frames, unsafe = [], [], [], 0, 0, 0
        t0 = time.perf_counter()
        for i, e in enumerate(errors):
            r = run_platform_dwell(
                platform=platform,
                doors=doors,
                station="bench",
                stop_error_m=float(e),
                seed=args.seed,
                counter=i,
            )
            outcomes[r.outcome] += 1
            tl = r.timeline
            doors_open, psd_open = _first(tl, "train_doors", "open"), _first(tl, "PSD", "open")
            if doors_open is not None and psd_open is not None:
                open_lag.append(psd_open - doors_open)
            doors_locked = [x.t_s for x in tl if x.signal == "train_doors" and x.value == "closed_locked"]
            psd_locked = [x.t_s for x in tl if x.signal == "PSD" and x.value == "closed_locked"]
            if doors_locked and psd_locked:
                close_lag.append(psd_locked[-1] - doors_locked[-1])
            if r.departure_s is not None:
                depart.append(r.departure_s)
            misreads += r.camera_misreads
            frames += r.camera_frames
            unsafe += _unsafe(tl)
        rate = args.dwells / (time.perf_counter() - t0)
        shown = ", ".join(f"{k} {v}" for k, v in outcomes.items() if v)

        def span(xs: list[float]) -> str:
            return f"{statistics.fmean(xs):.2f}/{max(xs):.2f}" if xs else "-"

        print(
            f"{p:8.2f} {k:8d} {shown:36s} {span(open_lag):>11s} {span(close_lag):>12s} {span(depart):>12s} "
            f"{misreads / max(frames, 1):8.2%} {unsafe:7d} {rate:9.0f}"
        )
    print("lags and departure: mean/max; misread: share of frames; unsafe: PSD moves the interlock forbids")


if __name__ == "__main__":
    main()
