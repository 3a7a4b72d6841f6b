"""The run loop of the station stop: ``simulate_run``, ``simulate_block``, and ``run_kernel`` for Python.

``simulate_block`` simulates runs one after another, each from the start of
the approach to standstill (no lockstep: a run ends at its own stop), every
10 ms (the Doppler sample period of SPEC §1): ``simulate_run`` is
``stop_init``, then ``stop_step`` until the train stands, then
``stop_finish`` (:mod:`railstop.model.step`). The detailed stop is one run
with recording on; a campaign runs blocks of runs on threads (the loop holds
no GIL) or processes (DESIGN rule 1: one model for every stop).

Splitting the old kernel (one 559-line function of 69 positional arrays)
into these records and steps changed no result bit (every controller,
station, signal form and disturbance set, recorded runs included). Thread
CPU time per run before -> after (1000 runs of the standard set at
Riverside, best of 2 x 3, on 2 cores under a load of 9): tasc-pwm 275 -> 269
µs, tasc-step 497 -> 479, ato 246 -> 232, ato-corrected 379 -> 352,
driver-ats 164 -> 166, driver-unaided 143 -> 149 (a driver's step is short,
so the state's round trip through memory shows: +1 to +4 %), the ten
controllers together 2658 -> 2585 µs. Why records, and how they are compiled:
:mod:`railstop.model.records`.

The run's work arrays of constant shape live on ``simulate_run``'s stack
(``state_on_stack``; issue 37 item 1), where LLVM knows they overlap no other
array and keeps what it can of them in registers. Measured on this project's
machine (thread CPU time of a block of runs, the best of 15 in one process,
the two builds alternated, the lowest of each build's trials): tasc-pwm
0.440 -> 0.416 s per 1,000 runs (three trials each), tasc-step 0.386 ->
0.366 s per 600 runs, ato 0.205 -> 0.193, driver-atc2 0.400 -> 0.368 (two
trials each): about 5 % (8 % for the driver), every result the same to the
bit (ten controllers, 1,500 runs each, against the rows of the build before).
Most of the step's state is still read and written in memory: the units the
step calls out of line (the wayside's command, the receiver's plan, the
modulator) take their arrays by pointer, which keeps those arrays out of
registers.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numba.core import types
from numba.extending import intrinsic, overload
from numpy.typing import NDArray

from railstop.config import default_line, default_vehicle
from railstop.config.scenario import Scenario
from railstop.controllers import is_corrected
from railstop.errors import SimulationError
from railstop.jit import as_python, cache_dir, njit, njit_inline, njit_step, stack_array_value
from railstop.messages import TEL_SIZE
from railstop.model.build import DRIVER_MODES, KernelModel, compiled_law, scenario_arrays, stop_params
from railstop.model.records import (
    FP_DRIVER_FIXES,
    KP_DT,
    KP_IN_FLIGHT,
    KP_STEPS,
    KP_STOP,
    LA_SIZE,
    RC_ATTEMPTS,
    RC_COMMANDS,
    RC_DELIVERIES,
    RC_SIZE,
    RC_STEPS,
    RES_SIZE,
    RUN_DTYPE,
    SC_DEAD_TIME,
    SC_ENTRY_SPEED,
    STATE_FIELDS,
    STREAMS,
    TR_SIZE,
    FloatArray,
    Recording,
    RunParams,
    StopOutputs,
    StopParams,
    StopState,
    UintArray,
    constant_shape,
    new_record,
    new_state,
    state_array,
)
from railstop.model.step import stop_finish, stop_init, stop_step
from railstop.onboard.ato import ato_fix_1
from railstop.stream_cores import seed_key
from railstop.streams import seed_u64
from railstop.wayside.tasc_unit import CR_SIZE


@intrinsic
def _state_on_stack(typingctx: Any, state: Any) -> Any:
    """``state_on_stack(s)`` in compiled code: the state ``s`` with every work array of constant
    shape (:data:`~railstop.model.records.STATE_FIELDS`: the records, the units' slots, the
    histories) replaced by one on the calling function's stack, set to its initial value as
    ``new_state`` sets it; the arrays sized by the model (the dead time's ring, the radar buffer,
    ...) stay those of ``s``. The CPU's run loop works on it (see :func:`simulate_run`)."""
    if not (isinstance(state, types.NamedTuple) and state.instance_class is StopState):
        return None
    field_types = state.types

    def codegen(context: Any, builder: Any, sig: Any, args: Any) -> Any:
        values = []
        for i, (_, shape, _, fill) in enumerate(STATE_FIELDS):
            dims = constant_shape(shape)
            if dims is not None:
                values.append(stack_array_value(context, builder, field_types[i], dims, fill))
            else:
                values.append(builder.extract_value(args[0], i))
        return context.make_tuple(builder, state, values)

    return state(state), codegen


def _state_on_stack_py(state: StopState) -> StopState:
    """What :func:`_state_on_stack` does, for the model run as Python (``NUMBA_DISABLE_JIT=1``,
    where an intrinsic cannot run): fresh arrays of constant shape set as ``new_state`` sets
    them, the model-sized ones kept."""
    fresh: list[Any] = []
    for value, (_, shape, dtype, fill) in zip(state, STATE_FIELDS, strict=True):
        dims = constant_shape(shape)
        fresh.append(value if dims is None else state_array(dims, dtype, fill))
    return StopState(*fresh)


state_on_stack = _state_on_stack_py if as_python() else _state_on_stack


def new_run_record() -> NDArray[np.void]:
    """A run's derived record (``RUN_DTYPE``), zeroed: a record array when run as Python."""
    return new_record(RUN_DTYPE)


@overload(new_run_record)
def _new_run_record_compiled() -> Any:
    def impl() -> NDArray[np.void]:
        return np.zeros(1, dtype=RUN_DTYPE)

    return impl


@njit_inline
def run_steps(
    p: StopParams,
    run: RunParams,
    s: StopState,
    out: StopOutputs,
    seed_keys: UintArray,
    run_index: int,
    law: Any,
) -> None:
    """Run ``run_index`` from the start of its approach to its stop (or the time limit) on the
    state ``s`` (the device's kernel calls this with its thread's local arrays)."""
    stop_init(p, run, s, out, seed_keys, run_index)
    k = 0
    for k in range(int(p.kp[KP_STEPS])):
        if stop_step(p, run, s, out, k, law):
            break
    stop_finish(p, run, s, out, k + 1)


@njit_step
def simulate_run(
    p: StopParams,
    run: RunParams,
    s: StopState,
    out: StopOutputs,
    seed_keys: UintArray,
    run_index: int,
    law: Any,
) -> None:
    """Run ``run_index`` from the start of its approach to its stop (or the time limit).

    The work arrays of constant shape live on this function's stack for the run
    (:func:`state_on_stack`): LLVM may then keep the state's scalars in registers from step to
    step instead of storing and reloading them around every store into another array. The
    arrays the model sizes are ``s``'s; ``s``'s other arrays are left as they were."""
    run_steps(p, run, state_on_stack(s), out, seed_keys, run_index, law)  # type: ignore[call-arg]


@njit
def simulate_block(
    seed: np.uint64,
    first_run: int,
    p: StopParams,
    sc: FloatArray,
    gv: FloatArray,
    ge: FloatArray,
    s: StopState,
    res: FloatArray,
    passages: FloatArray,
    rec: Recording,
    law: Any,
) -> None:
    """Simulate runs ``first_run .. first_run + n - 1`` (rows of the draws ``sc`` and of the
    gradients ``gv``, ``ge``), one after another through the state ``s``; run 0 is recorded when
    ``rec.on``. ``law``: the onboard stop-control law (``model.build.compiled_law``)."""
    seed_keys = np.empty(STREAMS.size, dtype=np.uint64)
    for i in range(STREAMS.size):
        seed_keys[i] = seed_key(seed, STREAMS[i])
    derived = new_run_record()
    for r in range(sc.shape[0]):
        run = RunParams(sc[r], (p.bp, gv[r], ge[r]), derived)
        rec_r = Recording(
            rec.on and r == 0, rec.trace, rec.commands, rec.sends, rec.attempts, rec.deliveries, rec.counters
        )
        simulate_run(p, run, s, StopOutputs(res[r], passages[r], rec_r), seed_keys, first_run + r, law)


# --------------------------------------------------------------------------
# The Python side: the records' arrays in, the results out.


@dataclass(frozen=True, slots=True, kw_only=True)
class KernelRecord:
    """What the kernel recorded of run 0 (the detailed stop)."""

    trace: FloatArray  # (steps, TR_SIZE)
    commands: FloatArray  # (k, CR_SIZE + 1): command records and the step they were sent in
    sends: FloatArray  # (k, TEL_SIZE): the telegrams as quantised for the air
    attempts: FloatArray  # (m, LA_SIZE)
    deliveries: NDArray[np.int64]  # steps at which the pending telegram was delivered


def state_sizes(model: KernelModel, ring_size: int) -> dict[str, int]:
    """The sizes of the state's arrays (records.STATE_SIZES) for ``model``, its dead time's ring
    ``ring_size`` steps long."""
    return {
        "ring": ring_size,
        "window": model.window,
        "tach_window": model.tach_window,
        "in_flight": max(int(model.kp[KP_IN_FLIGHT]), 1),  # at least one slot
        "log_len": model.log_len,
        "circuits": model.tc_starts.size,
    }


def block_state(model: KernelModel, ring_size: int) -> StopState:
    """The state buffers of a block of runs of ``model`` (``ring_size``: the longest dead time in steps)."""
    return new_state(state_sizes(model, ring_size))


def ring_steps(model: KernelModel, sc: FloatArray) -> int:
    """The dead time's ring the draws ``sc`` need: their longest dead time in steps, plus one."""
    return int(np.rint(np.max(sc[:, SC_DEAD_TIME]) / model.kp[KP_DT])) + 1 if sc.shape[0] else 1


def model_draws(
    model: KernelModel, scenario: Scenario
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """``scenario`` as the model's arrays (``scenario_arrays``), refused where ``model`` cannot
    run it: ``ato-corrected`` needs the approach to start on the line's track circuits."""
    sc, bp, gv, ge = scenario_arrays(scenario)
    if is_corrected(model.controller) and scenario.n:
        # The train was corrected at the last circuit boundary behind its start (SPEC §2).
        start = model.det_pos[0] - np.maximum(20.0, 1.5 * sc[:, SC_ENTRY_SPEED])
        if np.any(start < model.tc_starts[0]):
            raise SimulationError("ato-corrected: the approach starts before the first track circuit")
    return sc, bp, gv, ge


@dataclass(frozen=True, slots=True)
class _Buffers:
    """What a call of the model works on: the draws as arrays, the records, the outputs."""

    sc: FloatArray
    bp: FloatArray
    gv: FloatArray
    ge: FloatArray
    rec: Recording
    res: FloatArray
    passages: FloatArray
    state: StopState


def _buffers(model: KernelModel, scenario: Scenario, record: bool) -> _Buffers:
    sc, bp, gv, ge = model_draws(model, scenario)
    n = scenario.n
    rows = int(model.kp[KP_STEPS]) if record else 1
    if record and model.controller in DRIVER_MODES:
        rows *= 2  # room for the re-stops after the first standstill
    rec = Recording(
        on=record,
        trace=np.full((rows, TR_SIZE), np.nan),
        commands=np.zeros((rows, CR_SIZE + 1)),
        sends=np.zeros((rows, TEL_SIZE)),
        attempts=np.zeros((rows, LA_SIZE)),
        deliveries=np.zeros(rows),
        counters=np.zeros(RC_SIZE, dtype=np.int64),
    )
    return _Buffers(
        sc=sc,
        bp=bp,
        gv=gv,
        ge=ge,
        rec=rec,
        res=np.empty((n, RES_SIZE)),
        passages=np.empty((n, model.det_pos.size)),
        state=block_state(model, ring_steps(model, sc)),
    )


def _record(rec: Recording) -> KernelRecord:
    counters = rec.counters
    return KernelRecord(
        trace=rec.trace[: counters[RC_STEPS]],
        commands=rec.commands[: counters[RC_COMMANDS]],
        sends=rec.sends[: counters[RC_COMMANDS]],
        attempts=rec.attempts[: counters[RC_ATTEMPTS]],
        deliveries=rec.deliveries[: counters[RC_DELIVERIES]].astype(np.int64),
    )


def run_kernel(
    model: KernelModel,
    scenario: Scenario,
    *,
    seed: int,
    first_run: int,
    record: bool = False,
) -> tuple[FloatArray, FloatArray, KernelRecord | None]:
    """Simulate ``scenario.n`` runs: (results (n, RES_SIZE), true passage times (n, D), record of run 0)."""
    b = _buffers(model, scenario, record)
    p = stop_params(model, b.bp)
    law = compiled_law(model)
    simulate_block(seed_u64(seed), first_run, p, b.sc, b.gv, b.ge, b.state, b.res, b.passages, b.rec, law)
    return b.res, b.passages, _record(b.rec) if record else None


@njit_step
def stop_steps(
    p: StopParams, run: RunParams, s: StopState, out: StopOutputs, k: int, n: int, law: Any
) -> tuple[int, bool, bool]:
    """Steps ``k`` .. ``k + n - 1`` of a run (fewer when the train comes to a stand or the run's
    time is up), for a driver that steps the stop on its own clock: (the steps done so far, whether
    the run is at its end, whether the wheels slid in a step while the train still moved)."""
    steps = int(p.kp[KP_STEPS])
    end = min(k + n, steps)
    slid = False
    while k < end:
        stands = stop_step(p, run, s, out, k, law)
        k += 1
        tr = s.train[0]
        slid = slid or (tr.sliding and not tr.stopped)
        if stands:
            return k, True, slid
    return k, k >= steps, slid


def _type_key(fn: Any, a: Any) -> Any:
    """What numba's ``typeof`` reads of the argument ``a`` of ``fn`` to type it (numba 0.68's
    ``numba.core.typing.typeof``), in a form much cheaper to make and to compare than the type:
    equal keys, equal numba types.

    An array's type is its dtype as numba's (``from_dtype``: a record's fields, offsets, size and
    alignment), its dimensions, its layout (C, F or neither by its flags) and whether it is
    read-only; a tuple's the types of its items and its class (a named tuple's too); an int's its
    bit length (intp, int64 or uint64); a bool is a boolean. Anything else (the control law, a C
    callback) is keyed by the numba type itself.
    """
    t = type(a)
    if t is np.ndarray:
        d = a.dtype
        f = a.flags
        return (t, d, d.isalignedstruct, a.ndim, f.c_contiguous, f.f_contiguous, f.writeable)
    if isinstance(a, tuple):
        return (t, *[_type_key(fn, e) for e in a])
    if t is int:  # numba's classes of an int (intp, int64, uint64); beyond them, the value
        n = a.bit_length()
        return (t, "intp" if n < 32 else "int64" if n < 64 else "uint64" if n == 64 and a >= 0 else a)
    if t is bool:
        return t
    return fn.typeof_pyval(a)


#: The entry points :func:`compiled_for` found: (the dispatcher, :func:`_type_key` of the
#: arguments) -> the entry point of the overload numba chose for their types.
_ENTRY_POINTS: dict[tuple[Any, Any], Any] = {}


def compiled_for(fn: Any, args: tuple[Any, ...]) -> Any:
    """The compiled entry point of ``fn`` for the types of ``args`` (compiled, or loaded from the
    cache, if need be), to call again and again with arguments of those types.

    Why: numba's dispatcher works out the types of a call's arguments every call, and for the stop's
    records (tuples of some 80 arrays) that costs more than the steps a line tick runs. Measured on
    this project's machine: 32 us a call through the dispatcher, 4.8 us through the entry point.

    Working out the types once (and looking their tuple up among ``fn``'s overloads) still costs
    about 1.7 ms, at every station stop of a line; so the entry point is kept, keyed by
    :func:`_type_key` of the arguments, which decides their numba types: arguments of the same
    types (every stop of the same model) find it again for about 0.06 ms, and arguments of other
    types (another dtype, layout, law) make another key and are typed afresh.
    """
    try:
        key = (fn, _type_key(fn, args))
        found = _ENTRY_POINTS.get(key)
        if found is not None:
            return found
        sig = tuple(fn.typeof_pyval(a) for a in args)
        overloads = fn.overloads
    except AttributeError:
        # Not a numba dispatcher as this numba version shapes them (``typeof_pyval``,
        # ``overloads``, ``entry_point`` are its, not a documented API): the function itself,
        # through its own dispatch (slower, the same results).
        return fn
    if sig not in overloads:
        fn.compile(sig)
    entry = overloads[sig].entry_point
    _ENTRY_POINTS[key] = entry
    return entry


class StopRecords:
    """One run's records (:mod:`railstop.model.records`), started by ``stop_init``: what a driver
    that steps the stop itself holds (``p``, ``run``, ``state``, ``out``, ``law``)."""

    def __init__(
        self, model: KernelModel, scenario: Scenario, *, seed: int, run: int, record: bool = False
    ) -> None:
        if scenario.n != 1:
            raise SimulationError(f"a stepped run is one run ({scenario.n} drawn)")
        b = _buffers(model, scenario, record)
        self.buffers = b
        self.p = stop_params(model, b.bp)
        self.law = compiled_law(model)
        # Writable copies of the gradient's rows (a draw may broadcast one read-only profile): a
        # read-only array is another type to numba, and each type another compilation of the step.
        grad = (b.bp, np.array(b.gv[0], dtype=np.float64), np.array(b.ge[0], dtype=np.float64))
        self.run = RunParams(b.sc[0], grad, new_record(RUN_DTYPE))
        self.state = b.state
        self.out = StopOutputs(b.res[0], b.passages[0], b.rec)
        self.dt_s = float(model.kp[KP_DT])
        seed_keys = np.array([seed_key(seed_u64(seed), int(k)) for k in STREAMS], dtype=np.uint64)
        stop_init(self.p, self.run, self.state, self.out, seed_keys, run)

    @property
    def train(self) -> Any:
        """The train's state record (``TRAIN_DTYPE``; a view: fields read and written by name)."""
        return self.state.train[0]

    @property
    def entry_speed_mps(self) -> float:
        """The run's speed at the start of its approach (its draw's)."""
        return float(self.buffers.sc[0, SC_ENTRY_SPEED])

    @property
    def tach_scale(self) -> float:
        """The run's odometer: metres counted per metre rolled (D_assumed / D_actual, SPEC §2)."""
        return float(self.run.derived[0]["tach_scale"])

    @property
    def driver_fixes(self) -> bool:
        """Whether the run's driver positions the train (``KernelModel.with_driver_fixes``): it takes
        the driver's fixes and runs no chain of its own."""
        return bool(self.p.fp[FP_DRIVER_FIXES] != 0.0)

    def fix(self, position_m: float) -> None:
        """A position fix from the driver's SPEC §2 chain (the line's positioning unit): the
        ``ato-corrected`` train's ATO now believes its front at ``position_m`` (its distance to
        go, a new reference for its law), as a fix of the run's own chain does (``ato_fix_1``).
        Only for a model whose driver positions the train (``KernelModel.with_driver_fixes``)."""
        if not self.driver_fixes:
            raise SimulationError("fix: this stop runs its own position chain (or takes no fixes)")
        if not math.isfinite(position_m):
            raise SimulationError(f"fix: position_m = {position_m} is not a position")
        ato_fix_1(self.state.at, float(self.p.kp[KP_STOP]) - position_m)

    def emergency_brake(self, t_s: float) -> None:
        """Apply the emergency brake from outside the stop's units (a CBTC onboard unit) from the
        step at ``t_s`` (the run's clock) on, to the stand; the result's cause is ``EbCause.CBTC``
        unless a unit of the stop braked too."""
        ob = self.state.onboard[0]
        if not math.isfinite(ob["external_eb_t_s"]):
            ob["external_eb_t_s"] = t_s


class SteppedStop:
    """One run of the station stop, driven by a caller's clock (DESIGN rule 1: the line steps the
    stop model itself, a few steps per tick of its clock, rather than replaying a trajectory).

    ``stop_init`` on creation; :meth:`advance` runs ``stop_step`` through :func:`stop_steps`;
    :meth:`finish` runs ``stop_finish`` once the run is at its end. Whatever the chunks, the steps
    are the campaign's own: the results equal :func:`run_kernel`'s for the same draw, bit for bit.
    Between the calls the train is where :attr:`position_m` and :attr:`speed_mps` say.
    """

    def __init__(
        self, model: KernelModel, scenario: Scenario, *, seed: int, run: int, record: bool = False
    ) -> None:
        r = StopRecords(model, scenario, seed=seed, run=run, record=record)
        self.records = r
        self.run = run
        self.dt_s = r.dt_s
        self.steps = 0  # steps done: the run's time is steps * dt_s
        self.done = False  # the train stands at its end, or the run's time is up
        self._finished = False
        self._steps_fn = compiled_for(stop_steps, (r.p, r.run, r.state, r.out, 0, 0, r.law))
        # A stop its driver positions (``KernelModel.with_driver_fixes``): the fixes given, as
        # (the steps done when given, the position), in order; it may not step before the first.
        self.driver_fixes = r.driver_fixes
        self.fixes: list[tuple[int, float]] = []

    @property
    def entry_speed_mps(self) -> float:
        """The run's speed at the start of its approach (its draw's)."""
        return self.records.entry_speed_mps

    @property
    def elapsed_s(self) -> float:
        """The run's time after the steps done (the stand's step once it stands)."""
        return self.steps * self.dt_s

    @property
    def position_m(self) -> float:
        """The train's front (chainage) after the steps done."""
        return float(self.records.train["position_m"])

    @property
    def speed_mps(self) -> float:
        """The train's speed after the steps done."""
        return float(self.records.train["speed_mps"])

    def advance(self, n: int) -> bool:
        """Up to ``n`` more steps (none once at the end); True if the wheels slid in one of them
        while the train still moved."""
        if self.done or n <= 0:
            return False
        if self.driver_fixes and not self.fixes:
            # Never a step without a position: its ATO would not brake (the most restrictive
            # thing is to refuse to run it; the line gives the first fix at the hand-over).
            raise SimulationError("a stop its driver positions needs a fix before its first step")
        r = self.records
        self.steps, self.done, slid = self._steps_fn(r.p, r.run, r.state, r.out, self.steps, n, r.law)
        return bool(slid)

    def fix(self, position_m: float) -> None:
        """A fix of the driver's SPEC §2 chain (:meth:`StopRecords.fix`), acting from the next step."""
        self.records.fix(position_m)
        self.fixes.append((self.steps, position_m))

    def emergency_brake(self) -> None:
        """Apply the emergency brake from outside the stop's units (the line's CBTC onboard unit)
        from the next step on, to the stand (:meth:`StopRecords.emergency_brake`)."""
        self.records.emergency_brake(self.elapsed_s)

    def finish(self) -> tuple[FloatArray, FloatArray, KernelRecord | None]:
        """``stop_finish`` (a driver's corrections at the stand included): (results (1, RES_SIZE),
        true passage times (1, D), the recording if asked for)."""
        if not self.done:
            raise SimulationError("the stepped run is not at its end")
        r = self.records
        b = r.buffers
        if not self._finished:
            stop_finish(r.p, r.run, r.state, r.out, self.steps)
            self._finished = True
        return b.res, b.passages, _record(b.rec) if b.rec.on else None


def run_stepped(
    model: KernelModel,
    scenario: Scenario,
    *,
    seed: int,
    run: int,
    record: bool = False,
    fixes: Sequence[tuple[int, float]] = (),
) -> tuple[FloatArray, FloatArray, KernelRecord | None]:
    """Run ``run`` (``scenario`` holds its draw alone) driven from Python one step at a time, as a
    driver on a clock of its own may drive it (DESIGN rule 2). The same results as
    :func:`run_kernel`, bit for bit.

    ``fixes``: for a model whose driver positions the train (``KernelModel.with_driver_fixes``),
    the driver's fixes as :attr:`SteppedStop.fixes` lists them, (steps done, position): each is
    given once that many steps are done (a line's stop again, from its fixes alone)."""
    stop = SteppedStop(model, scenario, seed=seed, run=run, record=record)
    pending = list(fixes)
    while not stop.done:
        while pending and pending[0][0] <= stop.steps:
            stop.fix(pending.pop(0)[1])
        stop.advance(1)
    return stop.finish()


def warm_up() -> dict[str, object]:
    """Compile the kernel (or load it from the on-disk cache) by running one short stop without and
    with recording (one compiled signature serves every controller, form and station), and once
    driven from Python step by step (``run_stepped``).

    Returns what happened: whether anything was compiled, and the cache folder.
    """
    line, vehicle = default_line(), default_vehicle()
    station = line.stations[0]
    scenario = Scenario.nominal(station, vehicle)
    stats: Any = simulate_block.stats  # type: ignore[attr-defined]
    misses_before = sum(stats.cache_misses.values())
    model = KernelModel.create(
        station=station, vehicle=vehicle, controller="tasc-pwm", form=None, dt_s=0.01, max_time_s=150.0
    )
    for record in (False, True):
        run_kernel(model, scenario, seed=0, first_run=0, record=record)
    # The steps as a driver outside the compiled loop calls them (compiled for that call apart).
    run_stepped(model, scenario, seed=0, run=0, record=True)
    compiled = sum(stats.cache_misses.values()) > misses_before
    return {"compiled": compiled, "cache_dir": str(cache_dir())}
