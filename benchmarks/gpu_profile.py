"""Where the stop kernel's time goes on a GPU: compile options and the runs' order, side by side.

    python benchmarks/gpu_profile.py [--controller tasc-pwm] [--runs 1000000]
                                     [--variants default,regs128,regs96]
    python benchmarks/gpu_profile.py --one default --profile --runs 40000 --lineinfo   # under a profiler

For each variant (``default``: the compiler's registers; ``regsN``: at most N
registers per thread; ``draws-L``: the draws laid out as ``L``, one of
``rows``, ``launch-order``, ``columns``; ``railstop.model.gpu.KernelOptions``), compiled side by
side in processes of their own and timed one at a time on the GPU (a lock
file): the kernel's time for the same ``--runs`` runs (standard set at the
default station, seed 1) handed to the threads

- ``natural``: in their order;
- ``ordered``: by entry speed (``model.gpu.launch_order``: the default for the
  TASC controllers, whatever the controller here);
- ``alike``: every thread the draws of run 0 (its own run index, so its own
  noise): how fast the kernel is when a warp's runs take nearly the same path,
  an upper bound for any order of the real runs.

Printed per variant: registers and local memory per thread, runs/s of each
order, whether the ordered and natural results are identical, and whether each
variant's results equal the first variant's (the options change no result). ``--one``
runs one variant's warm-up and one launch, for Nsight Compute to profile
(``ncu --launch-skip 1 --launch-count 1 -k regex:stop_kernel``); ``--lineinfo``
maps its machine code to the model's Python lines.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from gpu_throughput import SEED, _draw, compiled, gpu_lock, side_by_side


def _options(variant: str, lineinfo: bool):  # type: ignore[no-untyped-def]
    from railstop.model.gpu import DRAW_LAYOUTS, KernelOptions

    if variant == "default":
        return KernelOptions(lineinfo=lineinfo)
    if variant.startswith("draws-") and variant[len("draws-") :] in DRAW_LAYOUTS:  # in device memory
        return KernelOptions(lineinfo=lineinfo, draws=variant[len("draws-") :])
    if variant.startswith("regs") and variant[4:].isdigit():
        return KernelOptions(max_registers=int(variant[4:]), lineinfo=lineinfo)
    raise SystemExit(
        f"gpu_profile: variant {variant!r}: default, regsN (e.g. regs128) or draws-L, L one of "
        f"{', '.join(DRAW_LAYOUTS)}"
    )


def _alike(scenario, n: int):  # type: ignore[no-untyped-def]
    """The scenario with every run given run 0's draws (the gradient: run 0's, broadcast)."""
    import dataclasses

    from railstop.config.gradient import GradientProfile

    changes = {}
    for f in dataclasses.fields(scenario):
        value = getattr(scenario, f.name)
        if isinstance(value, GradientProfile):
            changes[f.name] = GradientProfile.create(value.breakpoints_m, value.values_permille[:1])
        elif isinstance(value, np.ndarray) and value.ndim == 1:
            changes[f.name] = np.repeat(value[:1], n)
    return scenario.with_values(**changes)


def one(
    controller: str,
    variant: str,
    runs: int,
    lineinfo: bool,
    lock: Path | None,
    profile: bool,
    save: Path | None = None,
) -> dict:
    from railstop.model import gpu

    options = _options(variant, lineinfo)
    station, vehicle, dist, model, out = compiled(controller, options)
    out["variant"] = variant
    scenario = _draw(station, vehicle, dist, 0, runs)
    timings: dict[str, float] = {}
    with gpu_lock(lock):  # one variant at a time on the GPU
        if profile:  # one launch, for the profiler
            gpu.run_kernel_gpu(model, scenario, seed=SEED, first_run=0, timings=timings, options=options)
            out["kernel_s"] = round(timings["kernel"], 3)
            return out
        results = {}
        for name, sc, order in (
            ("natural", scenario, "drawn"),
            ("ordered", scenario, "entry-speed"),
            ("alike", _alike(scenario, runs), "drawn"),
        ):
            res, _ = gpu.run_kernel_gpu(
                model, sc, seed=SEED, first_run=0, timings=timings, order=order, options=options
            )
            out[f"{name}_runs_per_s"] = round(runs / timings["kernel"])
            results[name] = res
    out["ordered_equals_natural"] = bool(
        np.array_equal(results["ordered"], results["natural"], equal_nan=True)
    )
    out["mean_stop_time_s"] = float(np.nanmean(results["natural"][:, 1]))
    if save is not None:  # for the comparison between variants
        np.save(save, results["natural"])
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--controller", default="tasc-pwm")
    ap.add_argument("--runs", type=int, default=1_000_000)
    ap.add_argument("--variants", default="default")
    ap.add_argument("--lineinfo", action="store_true")
    ap.add_argument("--one", default=None, help="one variant in this process (for a profiler)")
    ap.add_argument("--profile", action="store_true", help="with --one: one launch of --runs runs")
    ap.add_argument("--lock", type=Path, default=None, help="a lock file: one process at a time on the GPU")
    ap.add_argument("--save-dir", type=Path, default=None, help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.one is not None:
        save = None if a.save_dir is None else a.save_dir / f"{a.one}.npy"
        result = one(a.controller, a.one, a.runs, a.lineinfo, a.lock, profile=a.profile, save=save)
        print("RESULT " + json.dumps(result), flush=True)
        return
    from railstop.model.gpu import gpu_unavailable

    why = gpu_unavailable()
    if why is not None:
        print(f"gpu_profile: {why}", file=sys.stderr)
        raise SystemExit(2)
    lock = a.lock if a.lock is not None else Path(tempfile.mkdtemp()) / "gpu.lock"
    saved = Path(tempfile.mkdtemp())
    base = [
        sys.executable,
        __file__,
        "--controller",
        a.controller,
        "--runs",
        str(a.runs),
        "--lock",
        str(lock),
        "--save-dir",
        str(saved),
    ]
    variants = [v for v in a.variants.split(",") if v]
    for v in variants:
        _options(v, a.lineinfo)  # a variant this benchmark does not know: one line, before any work
    print(f"{a.controller}, {a.runs:,} runs: kernel runs/s by the order of the runs")
    print(
        f"{'variant':18s} {'regs':>5s} {'local B':>8s} {'compile s':>9s} "
        f"{'natural':>10s} {'ordered':>10s} {'alike':>10s}"
    )
    for v, r in side_by_side(base, variants, 18):
        regs = (r.get("registers") or ["-"])[0]
        local = (r.get("local_bytes") or ["-"])[0]
        print(
            f"{v:18s} {regs!s:>5s} {local!s:>8s} "
            f"{r['compile_s']:9.1f} {r['natural_runs_per_s']:10,d} {r['ordered_runs_per_s']:10,d} "
            f"{r['alike_runs_per_s']:10,d}  ordered = natural: {r['ordered_equals_natural']}"
        )
        print("  " + json.dumps(r), flush=True)
    done = [v for v in variants if (saved / f"{v}.npy").exists()]
    for v in done[1:]:
        same = np.array_equal(np.load(saved / f"{v}.npy"), np.load(saved / f"{done[0]}.npy"), equal_nan=True)
        print(f"{v}: results identical to {done[0]}'s: {same}")


if __name__ == "__main__":
    os.environ.setdefault("PYTHONUNBUFFERED", "1")
    main()
