"""The station stop on an NVIDIA GPU: the CPU's model, compiled by numba-cuda for the device.

One source, two targets. The CUDA kernel here holds no model of its own: each
GPU thread runs one run through :func:`railstop.model.run.run_steps`, the
run loop the CPU's ``simulate_run`` runs, which numba-cuda compiles again
for the device from the same Python source (every per-step function of the
stop is a plain scalar function of named records, :mod:`railstop.model.records`).
What differs is only where a run's state lives: on the CPU in arrays allocated
once per block (:func:`railstop.model.records.new_state`), those of constant
shape on ``simulate_run``'s stack for each run (``state_on_stack``), here in each
thread's local memory (``cuda.local.array`` of the same dtypes and shapes,
which the kernel factory fixes as constants per model: the longest dead time,
the radar window, the tachometer's window, the frames in flight, the
positioning log, the track circuits). Both are made from one list of work
arrays, :data:`railstop.model.records.STATE_FIELDS`, so a field added to the
state cannot be forgotten here.

Exactness policy **[interpretation]** (the issue asks for a stated bound):

- the model's scalar maths is ``math.*`` (and :func:`railstop.jit.rint_1`,
  ``ceil_1``), which both targets compile;
- the kernel is compiled with FMA contraction off (``fastmath`` off, and
  NVVM's ``fma`` option 0) so that ``a * b + c`` rounds twice on the device
  as on the CPU;
- ``exp``, ``log``, ``cos``, ``expm1`` and ``log1p`` come from CUDA's
  libdevice on the device and from the C library on the CPU; both are
  within 1-2 ulp of the exact result, but not always the same ulp. A run's
  results are therefore equal to the CPU's within a bound, not always to
  the bit: the stated bound is 1e-9 m on the stop error and 1e-9 s on the
  stop time of every run whose discrete events (emergency brake, notch
  changes, commands) agree, and the share of runs whose events differ at
  most 1e-3 (one ulp can move a threshold decision).
  ``benchmarks/gpu_throughput.py`` measures both on a GPU (one H200, stop
  models 9 and 10: no discrete result differed in 100,000 runs of the ten
  controllers, the largest difference was 3.4e-12 m; docs/gpu.md); the tests check the
  wiring bit for bit in numba's CUDA simulator.

What runs on the GPU: the built-in controllers (a law loaded from a user's
file runs on the CPU only: on the CPU it is compiled with bounds checks and
wrapped so that its errors become a full-service demand, which the device
cannot do; HZ-LAW-01 holds only there), without recording (the detailed
stop is one run, on the CPU). The scenario is drawn on the host (its
counter-based streams, :mod:`railstop.streams`) and copied over: a few
hundred bytes per run against thousands of 10 ms steps of work.

Optional: numba-cuda is the extra ``railstop[gpu]``; without it (or without
a GPU) :func:`gpu_unavailable` says why and ``--device gpu`` exits 2 with
that line. ``NUMBA_ENABLE_CUDASIM=1`` runs the same kernel in numba's CUDA
simulator (each thread in Python, the model's functions through their CPU
compilation): what CI tests, on a few runs.
"""

from __future__ import annotations

import math
import os
import time
import warnings
from dataclasses import dataclass
from typing import Any

import numpy as np
from numba.core.errors import NumbaError, NumbaPerformanceWarning
from numpy.typing import NDArray

from railstop.config.scenario import Scenario
from railstop.controllers import CONTROLLERS, TASC_CONTROLLERS
from railstop.errors import SimulationError
from railstop.messages import TEL_SIZE
from railstop.model.build import KernelModel, control_law_of, stop_params
from railstop.model.records import (
    LA_SIZE,
    RC_SIZE,
    RES_SIZE,
    RUN_DTYPE,
    SC_ENTRY_SPEED,
    STATE_FIELDS,
    STATE_SIZES,
    STREAMS,
    TR_SIZE,
    FloatArray,
    Recording,
    RunParams,
    StopOutputs,
    StopState,
    state_shape,
)
from railstop.model.run import (
    KernelRecord,
    model_draws,
    ring_steps,
    run_kernel,
    run_steps,
    simulate_block,
    state_sizes,
)
from railstop.stream_cores import seed_key
from railstop.streams import seed_u64
from railstop.wayside.tasc_unit import CR_SIZE

#: Threads per block. Measured for tasc-pwm on one H200 (stop model 9, 1,000,000 runs as drawn,
#: kernel alone; the kernel used 255 registers and 7,984 bytes of local memory per thread):
#: 32: 195,460 runs/s, 64: 200,699, 128: 209,736, 256: 224,476
#: (benchmarks/gpu_throughput.py --sweep-threads).
THREADS_PER_BLOCK = 256
#: The dead time's ring is a multiple of this many steps (one kernel for every chunk's draws).
RING_QUANTUM = 64


def _one_line(exc: BaseException) -> str:
    """An error of the driver on one line: its kind and its words (the driver's messages run over
    several lines, the first often empty of meaning), at most 200 characters."""
    words = " ".join(str(exc).split())
    text = f"{type(exc).__name__}: {words}" if words else type(exc).__name__
    return text if len(text) <= 200 else text[:199] + "…"


def _numpy_shim() -> None:
    """numba-cuda 0.30 reads ``numpy.row_stack``, which numpy 2.5 removed (``vstack`` under its old
    name); set before numba-cuda is imported."""
    if not hasattr(np, "row_stack"):
        setattr(np, "row_stack", np.vstack)  # noqa: B010 (numpy 2.5 stubs lack the name)


def cuda_simulated() -> bool:
    """Whether numba's CUDA simulator stands in for a GPU (``NUMBA_ENABLE_CUDASIM=1``)."""
    return os.environ.get("NUMBA_ENABLE_CUDASIM", "") == "1"


def gpu_unavailable() -> str | None:
    """Why ``--device gpu`` cannot run here (None: it can): no numba-cuda, or no GPU."""
    _numpy_shim()
    try:
        from numba import cuda
    except ImportError:  # pragma: no cover - numba always ships numba.cuda's shim
        return "numba-cuda is not installed (pip install 'railstop[gpu]')"
    try:
        import numba_cuda  # noqa: F401
    except ImportError:
        if not cuda_simulated():
            return "numba-cuda is not installed (pip install 'railstop[gpu]')"
    if cuda_simulated():
        return None
    try:
        if not cuda.is_available():
            return "no CUDA GPU is available (numba-cuda finds no device or driver)"
    except Exception as exc:  # the driver's own errors come in many kinds
        return f"no CUDA GPU is available ({_one_line(exc)})"
    return None


@dataclass(frozen=True, slots=True)
class Shapes:
    """The constant shapes of one run's work arrays (each GPU thread's local memory): the CPU's
    sizes (``model.run.state_sizes``), the dead time's ring rounded up."""

    ring: int
    window: int
    tach_window: int
    in_flight: int
    log_len: int
    circuits: int

    @classmethod
    def of(cls, model: KernelModel, sc: FloatArray) -> Shapes:
        # The ring needs the longest delay + 1 steps; any longer ring gives the same results
        # (brake.actuator_step_1 indexes it modulo its length, as the CPU's blocks of different
        # maxima do). Rounded up to RING_QUANTUM so that the chunks of a campaign, each with its
        # own longest draw, share one compiled kernel.
        ring = -(-ring_steps(model, sc) // RING_QUANTUM) * RING_QUANTUM
        return cls(**state_sizes(model, ring))

    def sizes(self) -> dict[str, int]:
        return {name: int(getattr(self, name)) for name in STATE_SIZES}


def _host(value: Any) -> Any:
    """In numba's CUDA simulator: the numpy array behind a simulated device array (tuples and
    named tuples element by element), which the model's CPU compilation takes."""
    if isinstance(value, tuple):
        items = [_host(v) for v in value]
        return type(value)(*items) if hasattr(value, "_fields") else tuple(items)
    return getattr(value, "_ary", value)


def _read_only(a: np.ndarray) -> np.ndarray:
    view = a.view()
    view.flags.writeable = False
    return view


def _column_as_row(a: np.ndarray, g: int, read_only: bool) -> np.ndarray:
    """In numba's CUDA simulator: column ``g`` of the draws laid out by columns, as the one-row
    block the CPU's compiled model takes (read-only where the CPU's signature has it so)."""
    row = np.ascontiguousarray(a[:, g])[None, :]
    return _read_only(row) if read_only else row


#: How a launch lays the runs' draws out in device memory (:class:`KernelOptions`).
DRAW_LAYOUTS = ("rows", "launch-order", "columns")


def _kernel_source(shapes: Shapes, simulated: bool = False, draws: str = "rows") -> str:
    """The kernel's Python source for ``shapes``: one local array per work array of
    ``records.STATE_FIELDS``, set to its initial value as ``new_state`` sets it, then the run
    (generated, so that the one list of work arrays makes both the CPU's state and the device's).
    ``draws``: how the draws are laid out (:class:`KernelOptions`)."""
    sizes = shapes.sizes()
    # Where thread g finds its run's draws: row order[g] of the drawn rows, row g of the rows
    # copied in launch order, or column g of the columns copied in launch order.
    at = "r" if draws == "rows" else "g"
    if draws == "columns":
        sc_run, gv_run, ge_run = "sc[:, g]", "gv[:, g]", "ge[:, g]"
        sim_rows = "COLUMN(sc, g, False), COLUMN(gv, g, grad_read_only), COLUMN(ge, g, grad_read_only)"
    else:
        sc_run, gv_run, ge_run = f"sc[{at}]", f"gv[{at}]", f"ge[{at}]"
        sim_rows = f"sc[{at} : {at} + 1], gv[{at} : {at} + 1], ge[{at} : {at} + 1]"
    lines = [
        "def stop_kernel(seed, seed_keys, first_run, order, p, sc, gv, ge, res, passages, rec_arrays,"
        " rec_counters, grad_read_only):",
        "    g = cuda.grid(1)",
        "    if g >= order.shape[0]:",  # one thread per run
        "        return",
        # Thread g runs the draws' row order[g] (its run index, its results' row): the host
        # orders the runs so that a warp's runs take about as many steps (launch_order).
        "    r = order[g]",
    ]
    if simulated:
        lines.append(
            "    seed_keys, p, sc, gv, ge, res, passages, rec_arrays, rec_counters = HOST("
            "(seed_keys, p, sc, gv, ge, res, passages, rec_arrays, rec_counters))"
        )
        # A broadcast gradient is read-only on the host: the CPU's compiled signature has that type
        # (a writable copy would be another type, compiled again).
        lines.append("    gv, ge = (READ_ONLY(gv), READ_ONLY(ge)) if grad_read_only else (gv, ge)")
    for i, (name, shape, dtype, fill) in enumerate(STATE_FIELDS):
        dims = state_shape(shape, sizes)
        lines.append(f"    {name} = cuda.local.array({dims!r}, DTYPES[{i}])")
        if dtype.names is not None:
            continue  # records: stop_init sets every field it reads
        index = ", ".join(chr(105 + d) for d in range(len(dims)))  # i, j
        indent = "    "
        for d, n in enumerate(dims):
            lines.append(f"{indent}for {chr(105 + d)} in range({n}):")
            indent += "    "
        value = "NAN" if math.isnan(fill) else (str(int(fill)) if dtype.kind in "iu" else repr(float(fill)))
        lines.append(f"{indent}{name}[{index}] = {value}")
    args = ", ".join(name for name, _, _, _ in STATE_FIELDS)
    lines += [
        f"    s = StopState({args})",
        "    derived = cuda.local.array(1, RUN_DTYPE)",
        f"    run = RunParams({sc_run}, (p.bp, {gv_run}, {ge_run}), derived)",
        "    rec = Recording(False, rec_arrays[0], rec_arrays[1], rec_arrays[2], rec_arrays[3],"
        " rec_arrays[4], rec_counters)",
    ]
    if simulated:
        # The simulator runs this body in Python and the model through its CPU compilation: the
        # CPU's block of one run on this thread's state (simulate_block runs the same run loop
        # as the line below, through its cached compiled signature).
        lines.append(
            f"    simulate_block(seed, first_run + r, p, {sim_rows}, s,"
            " res[r : r + 1], passages[r : r + 1], rec, LAW)"
        )
    else:
        # The CPU's run loop on this thread's local arrays (the CPU's simulate_run puts them on
        # its stack first, which the device's local arrays already are).
        lines.append(
            "    run_steps(p, run, s, StopOutputs(res[r], passages[r], rec), seed_keys, first_run + r, LAW)"
        )
    return "\n".join(lines) + "\n"


@dataclass(frozen=True, slots=True)
class KernelOptions:
    """How the kernel is compiled (the results do not depend on it): ``max_registers`` caps the
    registers per thread (None: the compiler's choice, 255 for the stop model; fewer let more
    threads be resident per multiprocessor, at the price of spills to local memory);
    ``lineinfo`` maps the machine code to the model's Python lines for a profiler (Nsight
    Compute's source view) without changing the code; ``draws``: how the runs' draws lie in
    device memory, one of :data:`DRAW_LAYOUTS`: ``rows`` as drawn (thread g reads row
    ``order[g]``), ``launch-order`` (the rows copied in launch order: thread g reads row g, so a
    warp reads neighbouring rows), ``columns`` (one column per run, in launch order: the threads
    of a warp read neighbouring words of each draw, one coalesced load: the fastest of the three
    in every order for the two controllers measured on one H200, docs/gpu.md, but not yet the
    default, its throughput for every controller unmeasured). Each thread reads the same numbers
    in every layout."""

    max_registers: int | None = None
    lineinfo: bool = False
    draws: str = "rows"

    def __post_init__(self) -> None:
        if self.draws not in DRAW_LAYOUTS:
            raise SimulationError(f"draws layout {self.draws!r}: one of {', '.join(DRAW_LAYOUTS)}")


_KERNELS: dict[tuple[Shapes, str, KernelOptions], Any] = {}


def _fma_off() -> None:
    """Compile without contracting ``a * b + c`` into one fused multiply-add (the exactness
    policy above): NVVM contracts by default, and numba-cuda's ``cuda.jit`` has no option for it,
    so NVVM's compile call gets ``fma=0`` unless the caller asked for fast maths.
    **[interpretation]** this wraps numba-cuda's ``nvvm.compile_ir`` (its module function, which
    its code generator calls by name); a later numba-cuda that renames it leaves FMA on, which
    the equality check (``benchmarks/gpu_throughput.py``) would show as a wider difference."""
    from numba.cuda.cudadrv import nvvm

    compile_ir = nvvm.compile_ir
    if getattr(compile_ir, "railstop_fma_off", False):
        return

    def compile_ir_fma_off(llvmir: Any, **options: Any) -> Any:
        if not options.get("fastmath"):
            options.setdefault("fma", False)
        return compile_ir(llvmir, **options)

    compile_ir_fma_off.railstop_fma_off = True  # type: ignore[attr-defined]
    nvvm.compile_ir = compile_ir_fma_off


def _kernel(shapes: Shapes, controller: str, options: KernelOptions = KernelOptions()) -> Any:
    """The compiled (on first launch) CUDA kernel for ``shapes`` and ``controller``'s law: one
    kernel per controller and shapes (numba-cuda specialises it; the CPU's one compiled model
    takes the law as a function pointer, which the device has not)."""
    key = (shapes, control_law_of(controller).name, options)
    if key not in _KERNELS:
        from numba import cuda, njit

        if not cuda_simulated():
            _fma_off()
        law = control_law_of(controller)
        namespace: dict[str, Any] = {
            "cuda": cuda,
            "NAN": np.nan,
            "DTYPES": tuple(dtype for _, _, dtype, _ in STATE_FIELDS),
            "RUN_DTYPE": RUN_DTYPE,
            "StopState": StopState,
            "RunParams": RunParams,
            "Recording": Recording,
            "StopOutputs": StopOutputs,
            "run_steps": run_steps,
            "simulate_block": simulate_block,
            # The simulator runs the kernel in Python and the model through its CPU compilation:
            # the CPU's law (a function pointer) keeps the model's compiled signature, cached.
            "LAW": law.compiled() if cuda_simulated() else njit(error_model="numpy")(law.function),
        }
        namespace["HOST"] = _host
        namespace["READ_ONLY"] = _read_only
        namespace["COLUMN"] = _column_as_row
        source = _kernel_source(shapes, simulated=cuda_simulated(), draws=options.draws)
        exec(compile(source, f"<railstop gpu kernel {key[1]}>", "exec"), namespace)
        extra: dict[str, Any] = {}
        if options.max_registers is not None and not cuda_simulated():
            extra["max_registers"] = int(options.max_registers)
        if options.lineinfo and not cuda_simulated():
            extra["lineinfo"] = True
        _KERNELS[key] = cuda.jit(fastmath=False, opt=True, **extra)(namespace["stop_kernel"])
    return _KERNELS[key]


def check_gpu_model(model: KernelModel) -> None:
    """Refuse what the device does not run (a ``SimulationError`` naming it)."""
    if model.controller not in CONTROLLERS:
        raise SimulationError(
            f"{model.controller}: a law loaded from a file runs on the CPU only (the GPU cannot check "
            "its indices nor catch its errors); run it without --device gpu"
        )


def run_kernel_gpu(
    model: KernelModel,
    scenario: Scenario,
    *,
    seed: int,
    first_run: int,
    timings: dict[str, float] | None = None,
    threads_per_block: int = THREADS_PER_BLOCK,
    order: str = "auto",
    options: KernelOptions = KernelOptions(),
) -> tuple[FloatArray, FloatArray]:
    """``run_kernel`` on the GPU: (results (n, RES_SIZE), true passage times (n, D)), no recording.

    ``threads_per_block``: the launch's block size; ``order``: how the runs are handed to the
    threads (:func:`launch_order`); ``options``: how the kernel is compiled. The results
    depend on none of them.
    ``timings``, if given, gets the seconds of each stage: ``compile_and_to_device`` (the
    kernel's compilation on its first launch for its shapes and law, and the copies to the
    device), ``kernel`` and ``to_host``. An error of the GPU or its driver is a
    :class:`SimulationError` of one line (HZ-GPU-03)."""
    why = gpu_unavailable()
    if why is not None:
        raise SimulationError(f"--device gpu: {why}")
    check_gpu_model(model)

    sc, bp, gv, ge = model_draws(model, scenario)
    n = scenario.n
    res = np.empty((n, RES_SIZE))
    passages = np.empty((n, model.det_pos.size))
    if n == 0:
        return res, passages
    rows = launch_order(sc, model.controller, order)
    try:
        _launch(
            model,
            (sc, bp, gv, ge),
            rows,
            res,
            passages,
            seed,
            first_run,
            timings,
            threads_per_block,
            options,
        )
    except (SimulationError, NumbaError):
        raise  # our own refusals, and numba's typing and compilation errors (a defect, not the GPU)
    except Exception as exc:  # the CUDA driver's and runtime's errors come in many kinds
        raise SimulationError(f"--device gpu: the GPU failed ({_one_line(exc)})") from None
    return res, passages


#: How a launch hands its runs to the threads (:func:`launch_order`).
ORDERS = ("auto", "drawn", "entry-speed")


def launch_order(sc: FloatArray, controller: str, how: str = "auto") -> NDArray[np.int64]:
    """The order in which a launch hands its runs to the threads (thread g runs row order[g]):
    ``drawn``, ``entry-speed``, or ``auto``: by entry speed for the TASC controllers, as drawn
    for the others.

    A warp's 32 threads run in lockstep until the last of their runs stands, so a warp costs the
    steps of its longest run. The entry speed sets most of a stop's length (on the standard set
    its correlation with tasc-pwm's stop time is -0.79), so neighbours in this order take about
    as many steps. Measured on one H200 (``benchmarks/gpu_profile.py``, 1,000,000 runs, kernel
    alone, the draws in rows; docs/gpu.md): tasc-pwm 223,632 -> 270,801 runs/s (stop model 11),
    tasc-step 147,120 -> 187,167 (model 10); but ato 1,780,967 -> 1,581,039 (model 11) and
    driver-atc2 774,013 -> 661,666 (model 10), so ``auto`` keeps the drawn order for those. Each
    thread still runs its own row and run index: the results are the same in any order. Stable,
    so equal speeds keep their order."""
    if how not in ORDERS:
        raise SimulationError(f"launch order {how!r}: one of {', '.join(ORDERS)}")
    if how == "entry-speed" or (how == "auto" and controller in TASC_CONTROLLERS):
        return np.argsort(sc[:, SC_ENTRY_SPEED], kind="stable").astype(np.int64)
    return np.arange(sc.shape[0], dtype=np.int64)


def _launch(
    model: KernelModel,
    draws: tuple[FloatArray, FloatArray, FloatArray, FloatArray],
    order: NDArray[np.int64],
    res: FloatArray,
    passages: FloatArray,
    seed: int,
    first_run: int,
    timings: dict[str, float] | None,
    threads_per_block: int,
    options: KernelOptions,
) -> None:
    """Copy the draws and the station's parameters to the device, run the kernel, copy the
    results back into ``res`` and ``passages``."""
    import numba
    from numba import cuda

    sc, bp, gv, ge = draws
    n = sc.shape[0]
    clock = time.perf_counter
    t0 = clock()
    shapes = Shapes.of(model, sc)
    kernel = _kernel(shapes, model.controller, options)
    grad_read_only = int(not (gv.flags.writeable and ge.flags.writeable))  # the simulator's alone
    if options.draws != "rows":  # copied in launch order (thread g reads its run's draws at g)
        sc, gv, ge = sc[order], gv[order], ge[order]
        if options.draws == "columns":
            sc, gv, ge = (np.ascontiguousarray(a.T) for a in (sc, gv, ge))
    keys = np.array([seed_key(seed_u64(seed), int(k)) for k in STREAMS], dtype=np.uint64)
    p = stop_params(model, bp)
    d_p = type(p)(*(cuda.to_device(np.ascontiguousarray(a)) for a in p))
    rec_arrays = tuple(
        cuda.to_device(np.zeros(shape))
        for shape in ((1, TR_SIZE), (1, CR_SIZE + 1), (1, TEL_SIZE), (1, LA_SIZE), (1,))
    )
    d_res = cuda.device_array((n, RES_SIZE))
    d_pass = cuda.device_array((n, model.det_pos.size))
    args = (
        seed_u64(seed),
        cuda.to_device(keys),
        first_run,
        cuda.to_device(np.ascontiguousarray(order, dtype=np.int64)),
        d_p,
        cuda.to_device(sc),
        cuda.to_device(np.ascontiguousarray(gv)),
        cuda.to_device(np.ascontiguousarray(ge)),
        d_res,
        d_pass,
        rec_arrays,
        cuda.to_device(np.zeros(RC_SIZE, dtype=np.int64)),
        grad_read_only,
    )
    compiled = bool(kernel.overloads) or cuda_simulated()
    if not compiled:
        kernel.compile(tuple(numba.typeof(a) for a in args))
    cuda.synchronize()
    t1 = clock()
    blocks = (n + threads_per_block - 1) // threads_per_block
    with warnings.catch_warnings():
        # A small block of runs fills few of the GPU's multiprocessors: slower, not wrong.
        warnings.simplefilter("ignore", NumbaPerformanceWarning)
        kernel[blocks, threads_per_block](*args)
    cuda.synchronize()
    t2 = clock()
    d_res.copy_to_host(res)
    d_pass.copy_to_host(passages)
    t3 = clock()
    if timings is not None:
        timings["compile_and_to_device"] = t1 - t0
        timings["kernel"] = t2 - t1
        timings["to_host"] = t3 - t2


#: Where the stop model runs: the CPU (numba, threads or processes) or an NVIDIA GPU (numba-cuda).
DEVICES = ("cpu", "gpu")


def run_on(
    device: str,
    model: KernelModel,
    scenario: Scenario,
    *,
    seed: int,
    first_run: int,
    record: bool = False,
) -> tuple[FloatArray, FloatArray, KernelRecord | None]:
    """:func:`railstop.model.run.run_kernel` on ``device`` (the detailed stop, ``record``, runs on
    the CPU only): (results (n, RES_SIZE), true passage times (n, D), record of run 0)."""
    if device == "cpu":
        return run_kernel(model, scenario, seed=seed, first_run=first_run, record=record)
    if device != "gpu":
        raise SimulationError(f"device {device!r}: one of {', '.join(DEVICES)}")
    if record:
        raise SimulationError("the detailed stop (its recording) runs on the CPU")
    res, passages = run_kernel_gpu(model, scenario, seed=seed, first_run=first_run)
    return res, passages, None
