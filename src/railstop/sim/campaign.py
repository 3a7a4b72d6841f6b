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
    chunks/           one Parquet file per finished chunk
    runs.parquet      every run, in run order (written when all chunks are done)
    summary.json      the summary statistics
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import json
import os
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from railstop.config.disturbances import DisturbanceSet, draw_scenario
from railstop.config.schema import Line, Station, Track, Vehicle
from railstop.errors import RailstopError
from railstop.report.campaign_report import summary_stats
from railstop.sim.engine import CONTROLLERS, BatchResult, run_batch
from railstop.sim.executor import execute
from railstop.streams import RunStreams
from railstop.wayside.tasc_unit import SignalForm

MANIFEST = "campaign.json"
RUNS_FILE = "runs.parquet"
SUMMARY_FILE = "summary.json"
CHUNK_DIR = "chunks"
DEFAULT_CHUNK = 10_000
MANIFEST_VERSION = 1
# The stop model's version: a campaign is resumed (and a run replayed) only by the model that
# made it. 2: the compiled kernel, each run ending at its own stop (the lockstep array engine,
# version 1, went on stepping stopped runs, so in continuous update its command counts
# depended on the other runs of the chunk). 3: the Doppler noise drawn by the ziggurat
# (streams.key_normal_zig) instead of Box–Muller: same distribution, other numbers.
MODEL_VERSION = 3

RESULT_COLUMNS = (
    "run",
    "stop_error_m",
    "stop_time_s",
    "max_jerk_mps3",
    "notch_changes",
    "commands_sent",
    "commands_received",
    "stopped",
    "slid",
)


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

    def manifest(self) -> dict[str, Any]:
        st = self.line.station(self.station)
        return {
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
            # The data the numbers come from: a resume must use the same.
            "data_sha256": _data_hash(self.line, self.vehicle),
        }

    @property
    def chunks(self) -> int:
        return -(-self.runs // self.chunk_size)

    def chunk_range(self, k: int) -> tuple[int, int]:
        first = k * self.chunk_size
        return first, min(first + self.chunk_size, self.runs)


def _data_hash(line: Line, vehicle: Vehicle) -> str:
    text = json.dumps([line.model_dump(mode="json"), vehicle.model_dump(mode="json")], sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()


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
) -> tuple[BatchResult, dict[str, np.ndarray]]:
    """Runs ``first_run .. first_run + n - 1`` of a campaign: the drawn values and the batch result.

    ``track``: the line's track circuits (needed by ``ato-corrected``).
    """
    streams = RunStreams.for_runs(seed, first_run, n)
    scenario, drawn = draw_scenario(disturbances, station, vehicle, streams)
    result = run_batch(
        station=station,
        vehicle=vehicle,
        scenario=scenario,
        controller=controller,
        streams=streams,
        form=None if form is None else SignalForm(form),
        record=record,
        track=track,
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
    }
    for name, values in drawn.items():
        cols[name] = np.asarray(values)
    return pa.table(cols)


def _chunk_path(out: Path, k: int) -> Path:
    return out / CHUNK_DIR / f"chunk-{k:06d}.parquet"


def simulate_block(spec: CampaignSpec, block: tuple[int, int, int]) -> pa.Table:
    """The per-run rows of runs ``first .. end - 1`` of a chunk (``block`` = (chunk, first, end)): a
    pure function of the spec and the block, so any thread, process or machine may compute it."""
    _, first, end = block
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
    )
    return _chunk_table(first, result, drawn)


def _write_chunk(out: Path, k: int, table: pa.Table) -> None:
    """Write chunk k atomically (temporary file, then rename): a chunk file is whole or absent."""
    path = _chunk_path(out, k)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    pq.write_table(table, tmp)
    os.replace(tmp, path)


@dataclass(frozen=True, slots=True, kw_only=True)
class CampaignOutcome:
    out: Path
    manifest: dict[str, Any]
    summary: dict[str, Any]
    runs_simulated: int  # by this call (a resume skips finished chunks)
    elapsed_s: float


Progress = Callable[[int, int], None]  # (runs done so far, runs in total)


def _prepare(spec: CampaignSpec, out: Path, resume: bool) -> list[int]:
    """Check or write the manifest; return the chunks still to run."""
    if spec.controller not in CONTROLLERS:
        raise RailstopError(
            f"--controller: unknown controller {spec.controller!r}; choose one of: {', '.join(CONTROLLERS)}"
        )
    if spec.runs < 1 or spec.chunk_size < 1:
        raise RailstopError(
            f"--runs and the chunk size must be at least 1 (got {spec.runs}, {spec.chunk_size})"
        )
    manifest = spec.manifest()
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
    elif resume and out.exists() and any(out.iterdir()):
        raise RailstopError(f"{out}: --resume but no {MANIFEST} there")
    (out / CHUNK_DIR).mkdir(parents=True, exist_ok=True)
    if not path.exists():
        tmp = path.with_name(f".{MANIFEST}.tmp")
        tmp.write_text(json.dumps(manifest, indent=2, sort_keys=True), encoding="utf-8")
        os.replace(tmp, path)
    for stale in (out / CHUNK_DIR).glob(".*.tmp"):  # a chunk killed while writing
        stale.unlink(missing_ok=True)
    return [k for k in range(spec.chunks) if not _chunk_path(out, k).exists()]


def _executed(
    spec: CampaignSpec, out: Path, todo: list[int], workers: int, scheduler: str | None
) -> Iterator[int]:
    """Run the chunks in ``todo`` where the executor says; write each as it arrives, yield its run count.

    Interrupted (Ctrl-C, a kill, a failed chunk): the chunks not yet written
    are abandoned (their files are written atomically, so none is half
    there); every finished one stays.
    """
    blocks = _blocks(spec, todo, 1 if scheduler else workers)
    parts: dict[int, dict[int, pa.Table]] = {k: {} for k in todo}
    expected = {k: sum(1 for b in blocks if b[0] == k) for k in todo}
    with contextlib.closing(
        execute(functools.partial(simulate_block, spec), blocks, workers=workers, scheduler=scheduler)
    ) as results:
        for (k, first, _), table in results:
            parts[k][first] = table
            if len(parts[k]) == expected[k]:
                _write_chunk(out, k, pa.concat_tables([parts[k][a] for a in sorted(parts[k])]))
                del parts[k]
            yield table.num_rows


def _blocks(spec: CampaignSpec, todo: list[int], workers: int) -> list[tuple[int, int, int]]:
    """The blocks (chunk, first run, end) to simulate: whole chunks, or when there are fewer
    chunks than workers each chunk cut into as many blocks as keep every worker busy (a run's
    result does not depend on its block, so the chunk files are the same)."""
    split = max(1, -(-workers // max(len(todo), 1)))
    blocks: list[tuple[int, int, int]] = []
    for k in todo:
        first, end = spec.chunk_range(k)
        size = -(-(end - first) // split)
        blocks.extend((k, a, min(a + size, end)) for a in range(first, end, size))
    return blocks


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
    todo = _prepare(spec, out, resume)
    done_runs = spec.runs - sum(spec.chunk_range(k)[1] - spec.chunk_range(k)[0] for k in todo)
    if progress:
        progress(done_runs, spec.runs)
    t0 = time.perf_counter()
    simulated = 0
    for n in _executed(spec, out, todo, workers, scheduler):
        simulated += n
        if progress:
            progress(done_runs + simulated, spec.runs)
    elapsed = time.perf_counter() - t0
    table = merge_chunks(spec, out)
    summary = summarise(table)
    summary["runs_per_s"] = round(simulated / elapsed, 1) if simulated and elapsed > 0 else None
    tmp = out / f".{SUMMARY_FILE}.tmp"
    tmp.write_text(json.dumps(summary, indent=2, sort_keys=True), encoding="utf-8")
    os.replace(tmp, out / SUMMARY_FILE)
    return CampaignOutcome(
        out=out, manifest=spec.manifest(), summary=summary, runs_simulated=simulated, elapsed_s=elapsed
    )


def merge_chunks(spec: CampaignSpec, out: Path) -> pa.Table:
    """Concatenate the chunk files in run order into ``runs.parquet``."""
    tables = []
    for k in range(spec.chunks):
        path = _chunk_path(out, k)
        try:
            tables.append(pq.read_table(path))
        except (OSError, pa.ArrowInvalid) as exc:
            raise RailstopError(
                f"{path}: cannot read a finished chunk ({exc}); delete it and --resume"
            ) from None
    table = pa.concat_tables(tables)
    tmp = out / f".{RUNS_FILE}.tmp"
    pq.write_table(table, tmp)
    os.replace(tmp, out / RUNS_FILE)
    return table


def summarise(table: pa.Table) -> dict[str, Any]:
    """The campaign's summary statistics (see ``summary_stats``), JSON-ready."""

    def col(name: str) -> np.ndarray:
        return table.column(name).to_numpy()

    stats = summary_stats(
        col("stop_error_m"), col("max_jerk_mps3"), col("stop_time_s"), col("stopped"), col("slid")
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


def spec_from_manifest(manifest: dict[str, Any], line: Line, vehicle: Vehicle, source: str) -> CampaignSpec:
    """The campaign a manifest describes, with the line and vehicle data it was run on."""
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
    )


def replay_profile(out: Path, run: int, line: Line, vehicle: Vehicle) -> tuple[np.ndarray, np.ndarray]:
    """Run ``run`` of the campaign in ``out`` again with recording: (distance to the stop m, speed km/h)."""
    spec = spec_from_manifest(read_manifest(out), line, vehicle, str(Path(out) / MANIFEST))
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
    )
    if result.trace is None:
        raise RailstopError("replay recorded no trace")
    return result.trace.position_m[:, 0] - station.stop_point_m, result.trace.speed_mps[:, 0] * 3.6
