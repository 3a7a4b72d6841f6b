"""The Monte Carlo campaign driver: many stops of one controller at one station (DESIGN rule 1).

A campaign is cut into chunks of runs; each chunk draws its scenario from the
disturbance set with the counter-based streams of its runs and goes through
``run_batch`` (the same code as the single stop). A chunk's per-run rows are
written to ``DIR/chunks/chunk-NNNNNN.parquet`` atomically (temporary file,
then rename) as soon as it is done, so an interrupted campaign (Ctrl-C, a
kill) loses no finished chunk and ``resume`` runs only the missing ones.
Because every random number is a function of (seed, run, stream, counter),
the results do not depend on the chunk size or on the number of workers.

Layout of ``DIR``:
    campaign.json     the manifest (what was asked; checked on resume)
    chunks/           one Parquet file per finished chunk; its metadata names the
                      campaign (the hash of the manifest) and the runs it holds,
                      and ``--resume`` checks both before trusting it
    runs.parquet      every run, in run order (written when all chunks are done)
    summary.json      the summary statistics
    .lock             held (``flock``) by the one process running the campaign

A chunk is simulated in blocks of at most ``BLOCK_RUNS`` runs (for progress
and load balance); blocks are never held beyond their chunk, and nothing is
built per chunk up front, so the bookkeeping stays small however many runs
are asked. What the disk and memory cannot hold is refused before any run
(:func:`check_capacity`).
"""

from __future__ import annotations

import contextlib
import functools
import json
import os
import shutil
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from railstop.config.disturbances import PARAMETERS, DisturbanceSet, draw_scenario
from railstop.config.driver import DriverFile
from railstop.config.platform import PlatformFile, stop_tolerance
from railstop.config.schema import Line, Station, Track, Vehicle
from railstop.control.law import LawFile
from railstop.controllers import known_controllers
from railstop.errors import RailstopError
from railstop.model.gpu import DEVICES, gpu_unavailable
from railstop.provenance import inputs_sha256, manifest_sha256, overrides_sha256, stamp
from railstop.quantities import KMH_PER_MPS
from railstop.sim.engine import BatchResult, run_batch
from railstop.sim.executor import ItemFailedError, blocks, describe, execute
from railstop.stats.summary import RESULT_COLUMNS, summary_stats
from railstop.streams import RUN_LIMIT, SEED_RANGE, RunStreams, seed_in_range
from railstop.wayside.tasc_unit import SignalForm

try:  # POSIX only: elsewhere campaign_lock takes no lock
    import fcntl
except ImportError:  # pragma: no cover - not POSIX
    fcntl = None  # type: ignore[assignment]

MANIFEST = "campaign.json"
RUNS_FILE = "runs.parquet"
SUMMARY_FILE = "summary.json"
CHUNK_DIR = "chunks"
LOCK_FILE = ".lock"
DEFAULT_CHUNK = 10_000
# Runs per block handed to a worker: small enough for a progress step of well under a second,
# large enough that the per-call cost does not show (1,000-run blocks run as fast as 10,000).
BLOCK_RUNS = 1_000
# 2: chunks carry the campaign's identity and run range in their Parquet metadata.
MANIFEST_VERSION = 2
# Bytes per run of the summary's working set: eight result columns (50 B) plus the
# temporaries of the masks, the absolute errors and the percentile's partition copies.
SUMMARY_BYTES_PER_RUN = 150
# Bytes per value on disk, uncompressed: the chunks and runs.parquet each hold every column.
DISK_BYTES_PER_VALUE = 8
# The stop model's version: a campaign is resumed (and a run replayed) only by the model that
# made it. 2: the compiled kernel, each run ending at its own stop (the lockstep array engine,
# version 1, went on stepping stopped runs, so in continuous update its command counts
# depended on the other runs of the chunk). 3: the Doppler noise drawn by the ziggurat
# (stream_cores.key_normal_zig) instead of Box–Muller: same distribution, other numbers.
# 4: the supervision (emergency brake, overrun guards) and the cyclic repeat of the latest
# braking telegram (more link draws per run).
# 5: the onboard ATO's law (bve-autopilot's pattern rejoin), the train's own brake command
# around TASC, config 2's switching unit and its PWM variant.
# 6: signal forms 1-5 carry para 92's combinations (longer frames) and the onboard planner
# calibrates its tachometer and fits its deceleration over the interval between commands;
# forms 7 and 8 are modulated by the wayside; the wayside models the train's own initial brake
# step. Form 6 runs without an initial brake step are unchanged.
# 7: the wayside identifies the brake response (dead time, lag) from its radar after the first
# braking command and plans with it (control.brake_ident); two result columns for it.
# 8: the human driver controllers of SPEC §3 (four result columns: first stop error, re-stops,
# lamp, driver level); the other controllers' numbers are unchanged.
# 9: SPEC §3 as written: the approach limit 60 km/h (entry capped), ATC option 2's code 25 before
# the home signal, the driver takes power when too slow and drives a long correction at the
# code, the signal-open switch; a driver's stop judged by the platform's PSD tolerance (SPEC §3
# ±500 mm). The train's own initial brake step is released at TASC's hand-over (config 3 with
# tasc.initial_brake_notch > 0); degraded mode after a lost link (a train that had a command
# finishes its stop on its odometry). Runs with neither are unchanged.
# 10: the notch modulator models the brakes as the plant has them, a dead time then a lag
# (control.notch; it was one lag of dead time + lag), and a new target starts its integrators
# from the braking commanded and not yet felt: every run of tasc-brake-controller, tasc-step,
# ato, ato-corrected and of forms 7 and 8 changes; the PWM controllers' forms 1-6 and the
# drivers are unchanged (tasc-pwm, 10,000 standard runs: the same summary to the bit).
# 11: the speed now from a ring of speed samples (the wayside's Doppler, the onboard unit's
# tachometer: control.tasc.fit_ring_1) is the mean of the short window carried forward with the
# long window's slope, no longer a line fitted through the short window alone (a quarter of its
# variance): every run of a controller that measures with the Doppler changes. Form 8's modulator
# moves one notch per hold along the ramp its plan assumed (control.notch, ramp_mps3).
# 12: the onboard unit knows when the wheel-slide protection acts (the plant's sensing carries
# it, as it carries the tachometer): it calibrates its tachometer (forms 1-3, 5) and its odometer
# between transponders (degraded mode) and updates the forms 1-5 loop gain only over stretches
# in which the wheels did not slide. Runs without a slide are unchanged.
# 13: the braking telegrams' medium has bursts (Gilbert-Elliott) and reordering, drawn as
# link.channel.SimChannel draws them (radio_burst_*_probability, radio_reorder_probability;
# the run's LINK_FAULTS stream). A set that names neither draws nothing new: its runs are unchanged.
# 14: a form-8 telegram carries its step's number; a train that sees one skipped (a step whose
# every transmission was lost) finishes the stop in degraded mode instead of braking a notch off
# the wayside's belief. Every form-8 run changes (its frame is a byte longer); the others do not.
# 15: without a Doppler radar (SPEC §1 variant 2) the wayside takes the speed at a passage from
# the last three passages with the deceleration its model misses (wayside.tasc_unit.
# _passages_fit_1), and its loop gain from the newest window alone. Runs with a radar are
# unchanged.
# 16: forms 1-3 calibrate the tachometer on the odometer's count, as forms 4 and 5 do, not on the
# tachometer's speed summed per step (one odometer distance in the onboard unit). Every run of
# forms 1-3 changes; the others do not.
# 17: a train not yet told to brake holds its speed to the next detector while the stop needs
# less than a fifth of full service and the next detector would need no more than half of it
# (control.tasc.START_FLOOR; not for forms 1-5 without a Doppler radar), form 8 sends its first
# telegram even when it changes no notch, and degraded mode after a hold ends it when its own
# plan brakes. The TASC runs whose first command was that small change (slow entries, uphill
# approaches); the others, the ATO and the drivers do not.
# 18: the overrun guards' limit is what this train's emergency brake keeps on the path left
# (control.supervision.guard_limit_1): the nominal emergency deceleration times the loop gain
# measured so far (at most 1), plus the steepest gradient and least resistance ahead. Runs whose
# guard would have fired later change; the ATO and the drivers do not.
# 19: the wayside identifies the brake response with form 7 too (it did with form 6 only), and
# its notch modulator times the notches by the identified dead time and lag. Form-7 runs change.
# 20: form 8: the notch modulator's end phase may move to any notch one step from the current one
# (below the target's lower notch too), not only to the two either side of the target, and with
# tasc-brake-controller the wayside allows half the brake controller's cycle more delay until a
# step acts. Form-8 runs change; the other forms do not.
# 21: arithmetic only (issue 37, the kernel's speed): the odometer's step is the distance times
# creep times the tachometer's scale (assumed / actual diameter) instead of revolutions of the
# actual wheel times the assumed one, and the brakes' deceleration is the actuator's output
# times one per-run factor (gain x believed / effective mass) instead of the same product and
# quotient every step. Two divisions fewer per step; results move by rounding alone (at most
# 6.8e-12 m in 360,000 standard runs of every controller and form, no discrete outcome
# different: docs/architecture.md).
# 22: config 2 (tasc-step): the onboard unit's own modulator chooses its notch once per its cycle
# (the vehicle's tasc_cycle_s, 0.05 s) instead of every simulation step, and relays a notch the
# wayside sends (forms 7, 8) in the step it has it. tasc-step runs change; the others do not.
# 23: forms 7, 8 with a Doppler radar: the wayside's notch modulator plans its end phase against
# the stopping point as its radar measures the distance to it (the last detector's chainage less
# the travel since), with the loop gain and the gradient and resistance there, instead of
# against where the last command's target would stop the train (control.notch.modulator_aim_1).
# Those runs change; forms 1-6 and the detectors-only variant do not.
MODEL_VERSION = 23


@dataclass(frozen=True, slots=True, kw_only=True)
class CampaignSpec:
    """What a campaign is: everything that decides its numbers."""

    line: Line
    vehicle: Vehicle
    station: str
    controller: str
    runs: int
    seed: int
    disturbances: DisturbanceSet
    chunk_size: int = DEFAULT_CHUNK
    form: int | None = None
    # The PSD tolerance of the summary (None: the station's psd_tolerance_m). Not in the
    # manifest: it does not change a run, so a resume may summarise with another one.
    tolerance_m: float | None = None
    # The driver controllers' data given in place of the embedded files (None: embedded).
    driver: DriverFile | None = None
    platform: PlatformFile | None = None
    # The file of a stop-control law loaded by the user (railstop.control.law; None: built in).
    law: LawFile | None = None
    # Where the stop model runs (railstop.model.gpu DEVICES). In the manifest when not the CPU:
    # the GPU's numbers equal the CPU's within a bound, not always to the bit, so a campaign is
    # resumed on the device that began it.
    device: str = "cpu"

    def tolerance(self) -> float:
        """The PSD tolerance the runs are judged by: the one given, else a driver controller's
        platform's (SPEC §3, ``PlatformFile.psd_tolerance_m``), else the station's."""
        if self.tolerance_m is not None:
            return self.tolerance_m
        return stop_tolerance(self.line.station(self.station), self.controller, self.platform)

    def manifest(self) -> dict[str, Any]:
        st = self.line.station(self.station)
        out: dict[str, Any] = {
            "kind": "railstop-campaign",
            "version": MANIFEST_VERSION,
            "model_version": MODEL_VERSION,
            "station": st.name,
            "controller": self.controller,
            "seed": self.seed,
            "runs": self.runs,
            "chunk_size": self.chunk_size,
            "form": int(st.tasc.signal_form if self.form is None else self.form),
            "disturbances": {"name": self.disturbances.name, "set": self.disturbances.to_dict()},
            "line": self.line.line.name,
            "vehicle": self.vehicle.name,
            # Where the wayside sees the train (for the report's plots; also in the data hash).
            "detectors_before_stop_m": list(st.tasc.detectors_before_stop_m),
            # The data the numbers come from: a resume must use the same.
            "data_sha256": _data_hash(self.line, self.vehicle),
        }
        manual = overrides_sha256(self.driver, self.platform)
        if manual is not None:  # only then: a campaign on the embedded data keeps its identity
            out["manual_data_sha256"] = manual
        if self.law is not None:  # the same: a built-in controller's campaign keeps its identity
            out["law"] = self.law.manifest()
        if self.device != "cpu":  # the same: a CPU campaign keeps its identity
            out["device"] = self.device
        return out

    def identity(self) -> str:
        """The campaign's identity: the SHA-256 of its manifest (every chunk file carries it)."""
        return manifest_sha256(self.manifest())

    @property
    def chunks(self) -> int:
        return -(-self.runs // self.chunk_size)

    def chunk_range(self, k: int) -> tuple[int, int]:
        first = k * self.chunk_size
        return first, min(first + self.chunk_size, self.runs)


def _data_hash(line: Line, vehicle: Vehicle) -> str:
    return inputs_sha256(line.model_dump(mode="json"), vehicle.model_dump(mode="json"))


def simulate_runs(
    *,
    station: Station,
    vehicle: Vehicle,
    controller: str,
    disturbances: DisturbanceSet,
    seed: int,
    first_run: int,
    n: int,
    form: int | None = None,
    record: bool = False,
    track: Track | None = None,
    driver: DriverFile | None = None,
    platform: PlatformFile | None = None,
    incapacitated: bool = False,
    signal_open: bool = False,
    device: str = "cpu",
    patch: bool | None = None,
) -> tuple[BatchResult, dict[str, np.ndarray]]:
    """Runs ``first_run .. first_run + n - 1`` of a campaign: the drawn values and the batch result.

    ``driver``, ``platform``, ``incapacitated``, ``signal_open``: the driver controllers'
    (``run_batch``).

    ``track``: the line's track circuits (needed by ``ato-corrected``); ``device``: where the
    stop model runs (``cpu`` or ``gpu``, :mod:`railstop.model.gpu`); ``patch``: a low-adhesion
    patch forced on every run or on none (``draw_scenario``; a certification stratum).
    """
    streams = RunStreams.for_runs(seed, first_run, n)
    scenario, drawn = draw_scenario(disturbances, station, vehicle, streams, patch)
    result = run_batch(
        station=station,
        vehicle=vehicle,
        scenario=scenario,
        controller=controller,
        streams=streams,
        form=None if form is None else SignalForm(form),
        record=record,
        track=track,
        driver=driver,
        platform=platform,
        incapacitated=incapacitated,
        signal_open=signal_open,
        device=device,
    )
    return result, drawn


def _chunk_table(first_run: int, result: BatchResult, drawn: dict[str, np.ndarray]) -> pa.Table:
    n = result.stop_error_m.size
    cols: dict[str, Any] = {
        "run": np.arange(first_run, first_run + n, dtype=np.int64),
        "stop_error_m": result.stop_error_m,
        "stop_time_s": result.stop_time_s,
        "max_jerk_mps3": result.max_jerk_mps3,
        "notch_changes": result.notch_changes.astype(np.int64),
        "commands_sent": result.commands_sent.astype(np.int64),
        "commands_received": result.commands_received.astype(np.int64),
        "stopped": result.stopped,
        "slid": result.slid,
        # DESIGN rule 10: the cause code (control.supervision.EB_CAUSES; 0 none) and its time.
        "emergency_brake": result.emergency_brake.astype(np.int64),
        # Null where none was applied (a NaN would make equal tables compare unequal).
        "emergency_brake_s": pa.array(result.emergency_brake_s, mask=np.isnan(result.emergency_brake_s)),
        "brake_delay_identified_s": pa.array(
            result.brake_delay_identified_s, mask=np.isnan(result.brake_delay_identified_s)
        ),
        "brake_lag_identified_s": pa.array(
            result.brake_lag_identified_s, mask=np.isnan(result.brake_lag_identified_s)
        ),
        "detectors_filled": result.detectors_filled,
        # SPEC §3 manual driving (other controllers: the same error, no re-stop, no lamp, level -1).
        "first_stop_error_m": result.first_stop_error_m,
        "restops": result.restops.astype(np.int64),
        "lamp": result.lamp.astype(np.int64),
        "driver_level": result.driver_level.astype(np.int64),
    }
    for name, values in drawn.items():
        cols[name] = np.asarray(values)
    return pa.table(cols)


def _chunk_path(out: Path, k: int) -> Path:
    return out / CHUNK_DIR / f"chunk-{k:06d}.parquet"


def _chunk_index(name: str) -> int | None:
    """k of a file named as ``_chunk_path`` names chunk k; None for any other name."""
    if not (name.startswith("chunk-") and name.endswith(".parquet")):
        return None
    digits = name.removeprefix("chunk-").removesuffix(".parquet")
    return int(digits) if digits.isdigit() else None


def simulate_block(spec: CampaignSpec, block: tuple[int, int, int]) -> pa.Table:
    """The per-run rows of runs ``first .. end - 1`` of a chunk (``block`` = (chunk, first, end)): a
    pure function of the spec and the block, so any thread, process or machine may compute it."""
    _, first, end = block
    if spec.law is not None:
        spec.law.load()  # in a worker process: the law by its file (once per process)
    result, drawn = simulate_runs(
        station=spec.line.station(spec.station),
        vehicle=spec.vehicle,
        controller=spec.controller,
        disturbances=spec.disturbances,
        seed=spec.seed,
        first_run=first,
        n=end - first,
        form=spec.form,
        track=spec.line.track,
        driver=spec.driver,
        platform=spec.platform,
        device=spec.device,
    )
    return _chunk_table(first, result, drawn)


_META_CAMPAIGN = b"railstop.campaign"
_META_RUNS = b"railstop.runs"


def _write_chunk(spec: CampaignSpec, identity: str, out: Path, k: int, table: pa.Table) -> None:
    """Write chunk k atomically (temporary file, then rename): a chunk file is whole or absent.

    Its metadata says which campaign it belongs to and which runs it holds.
    """
    first, end = spec.chunk_range(k)
    table = table.replace_schema_metadata({_META_CAMPAIGN: identity.encode(), _META_RUNS: f"{first}-{end}"})
    path = _chunk_path(out, k)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    pq.write_table(table, tmp)
    os.replace(tmp, path)


def _verify_chunk(spec: CampaignSpec, identity: str, path: Path, k: int) -> None:
    """A finished chunk found on --resume must be this campaign's chunk k, whole; else refuse."""
    first, end = spec.chunk_range(k)
    try:
        meta = pq.read_metadata(path)
    except (OSError, pa.ArrowInvalid) as exc:
        raise _unreadable(path, exc) from None
    tags = meta.metadata or {}
    owner = tags.get(_META_CAMPAIGN, b"").decode(errors="replace")
    runs = tags.get(_META_RUNS, b"").decode(errors="replace")
    if owner != identity:
        what = f"campaign {owner[:12]}" if owner else "no campaign (written by an older railstop?)"
        raise RailstopError(
            f"{path}: this chunk belongs to {what}, not to the campaign in {path.parent.parent} "
            f"({identity[:12]}); move it away and --resume"
        )
    if runs != f"{first}-{end}" or meta.num_rows != end - first:
        raise RailstopError(
            f"{path}: holds runs {runs or '?'} ({meta.num_rows} rows) where chunk {k} holds runs "
            f"{first}-{end} ({end - first}); move it away and --resume"
        )


def _unreadable(path: Path, exc: Exception) -> RailstopError:
    return RailstopError(f"{path}: cannot read a finished chunk ({exc}); move it away and --resume")


@contextlib.contextmanager
def campaign_lock(out: Path) -> Iterator[None]:
    """Hold ``out/.lock`` for the duration: a second process on the same campaign is refused.

    ``flock`` is released by the kernel when the process ends however it ends,
    so a killed campaign never leaves a stale lock. The file keeps the holder's
    PID for the message; it is not deleted (that would race with a new holder).
    """
    out.mkdir(parents=True, exist_ok=True)
    fd = os.open(out / LOCK_FILE, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        if fcntl is None:  # not POSIX: no lock
            yield
            return
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(fd, 32, 0).decode(errors="replace").strip()
            who = f"railstop process {holder}" if holder.isdigit() else "railstop process"
            raise RailstopError(
                f"{out}: another {who} is running this campaign; wait for it to end or stop it"
            ) from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        yield
    finally:
        os.close(fd)


def check_capacity(spec: CampaignSpec, out: Path) -> None:
    """Refuse, before any run, a campaign whose files the disk cannot hold or whose summary
    does not fit in memory (the estimates are upper bounds: the values are stored uncompressed)."""
    if not seed_in_range(spec.seed):
        raise RailstopError(f"--seed: {SEED_RANGE} (got {spec.seed})")
    if spec.runs >= RUN_LIMIT:
        raise RailstopError(f"--runs: {spec.runs:,} is beyond the 64-bit run numbers (< 2^63)")
    columns = len(RESULT_COLUMNS) + len(PARAMETERS) + 2  # the drawn values (draw_scenario)
    need = 2 * spec.runs * columns * DISK_BYTES_PER_VALUE  # the chunks, then runs.parquet
    place = out
    while not place.exists() and place != place.parent:
        place = place.parent
    free = shutil.disk_usage(place).free
    if need > free:
        raise RailstopError(
            f"--runs: {spec.runs:,} runs need up to {_size(need)} on disk ({columns} columns, "
            f"chunks and runs.parquet); {place} has {_size(free)} free"
        )
    memory = _physical_memory()
    if memory and spec.runs * SUMMARY_BYTES_PER_RUN > memory:
        raise RailstopError(
            f"--runs: {spec.runs:,} runs need about {_size(spec.runs * SUMMARY_BYTES_PER_RUN)} of memory "
            f"for the summary; this machine has {_size(memory)} (run several campaigns with other seeds)"
        )


def _physical_memory() -> int:
    try:
        return int(os.sysconf("SC_PAGE_SIZE")) * int(os.sysconf("SC_PHYS_PAGES"))
    except (ValueError, OSError, AttributeError):
        return 0


def _size(n: float) -> str:
    for unit in ("B", "kB", "MB", "GB", "TB", "PB"):
        if n < 1000 or unit == "PB":
            return f"{n:,.0f} {unit}" if unit == "B" else f"{n:,.1f} {unit}"
        n /= 1000
    raise AssertionError("unreachable")


@dataclass(frozen=True, slots=True, kw_only=True)
class CampaignOutcome:
    out: Path
    manifest: dict[str, Any]
    summary: dict[str, Any]
    runs_simulated: int  # by this call (a resume skips finished chunks)
    elapsed_s: float


Progress = Callable[[int, int], None]  # (runs done so far, runs in total)


def finished_chunks(spec: CampaignSpec, out: Path) -> tuple[int, int]:
    """The chunk files in ``out`` now and the runs they hold (by name: for messages, unchecked)."""
    chunks = runs = 0
    with contextlib.suppress(OSError), os.scandir(Path(out) / CHUNK_DIR) as entries:
        for entry in entries:
            k = _chunk_index(entry.name)
            if k is not None:
                first, end = spec.chunk_range(k)
                chunks += 1
                runs += max(end - first, 0)
    return chunks, runs


def _check_spec(spec: CampaignSpec) -> None:
    if spec.law is not None:
        spec.law.load()
    if spec.controller not in known_controllers():
        names = ", ".join(known_controllers())
        raise RailstopError(f"--controller: unknown controller {spec.controller!r}; choose one of: {names}")
    if spec.runs < 1 or spec.chunk_size < 1:
        raise RailstopError(
            f"--runs and the chunk size must be at least 1 (got {spec.runs}, {spec.chunk_size})"
        )
    check_device(spec.device, law_loaded=spec.law is not None)


def _failed_block(out: Path, exc: ItemFailedError) -> str:
    """A block that failed, as the user reads it: its runs (the executor's item is the block
    (chunk, first, end)), its error, and what is kept."""
    item = exc.item
    runs = f"runs {item[1]}..{item[2] - 1}" if isinstance(item, tuple) and len(item) == 3 else "a block"
    return f"{out}: {runs} failed: {exc.cause} (the chunks finished are kept for --resume)"


def _preflight(spec: CampaignSpec) -> None:
    """Run the campaign's first run on the CPU before anything is written: data the stop model
    refuses (a station it cannot run, an approach ``ato-corrected`` cannot position) is then one
    clear error and no campaign folder is left behind to block the corrected command."""
    simulate_block(replace(spec, device="cpu"), (0, 0, 1))


def check_device(device: str, *, law_loaded: bool = False) -> None:
    """Refuse a device the stop model cannot run on here, before any work (``--device``)."""
    if device not in DEVICES:
        raise RailstopError(f"--device: {device!r} is not one of {', '.join(DEVICES)}")
    if device == "gpu":
        why = gpu_unavailable()
        if why is not None:
            raise RailstopError(f"--device gpu: {why}")
        if law_loaded:
            raise RailstopError(
                "--device gpu: a law loaded from a file runs on the CPU only (the GPU can neither "
                "check its indices nor catch its errors); drop --device gpu"
            )


def _prepare(spec: CampaignSpec, out: Path, resume: bool) -> set[int]:
    """Check or write the manifest and the chunks already there; return the finished chunks.

    The caller holds the folder's lock.
    """
    manifest = spec.manifest()
    identity = manifest_sha256(manifest)
    path = out / MANIFEST
    if path.exists():
        if not resume:
            raise RailstopError(
                f"{out}: a campaign is already there; use --resume to continue it or choose another --out"
            )
        old = read_manifest(out)
        diff = sorted(k for k in set(old) | set(manifest) if old.get(k) != manifest.get(k))
        if diff:
            raise RailstopError(
                f"{path}: --resume asks for a different campaign (differs in: {', '.join(diff)})"
            )
    elif resume and any(p.name != LOCK_FILE for p in out.iterdir()):
        raise RailstopError(f"{out}: --resume but no {MANIFEST} there")
    chunk_dir = out / CHUNK_DIR
    chunk_dir.mkdir(parents=True, exist_ok=True)
    if not path.exists():
        tmp = path.with_name(f".{MANIFEST}.tmp")
        tmp.write_text(json.dumps(manifest, indent=2, sort_keys=True), encoding="utf-8")
        os.replace(tmp, path)
    finished: set[int] = set()
    with os.scandir(chunk_dir) as entries:
        for entry in entries:
            k = _chunk_index(entry.name)
            if entry.name.startswith(".") and entry.name.endswith(".tmp"):  # killed while being written
                Path(entry.path).unlink(missing_ok=True)
            elif k is not None:
                if k >= spec.chunks:
                    raise RailstopError(
                        f"{entry.path}: chunk {k} is beyond this campaign's {spec.chunks} chunks; "
                        "move it away and --resume"
                    )
                _verify_chunk(spec, identity, Path(entry.path), k)
                finished.add(k)
    return finished


def _executed(
    spec: CampaignSpec, out: Path, finished: set[int], workers: int, scheduler: str | None
) -> Iterator[int]:
    """Run the chunks not ``finished`` where the executor says; write each as it arrives;
    yield the run count of every block as it comes back.

    Interrupted (Ctrl-C, a kill, a failed chunk): the chunks not yet written
    are abandoned (their files are written atomically, so none is half
    there); every finished one stays.
    """
    identity = spec.identity()
    todo = (k for k in range(spec.chunks) if k not in finished)
    parts: dict[int, dict[int, pa.Table]] = {}
    with contextlib.closing(
        execute(
            functools.partial(simulate_block, spec),
            _blocks(spec, todo, spec.chunks - len(finished), 1 if scheduler else workers),
            # One thread feeds the GPU: it runs a whole chunk at once.
            workers=1 if spec.device == "gpu" else workers,
            scheduler=scheduler,
        )
    ) as results:
        for (k, first, _), table in results:
            got = parts.setdefault(k, {})
            got[first] = table
            lo, hi = spec.chunk_range(k)
            if sum(t.num_rows for t in got.values()) == hi - lo:
                _write_chunk(spec, identity, out, k, pa.concat_tables([got[a] for a in sorted(got)]))
                del parts[k]
            yield table.num_rows


def _blocks(
    spec: CampaignSpec, todo: Iterable[int], n_todo: int, workers: int
) -> Iterator[tuple[int, int, int]]:
    """The blocks (chunk, first run, end) to simulate, lazily: each chunk cut into blocks of at
    most ``BLOCK_RUNS`` runs, and into more when there are fewer chunks than workers so that
    every worker is busy (a run's result does not depend on its block, so the chunk files are
    the same)."""
    if spec.device == "gpu":
        # A GPU runs a chunk in one launch (one thread per run): the more runs, the fuller it is.
        for k in todo:
            yield k, *spec.chunk_range(k)
        return
    split = max(1, -(-workers // max(n_todo, 1)))
    for k in todo:
        for a, b in blocks(*spec.chunk_range(k), split, BLOCK_RUNS):
            yield k, a, b


def run_campaign(
    spec: CampaignSpec,
    out: Path,
    *,
    workers: int = 1,
    resume: bool = False,
    progress: Progress | None = None,
    scheduler: str | None = None,
) -> CampaignOutcome:
    """Run (or continue) the campaign into ``out``; see the module docstring.

    ``workers``: threads in this process (the kernel holds no GIL);
    ``scheduler``: the address of a Dask scheduler to run the chunks on instead.
    """
    out = Path(out)
    _check_spec(spec)
    check_capacity(spec, out)
    _preflight(spec)
    if scheduler is not None:
        describe(scheduler=scheduler)  # an address that does not answer: refused before the folder
    with campaign_lock(out):
        finished = _prepare(spec, out, resume)
        done_runs = sum(spec.chunk_range(k)[1] - spec.chunk_range(k)[0] for k in finished)
        if progress:
            progress(done_runs, spec.runs)
        t0 = time.perf_counter()
        simulated = 0
        try:
            for n in _executed(spec, out, finished, workers, scheduler):
                simulated += n
                if progress:
                    progress(done_runs + simulated, spec.runs)
        except ItemFailedError as exc:
            raise RailstopError(_failed_block(out, exc)) from exc
        elapsed = time.perf_counter() - t0
        merge_chunks(spec, out)
        st = spec.line.station(spec.station)
        summary = summarise(
            pq.read_table(out / RUNS_FILE, columns=list(SUMMARY_COLUMNS)),
            tolerance_m=spec.tolerance(),
            platform_end_m=st.platform_end - st.stop_point_m,
        )
        summary["runs_per_s"] = round(simulated / elapsed, 1) if simulated and elapsed > 0 else None
        # Who summarised it, when, and the campaign it is (the manifest's hash, as in the chunks).
        summary["provenance"] = stamp(spec.identity())
        tmp = out / f".{SUMMARY_FILE}.tmp"
        tmp.write_text(json.dumps(summary, indent=2, sort_keys=True), encoding="utf-8")
        os.replace(tmp, out / SUMMARY_FILE)
    return CampaignOutcome(
        out=out, manifest=spec.manifest(), summary=summary, runs_simulated=simulated, elapsed_s=elapsed
    )


SUMMARY_COLUMNS = (
    "stop_error_m",
    "max_jerk_mps3",
    "stop_time_s",
    "stopped",
    "slid",
    "emergency_brake",
    "low_adhesion",  # drawn with every run (draw_scenario)
    "first_stop_error_m",
    "restops",
    "lamp",
)


def merge_chunks(spec: CampaignSpec, out: Path) -> None:
    """Write the chunk files in run order into ``runs.parquet``, one chunk in memory at a time."""
    tmp = out / f".{RUNS_FILE}.tmp"
    writer: pq.ParquetWriter | None = None
    try:
        for k in range(spec.chunks):
            path = _chunk_path(out, k)
            try:
                table = pq.read_table(path).replace_schema_metadata(None)
            except (OSError, pa.ArrowInvalid) as exc:
                raise _unreadable(path, exc) from None
            if writer is None:
                writer = pq.ParquetWriter(tmp, table.schema)
            writer.write_table(table)
    finally:
        if writer is not None:
            writer.close()
    os.replace(tmp, out / RUNS_FILE)


def summarise(table: pa.Table, *, tolerance_m: float, platform_end_m: float | None = None) -> dict[str, Any]:
    """The campaign's summary statistics (see ``summary_stats``), JSON-ready."""

    def col(name: str) -> np.ndarray:
        return table.column(name).to_numpy()

    # SPEC §3: the driver columns are summarised where a run had a lamp (a driver controller).
    lamp = col("lamp") if "lamp" in table.column_names else None
    stats = summary_stats(
        col("stop_error_m"),
        col("max_jerk_mps3"),
        col("stop_time_s"),
        col("stopped"),
        col("slid"),
        tolerance_m=tolerance_m,
        emergency_brake=col("emergency_brake") if "emergency_brake" in table.column_names else None,
        platform_end_m=platform_end_m,
        low_adhesion=col("low_adhesion") if "low_adhesion" in table.column_names else None,
        manual=(col("first_stop_error_m"), col("restops"), lamp)
        if lamp is not None and bool(np.any(lamp > 0))
        else None,
    )
    return {k: (None if isinstance(v, float) and not np.isfinite(v) else v) for k, v in stats.items()}


def read_manifest(out: Path) -> dict[str, Any]:
    path = Path(out) / MANIFEST
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise RailstopError(f"{out}: not a campaign directory (no {MANIFEST})") from None
    except (OSError, ValueError) as exc:  # ValueError: bad JSON or not UTF-8 at all
        raise RailstopError(f"{path}: cannot read the campaign manifest: {exc}") from None
    if not isinstance(data, dict):
        raise RailstopError(f"{path}: the campaign manifest is not a JSON object")
    return data


def spec_from_manifest(
    manifest: dict[str, Any],
    line: Line,
    vehicle: Vehicle,
    source: str,
    *,
    driver: DriverFile | None = None,
    platform: PlatformFile | None = None,
    law: Path | None = None,
) -> CampaignSpec:
    """The campaign a manifest describes, with the line, vehicle (and driver, platform, law file)
    data it was run on."""
    law_file = law_of_manifest(manifest, law, source)
    if manifest.get("model_version") != MODEL_VERSION:
        raise RailstopError(
            f"{source}: the campaign was made by stop model version {manifest.get('model_version', 1)}; "
            f"this railstop has version {MODEL_VERSION} (run the campaign again)"
        )
    if manifest.get("data_sha256") != _data_hash(line, vehicle):
        raise RailstopError(
            f"{source}: the campaign was run on other line or vehicle data than given "
            "(pass the same --line / --vehicle files)"
        )
    if manifest.get("manual_data_sha256") != overrides_sha256(driver, platform):
        raise RailstopError(
            f"{source}: the campaign was run on other driver or platform data than given "
            "(pass the same --driver / --platform files)"
        )
    dist = manifest["disturbances"]
    return CampaignSpec(
        line=line,
        vehicle=vehicle,
        station=str(manifest["station"]),
        controller=str(manifest["controller"]),
        runs=int(manifest["runs"]),
        seed=int(manifest["seed"]),
        disturbances=DisturbanceSet.from_dict(dist["set"], name=str(dist["name"]), source=source),
        chunk_size=int(manifest["chunk_size"]),
        form=int(manifest["form"]),
        driver=driver,
        platform=platform,
        law=law_file,
        device=str(manifest.get("device", "cpu")),
    )


def law_of_manifest(manifest: dict[str, Any], law: Path | None, source: str) -> LawFile | None:
    """The law file of a campaign's manifest: the one given (``--law``), which must be the one
    the campaign ran."""
    recorded = manifest.get("law")
    if recorded is None:
        if law is not None:
            raise RailstopError(
                f"{source}: the campaign ran a built-in controller; --law {law} does not apply"
            )
        return None
    if law is None:
        raise RailstopError(
            f"{source}: the campaign ran the law of {recorded.get('file')!r}; pass that file with --law"
        )
    law_file = LawFile.of(law)
    if law_file.sha256 != recorded.get("sha256"):
        raise RailstopError(f"{source}: --law {law} is not the law file the campaign ran (its text differs)")
    law_file.load()
    return law_file


def replay_profile(
    out: Path,
    run: int,
    line: Line,
    vehicle: Vehicle,
    *,
    driver: DriverFile | None = None,
    platform: PlatformFile | None = None,
    law: Path | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Run ``run`` of the campaign in ``out`` again with recording: (distance to the stop m, speed
    km/h); ``law``: the law file of a campaign of a loaded law. The recording runs on the CPU, a
    GPU campaign's run too (its numbers agree with the GPU's within railstop.model.gpu's bound)."""
    spec = spec_from_manifest(
        read_manifest(out),
        line,
        vehicle,
        str(Path(out) / MANIFEST),
        driver=driver,
        platform=platform,
        law=law,
    )
    station = line.station(spec.station)
    result, _ = simulate_runs(
        station=station,
        vehicle=vehicle,
        controller=spec.controller,
        disturbances=spec.disturbances,
        seed=spec.seed,
        first_run=run,
        n=1,
        form=spec.form,
        record=True,
        track=line.track,
        driver=spec.driver,
        platform=spec.platform,
    )
    if result.trace is None:
        raise RailstopError("replay recorded no trace")
    return result.trace.position_m[:, 0] - station.stop_point_m, result.trace.speed_mps[:, 0] * KMH_PER_MPS
