"""Line campaigns (issue 14 item 5): many runs of the line over disturbance draws, in processes.

Run ``r`` of a campaign of seed ``S`` is the line run of seed ``S + r``: every
station stop of every train draws its own disturbances from that seed
(``sim.line``), so a run is reproduced alone by ``railstop line run --seed
S+r``. Finished runs are appended to ``runs.jsonl`` in the campaign folder as
they come back (one JSON object per line: the run's summary and its stops),
so an interrupted campaign keeps them and ``--resume`` runs only the others.
The summary pools the stops of every run per station.
"""

from __future__ import annotations

import functools
import json
import os
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from railstop.config.disturbances import DisturbanceSet
from railstop.config.operation import Operation
from railstop.config.schema import Line, Vehicle
from railstop.control.law import LawFile
from railstop.errors import RailstopError
from railstop.sim.campaign import MODEL_VERSION
from railstop.sim.executor import execute
from railstop.sim.line import LINE_MODEL_VERSION, LineSettings, LineSimulation

RUNS_FILE = "runs.jsonl"
SPEC_FILE = "campaign.json"


@dataclass(frozen=True, slots=True, kw_only=True)
class LineCampaignSpec:
    line: Line
    vehicle: Vehicle
    operation: Operation
    disturbances: DisturbanceSet
    runs: int
    seed: int
    duration_s: float
    settings: LineSettings = field(default_factory=LineSettings)  # checked when it is made
    # The file of a stop-control law loaded by the user (railstop.control.law; None: built in).
    # Its text travels with the spec to worker processes and Dask machines.
    law: LawFile | None = None

    def identity(self) -> dict[str, Any]:
        """What decides the numbers (checked on --resume)."""
        return {
            "line": self.line.model_dump(mode="json"),
            "vehicle": self.vehicle.model_dump(mode="json"),
            "operation": self.operation.model_dump(mode="json"),
            "disturbances": self.disturbances.name,
            "disturbance_params": {k: str(v) for k, v in sorted(self.disturbances.params.items())},
            "runs": self.runs,
            "seed": self.seed,
            "duration_s": self.duration_s,
            **self.settings.identity(),
            # A built-in controller's campaign keeps the identity it had before laws could be
            # loaded; with a law, its file's name and hash (--resume with another text is refused).
            **({} if self.law is None else {"law": self.law.manifest()}),
            # Absent from the campaigns of version 1 (its stops replayed a recorded trajectory):
            # a --resume across versions is refused rather than mixing their runs.
            "line_model_version": LINE_MODEL_VERSION,
            # The line steps the stop model in every station stop: runs of another stop model
            # stop otherwise, so a --resume across stop models is refused too.
            "model_version": MODEL_VERSION,
        }


def run_one(spec: LineCampaignSpec, run: int) -> dict[str, Any]:
    """One line run of the campaign: its summary and its stops (JSON-ready)."""
    if spec.law is not None:
        spec.law.load()  # in a worker process: the law by its text (compiled once per process)
    sim = LineSimulation(
        line=spec.line,
        vehicle=spec.vehicle,
        operation=spec.operation,
        disturbances=spec.disturbances,
        seed=spec.seed + run,
        settings=spec.settings,
    )
    result = sim.run(spec.duration_s)
    return {
        "run": run,
        "summary": result.summary(),
        "stops": [asdict(s) for s in result.stops],
        "dwells": [asdict(d) for d in result.dwells],
    }


def _read_done(out: Path) -> dict[int, dict[str, Any]]:
    path = out / RUNS_FILE
    done: dict[int, dict[str, Any]] = {}
    if not path.exists():
        return done
    lines = path.read_text(encoding="utf-8").splitlines()
    for k, line in enumerate(lines):
        try:
            row = json.loads(line)
            done[int(row["run"])] = row
        except (ValueError, KeyError, TypeError):
            # Only the last line can be cut (a kill mid-write): drop it, that run runs again.
            if k != len(lines) - 1:
                raise RailstopError(f"{path}: line {k + 1} is not a finished run") from None
            path.write_text("".join(ln + "\n" for ln in lines[:-1]), encoding="utf-8")
    return done


def run_line_campaign(
    spec: LineCampaignSpec,
    out: Path,
    *,
    workers: int = 1,
    resume: bool = False,
    progress: Callable[[int, int], None] | None = None,
    scheduler: str | None = None,
) -> dict[str, Any]:
    """Run the campaign into ``out`` (created); return its summary (also ``out/summary.json``).
    ``workers`` > 1: that many processes; ``scheduler``: the Dask scheduler at that address."""
    out = Path(out)
    ident = spec.identity()
    spec_path = out / SPEC_FILE
    if resume and not spec_path.exists():
        # --resume continues a campaign: a folder without one would silently start afresh.
        raise RailstopError(
            f"{out}: --resume but no line campaign there ({SPEC_FILE}); drop --resume to start one"
        )
    if spec_path.exists():
        if not resume:
            raise RailstopError(f"{out}: a line campaign is already there; use --resume or another --out")
        if json.loads(spec_path.read_text(encoding="utf-8")) != ident:
            raise RailstopError(f"{out}: --resume with other settings than the campaign there")
    else:
        out.mkdir(parents=True, exist_ok=True)
        spec_path.write_text(json.dumps(ident, sort_keys=True), encoding="utf-8")
    done = _read_done(out)
    todo = [r for r in range(spec.runs) if r not in done]
    # Each run is a pure function of the spec and its index: in this process, in processes, or
    # on a Dask cluster (sim.executor); each row is on disk before the next is taken.
    rows = execute(
        functools.partial(run_one, spec),
        todo,
        workers=workers,
        scheduler=scheduler,
        processes=scheduler is None and workers > 1,
    )
    with (out / RUNS_FILE).open("a", encoding="utf-8") as sink:
        for _, row in rows:
            sink.write(json.dumps(row) + "\n")
            sink.flush()
            os.fsync(sink.fileno())
            done[int(row["run"])] = row
            if progress:
                progress(len(done), spec.runs)
    summary = summarise(spec, [done[r] for r in sorted(done)])
    (out / "summary.json").write_text(json.dumps(summary, indent=2, sort_keys=True), encoding="utf-8")
    return summary


def summarise(spec: LineCampaignSpec, rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Per station: stops, share within its PSD tolerance, p99 |error|, mean dwell, emergency
    brakes; over the runs: trains per hour, mean delay, position error p99 (mean and worst)."""
    tol = {s.name: s.psd_tolerance_m for s in spec.line.stations}
    stations: dict[str, dict[str, Any]] = {}
    for name in tol:
        errs = np.array([abs(s["error_m"]) for r in rows for s in r["stops"] if s["station"] == name])
        dwells = [d["dwell_s"] for r in rows for d in r["dwells"] if d["station"] == name]
        stations[name] = {
            "stops": int(errs.size),
            "within_tolerance": round(float(np.mean(errs <= tol[name])), 6) if errs.size else None,
            "p99_abs_error_m": round(float(np.percentile(errs, 99.0)), 4) if errs.size else None,
            "mean_dwell_s": round(float(np.mean(dwells)), 2) if dwells else None,
            "emergency_brakes": int(
                sum(1 for r in rows for s in r["stops"] if s["station"] == name and s["emergency_brake"])
            ),
        }

    def values(key: str) -> list[float]:
        return [float(r["summary"][key]) for r in rows if r["summary"].get(key) is not None]

    def mean(key: str) -> float | None:
        v = values(key)
        return round(float(np.mean(v)), 3) if v else None

    pos = values("position_error_p99_m")
    separation = values("min_separation_m")
    return {
        "runs": len(rows),
        "seed": spec.seed,
        "disturbances": spec.disturbances.name,
        "trains": spec.operation.trains,
        "headway_s": spec.operation.headway_s,
        "stations": stations,
        "trains_per_hour_mean": mean("trains_per_hour"),
        "mean_delay_s_mean": mean("mean_delay_s"),
        "emergency_brakes": int(sum(values("emergency_brakes"))),
        "dwell_faults": int(sum(values("dwell_faults"))),
        "psc_retries": int(sum(values("psc_retries"))),
        "door_link": {
            k: int(sum(r["summary"].get("door_link", {}).get(k, 0) for r in rows))
            for k in ("frames", "lost", "rejected")
        },
        "occupancy_link": {
            k: int(sum(r["summary"].get("occupancy_link", {}).get(k, 0) for r in rows))
            for k in ("frames", "delivered", "lost", "rejected", "duplicates")
        },
        "skipped_stops": int(sum(values("skipped_stops"))),
        "signals_passed_at_danger": int(sum(values("signals_passed_at_danger"))),
        "min_separation_m": round(min(separation), 2) if separation else None,
        "position_error_p99_m_mean": round(float(np.mean(pos)), 3) if pos else None,
        "position_error_p99_m_worst": round(float(np.max(pos)), 3) if pos else None,
        "signalling": spec.settings.signalling,
        "cbtc": _cbtc_totals(rows),
    }


def _cbtc_totals(rows: list[dict[str, Any]]) -> dict[str, Any] | None:
    """The CBTC counts summed over the runs, and the delay split's means (None: fixed-block runs)."""
    parts = [r["summary"].get("cbtc") for r in rows]
    cbtc = [p for p in parts if p]
    if not cbtc:
        return None
    keys = (
        "lost_trains",
        "auto_releases",
        "flagged",
        "manual_releases",
        "restarts",
        "authority_overlaps",
        "collisions",
        "uncertainty_exceeded",
        "onboard_emergency_brakes",
        "zones",
        "zone_time_s",
        "zone_m_s",
    )
    totals: dict[str, Any] = {k: round(sum(float(p.get(k, 0)) for p in cbtc), 1) for k in keys}
    # The delay split (SPEC §4): the lost trains' own and the others', each the mean over the runs
    # that had such trains.
    for key in ("mean_delay_lost_trains_s", "mean_delay_other_trains_s"):
        got = [float(p[key]) for p in cbtc if p.get(key) is not None]
        totals[f"{key}_mean"] = round(float(np.mean(got)), 2) if got else None
    if any("regulation_holds" in p for p in cbtc):  # (only when the ATS regulated the runs)
        for key in ("regulation_holds", "regulation_hold_s"):
            totals[key] = round(sum(float(p.get(key, 0)) for p in cbtc), 1)
    return totals
