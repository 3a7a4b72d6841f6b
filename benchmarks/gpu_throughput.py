"""The stop model on an NVIDIA GPU (``railstop.model.gpu``): throughput and equality with the CPU.

    python benchmarks/gpu_throughput.py [--runs 2000000] [--check-runs 10000]
                                        [--controllers tasc-pwm,ato,...] [--cpu-rows FILE]
    python benchmarks/gpu_throughput.py --save-cpu-rows FILE [--check-runs 10000] [--controllers ...]

For each controller, standard disturbance set at the default station (as
``campaign_throughput.py``): the kernel is compiled (one process per
controller, compiling side by side on the host's cores), then, one
controller at a time on the GPU (a lock file), ``--runs`` runs in launches of
``--launch`` runs, timed per stage: the draws on the host, the copies, the
kernel (synchronised) and end to end; then the first ``--check-runs`` runs
(seed 1, runs 0..) against the CPU's rows of the same runs: computed here by
the CPU model, or read from ``--cpu-rows`` (written by ``--save-cpu-rows`` on
another machine: the draws are counter-based, so the rows are the same
runs). Printed per controller: runs/s (kernel, end to end), the largest
difference of the stop error and stop time over the runs whose discrete
results agree, and how many runs are bit-identical or differ in a discrete
result (emergency brake, notch changes, commands, re-stops, stopped).
"""

from __future__ import annotations

import argparse
import fcntl
import json
import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np

SEED = 1
# The result columns compared (railstop.model.records RES_*): continuous, and discrete.
CONTINUOUS = {"stop_error_m": 0, "stop_time_s": 1, "max_jerk_mps3": 2}
DISCRETE = {"notch_changes": 3, "sent": 4, "received": 5, "stopped": 6, "eb": 12, "restops": 18}


def _setup(controller: str):  # type: ignore[no-untyped-def]
    from railstop.config import default_line, default_vehicle
    from railstop.config.disturbances import load_disturbances
    from railstop.model.build import KernelModel

    line, vehicle = default_line(), default_vehicle()
    station = line.stations[0]
    model = KernelModel.create(
        station=station,
        vehicle=vehicle,
        controller=controller,
        form=None,
        dt_s=0.01,
        max_time_s=150.0,
        track=line.track,
    )
    return station, vehicle, load_disturbances("standard"), model


def _draw(station, vehicle, dist, first: int, n: int):  # type: ignore[no-untyped-def]
    from railstop.config.disturbances import draw_scenario
    from railstop.streams import RunStreams

    return draw_scenario(dist, station, vehicle, RunStreams.for_runs(SEED, first, n))[0]


def cpu_rows(controller: str, n: int) -> np.ndarray:
    from railstop.model.run import run_kernel

    station, vehicle, dist, model = _setup(controller)
    res, _, _ = run_kernel(model, _draw(station, vehicle, dist, 0, n), seed=SEED, first_run=0)
    return res


def compiled(controller: str, options=None) -> tuple:  # type: ignore[no-untyped-def]
    """Set up ``controller`` (``_setup``) and compile its kernel with a launch of 64 runs:
    (station, vehicle, disturbances, model, figures: the compilation's seconds and the kernel's
    registers and local bytes per thread, which numba's simulator does not have)."""
    from railstop.model import gpu

    station, vehicle, dist, model = _setup(controller)
    out: dict = {"controller": controller}
    t = time.perf_counter()
    extra = {} if options is None else {"options": options}
    gpu.run_kernel_gpu(model, _draw(station, vehicle, dist, 0, 64), seed=SEED, first_run=0, **extra)
    out["compile_s"] = round(time.perf_counter() - t, 1)
    for kernel in gpu._KERNELS.values():  # the kernel's resources per thread (not in the simulator)
        try:
            out["registers"] = [int(o.regs_per_thread) for o in kernel.overloads.values()]
            out["local_bytes"] = [int(o.local_mem_per_thread) for o in kernel.overloads.values()]
        except Exception as exc:  # numba's simulator has no such figures
            out["resources"] = f"{type(exc).__name__}: {exc}"
    return station, vehicle, dist, model, out


@contextmanager
def gpu_lock(path: Path | None) -> Iterator[None]:
    """Hold the lock file ``path`` (None: no lock) while timing, so that the benchmarks' processes
    time their launches one at a time on the GPU."""
    if path is None:
        yield
        return
    with open(path, "w") as held:
        fcntl.flock(held, fcntl.LOCK_EX)
        yield


def one(
    controller: str, runs: int, launch: int, check_runs: int, rows: Path | None, lock: Path, sweep: list[int]
) -> dict:
    from railstop.model.gpu import run_kernel_gpu

    station, vehicle, dist, model, out = compiled(controller)
    timings: dict[str, float] = {}
    expected = (
        np.load(rows)[controller][:check_runs] if rows is not None else cpu_rows(controller, check_runs)
    )
    with gpu_lock(lock):  # one controller at a time on the GPU
        stages = {"draw": 0.0, "compile_and_to_device": 0.0, "kernel": 0.0, "to_host": 0.0}
        t_all = time.perf_counter()
        first = 0
        while first < runs:
            n = min(launch, runs - first)
            t = time.perf_counter()
            scenario = _draw(station, vehicle, dist, first, n)
            stages["draw"] += time.perf_counter() - t
            run_kernel_gpu(model, scenario, seed=SEED, first_run=first, timings=timings)
            for k in ("compile_and_to_device", "kernel", "to_host"):
                stages[k] += timings[k]
            first += n
        wall = time.perf_counter() - t_all
        got, _ = run_kernel_gpu(model, _draw(station, vehicle, dist, 0, check_runs), seed=SEED, first_run=0)
        if sweep:
            # The block size: the same runs launched with each, kernel time alone.
            scenario = _draw(station, vehicle, dist, 0, launch)
            out["threads_per_block_runs_per_s"] = {}
            for threads in sweep:
                run_kernel_gpu(
                    model, scenario, seed=SEED, first_run=0, timings=timings, threads_per_block=threads
                )
                out["threads_per_block_runs_per_s"][threads] = round(launch / timings["kernel"])
    out["runs"] = runs
    out["kernel_runs_per_s"] = round(runs / stages["kernel"])
    out["end_to_end_runs_per_s"] = round(runs / wall)
    out["stages_s"] = {k: round(v, 3) for k, v in stages.items()}
    same_events = np.ones(check_runs, dtype=bool)
    for j in DISCRETE.values():
        same_events &= (got[:, j] == expected[:, j]) | (np.isnan(got[:, j]) & np.isnan(expected[:, j]))
    identical = np.all((got == expected) | (np.isnan(got) & np.isnan(expected)), axis=1)
    out["check_runs"] = check_runs
    out["bit_identical"] = int(identical.sum())
    out["discrete_differs"] = int((~same_events).sum())
    for name, j in CONTINUOUS.items():
        d = np.abs(got[same_events, j] - expected[same_events, j])
        d = d[np.isfinite(d)]
        out[f"max_diff_{name}"] = float(d.max()) if d.size else 0.0
    return out


def side_by_side(base: list[str], names: list[str], width: int) -> Iterator[tuple[str, dict]]:
    """Run ``base --one NAME`` for every name at once (each compiles in a process of its own), then
    yield each one's result (its last ``RESULT`` line) in order; a failure is printed and skipped."""
    procs = {n: subprocess.Popen([*base, "--one", n], stdout=subprocess.PIPE, text=True) for n in names}
    for name, proc in procs.items():
        stdout, _ = proc.communicate()
        lines = [ln for ln in stdout.splitlines() if ln.startswith("RESULT ")]
        if proc.returncode != 0 or not lines:
            print(f"{name:{width}s} failed (exit {proc.returncode})")
            continue
        yield name, json.loads(lines[-1][len("RESULT ") :])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=int, default=2_000_000)
    ap.add_argument("--launch", type=int, default=1_000_000, help="runs per kernel launch")
    ap.add_argument("--check-runs", type=int, default=10_000)
    ap.add_argument("--controllers", default="tasc-pwm")
    ap.add_argument("--cpu-rows", type=Path, default=None)
    ap.add_argument("--save-cpu-rows", type=Path, default=None)
    ap.add_argument("--sweep-threads", default="", help="block sizes to time, e.g. 32,64,128,256")
    ap.add_argument("--one", default=None, help=argparse.SUPPRESS)
    ap.add_argument("--lock", type=Path, default=None, help="a lock file: one process at a time on the GPU")
    a = ap.parse_args()
    controllers = [c for c in a.controllers.split(",") if c]
    if a.save_cpu_rows is not None:
        np.savez_compressed(a.save_cpu_rows, **{c: cpu_rows(c, a.check_runs) for c in controllers})
        print(f"CPU rows of {a.check_runs} runs for {', '.join(controllers)} in {a.save_cpu_rows}")
        return
    if a.one is not None:
        sweep = [int(t) for t in a.sweep_threads.split(",") if t]
        result = one(a.one, a.runs, a.launch, a.check_runs, a.cpu_rows, a.lock, sweep)
        print("RESULT " + json.dumps(result), flush=True)
        return
    from railstop.model.gpu import gpu_unavailable

    why = gpu_unavailable()
    if why is not None:
        print(f"gpu_throughput: {why}", file=sys.stderr)
        raise SystemExit(2)
    from numba import cuda

    dev = cuda.get_current_device()
    name = getattr(dev, "name", b"numba's CUDA simulator")
    print(f"device: {name.decode() if isinstance(name, bytes) else name}, cc {dev.compute_capability}")
    lock = a.lock if a.lock is not None else Path(tempfile.mkdtemp()) / "gpu.lock"
    base = [sys.executable, __file__, "--runs", str(a.runs), "--launch", str(a.launch)]
    base += ["--check-runs", str(a.check_runs), "--lock", str(lock), "--sweep-threads", a.sweep_threads]
    if a.cpu_rows is not None:
        base += ["--cpu-rows", str(a.cpu_rows)]
    head = f"{'controller':22s} {'compile s':>9s} {'kernel runs/s':>14s} {'end-to-end':>11s}"
    print(f"{head}  equality on the check runs")
    for c, r in side_by_side(base, controllers, 22):
        print(
            f"{c:22s} {r['compile_s']:9.1f} {r['kernel_runs_per_s']:14,d} {r['end_to_end_runs_per_s']:11,d}  "
            f"{r['bit_identical']}/{r['check_runs']} bit-identical, {r['discrete_differs']} differ in a "
            f"discrete result; max |diff| error {r['max_diff_stop_error_m']:.2e} m, "
            f"time {r['max_diff_stop_time_s']:.2e} s"
        )
        print("  " + json.dumps(r), flush=True)


if __name__ == "__main__":
    os.environ.setdefault("PYTHONUNBUFFERED", "1")
    main()
