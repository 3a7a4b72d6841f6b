"""SPEC §2 S10-S30 from the track to the trains, as one piece a driver steps: the occupancy chain.

For n trains (a "run" of the arrays is one train's passage):

    track-circuit devices (electrical boundary, detection delay: drawn per train and circuit)
        ─> wayside time-stamping unit (its GNSS clock per circuit; free-running in a shadow)
            ─> telegram (circuit ID, GNSS time) ─> radio (latency) ─> codec (the wire's resolution)
                ─> the train, with its own GNSS clock (``onboard_time_s``)

A driver calls, every step, :meth:`OccupancyChain.advance` with the trains' motion over the
step (the clocks advance, the devices detect, the unit stamps what its devices declared by the
step's end), reads :meth:`onboard_time_s` for the onboard log, then takes
:meth:`arrivals` (the telegrams that reached the trains by then) for the positioning unit.

The wayside's clocks are either one world shared by every train (``wayside_streams`` of one
run: a line, whose trains pass the same devices) or one world per run (``wayside_streams`` of
n runs: independent runs of one train). A train not on the line is passed as ``-inf``
positions (it enters nothing).

[interpretation] The time-stamping unit keeps a circuit's state per train: it sends when *a
train's* front enters a circuit, as if each train's passage had the circuit to itself. On a
line whose trains are kept a block apart (or a moving block's braking distance, longer than a
circuit) a front never enters a circuit another train still occupies; SPEC §2 does not say what
the unit sends then.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from railstop.config.schema import Line
from railstop.errors import SimulationError
from railstop.link.codec import TrackCircuitOccupancy, decode, encode
from railstop.onboard.positioning import FixOutcome, FixReport, PositioningUnit
from railstop.sensors.gnss_clock import PPM, GnssClock, in_shadow
from railstop.sensors.track_circuit import TrackCircuitDetector
from railstop.streams import RunStreams
from railstop.wayside.tc_timestamp import Indication, OccupancyTelegrams, TimestampUnit

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
BoolArray = NDArray[np.bool_]


@dataclass(frozen=True, slots=True, kw_only=True)
class ChainSettings:
    """What a run varies in the chain: GNSS time at all, the repeaters of the line data, the age
    of a clock with no time source (None: the line data's), the radio's latency."""

    gnss: bool = True  # SPEC §2 GNSS time (False: every clock free-runs)
    repeaters: bool = True  # SPEC §2 satellite-signal repeaters where the line data has them
    holdover_s: float | None = None
    latency_s: float = 0.05  # SPEC typical values: radio latency tens of ms


#: The service a line's clocks must hold their time over: a day (a line run lasts at most that).
SERVICE_DAY_S = 86400.0
#: The longest a train's clock stays in a GNSS shadow without a repeater ([interpretation]).
SHADOW_STAY_S = 3600.0


@dataclass(frozen=True, slots=True, kw_only=True)
class Arrivals:
    """Telegrams that reached the trains (k rows), as decoded from the wire."""

    run: IntArray  # (k,) the train
    circuit_id: IntArray
    gnss_time_s: FloatArray
    # The time error the fix sees: the stamping clock at the occupancy - the onboard clock now.
    clock_offset_s: FloatArray

    @property
    def size(self) -> int:
        return int(self.run.size)


@dataclass(frozen=True, slots=True, kw_only=True)
class _InFlight:
    """Telegrams on their way to the trains, with their arrival times and the stamping clocks' errors."""

    telegrams: OccupancyTelegrams
    arrival_s: FloatArray
    wayside_error_s: FloatArray

    def subset(self, rows: BoolArray) -> _InFlight:
        t = self.telegrams
        return _InFlight(
            telegrams=OccupancyTelegrams(
                run=t.run[rows], circuit_id=t.circuit_id[rows], gnss_time_s=t.gnss_time_s[rows]
            ),
            arrival_s=self.arrival_s[rows],
            wayside_error_s=self.wayside_error_s[rows],
        )


class OccupancyChain:
    """The devices, the time-stamping unit, the clocks and the radio of SPEC §2 for n trains."""

    def __init__(
        self,
        line: Line,
        *,
        train_streams: RunStreams,
        wayside_streams: RunStreams,
        start_position_m: FloatArray,
        settings: ChainSettings | None = None,
    ) -> None:
        cfg = settings or ChainSettings()
        circuits = line.track_circuits
        if not circuits:
            raise SimulationError("track.circuits: the line has no track circuits; positioning needs them")
        n = train_streams.n
        if wayside_streams.n not in (1, n):
            raise SimulationError(
                f"wayside streams: one world or one per train (got {wayside_streams.n} for {n})"
            )
        self.cfg = cfg
        self.n = n
        self._shared = wayside_streams.n == 1 and n != 1
        track = line.track
        start = np.broadcast_to(np.asarray(start_position_m, dtype=np.float64), (n,)).copy()
        clocks = track.clocks
        if cfg.holdover_s is not None:
            clocks = clocks.model_copy(update={"holdover_s": cfg.holdover_s})
        # SPEC §2: a shadow is a tunnel without a repeater (any tunnel when repeaters are off).
        shadow = [t for t in track.tunnels if not (t.repeater and cfg.repeaters)]
        self._sh_start = np.array([t.start_m for t in shadow])
        self._sh_end = np.array([t.end_m for t in shadow])
        onboard_disc = np.full(n, cfg.gnss) & ~in_shadow(start, self._sh_start, self._sh_end)
        self.onboard_clock = GnssClock.create(
            clocks, train_streams, clock_index=np.array([0]), disciplined=onboard_disc[:, None]
        )
        c_starts = np.array([c.start_m for c in circuits])
        # The time-stamping unit of a circuit sits at its start: in a shadow it has no GNSS.
        self._wayside_disc = np.full(len(circuits), cfg.gnss) & ~in_shadow(
            c_starts, self._sh_start, self._sh_end
        )
        self._clocks = clocks
        self.wayside_clock = GnssClock.create(
            clocks, wayside_streams, clock_index=1 + np.arange(len(circuits)), disciplined=self._wayside_disc
        )
        self.detector = TrackCircuitDetector.create(
            circuits, track.detection, train_streams, start_position_m=start
        )
        self.stamper = TimestampUnit([c.id for c in circuits], n)
        for r in range(n):
            occupied = np.flatnonzero(c_starts <= start[r])
            self.stamper.occupy_initial(np.full(occupied.size, r), occupied)
        self._pending: list[tuple[IntArray, IntArray, FloatArray]] = []
        self._wayside_due_s = 0.0  # simulated time the wayside clocks have not yet been advanced by
        self._in_flight: list[_InFlight] = []
        self.used_codec = False

    def _row(self, run: IntArray) -> IntArray:
        """The wayside world of each train: the shared one, or the run's own."""
        return np.zeros_like(run) if self._shared else run

    def advance(
        self,
        *,
        t0_s: float,
        dt_s: float,
        x0_m: FloatArray,
        v0_mps: FloatArray,
        accel_mps2: FloatArray,
        x1_m: FloatArray,
    ) -> None:
        """The step from ``t0_s`` (fronts at ``x0_m``, speeds ``v0_mps``, uniform ``accel_mps2``) to
        ``t0_s + dt_s`` (fronts at ``x1_m``): clocks, detection (S10), time-stamping (S20)."""
        t1 = t0_s + dt_s
        # SPEC §2 clocks: disciplined unless in a GNSS shadow without a repeater.
        onboard_disc = np.full(self.n, self.cfg.gnss) & ~in_shadow(x1_m, self._sh_start, self._sh_end)
        self.onboard_clock.advance(dt_s, onboard_disc[:, None])
        # The wayside clocks' state never changes (a unit stays where it is): they are advanced
        # only when a unit stamps (``_declare``), by the time since, the same error.
        self._wayside_due_s += dt_s
        # SPEC §2 S10: circuits entered; the device declares them after its delay.
        ev = self.detector.detect(x0_m=x0_m, v0_mps=v0_mps, accel_mps2=accel_mps2, x1_m=x1_m, t0_s=t0_s)
        if ev.size:
            self._pending.append((ev.run, ev.circuit_index, ev.occupied_time_s))
        self._declare(t1)

    def _declare(self, t1: float) -> None:
        """Hand the occupancies declared by ``t1`` to the time-stamping unit (SPEC §2 S20); keep the rest."""
        clock = self.wayside_clock
        keep: list[tuple[IntArray, IntArray, FloatArray]] = []
        for run, idx, t_occ in self._pending:
            due = t_occ <= t1
            if due.any():
                if self._wayside_due_s > 0.0:
                    clock.advance(self._wayside_due_s, self._wayside_disc[None, :])
                    self._wayside_due_s = 0.0
                r, c, tt = run[due], idx[due], t_occ[due]
                w = self._row(r)
                # The unit reads its own GNSS clock at the occupancy instant (error at the end of
                # this step, extrapolated back by the clock's drift: exact within the step).
                error = clock.error_s[w, c] - clock.drift[w, c] * (t1 - tt) * ~clock.disciplined[w, c]
                tel = self.stamper.handle(
                    run=r, circuit_index=c, indication=Indication.OCCUPIED, clock_time_s=tt + error
                )
                if tel.size and tel.source is not None:
                    # The telegram reaches the train a radio latency after the occupancy instant.
                    self._in_flight.append(
                        _InFlight(
                            telegrams=tel,
                            arrival_s=tt[tel.source] + self.cfg.latency_s,
                            wayside_error_s=error[tel.source],
                        )
                    )
            if (~due).any():
                keep.append((run[~due], idx[~due], t_occ[~due]))
        self._pending = keep

    def clock_sd_s(self, horizon_s: float = SERVICE_DAY_S) -> FloatArray:
        """Per circuit (line order), the standard deviation of the time error a fix of it carries:
        the stamping unit's clock against the train's, as the line data's clocks say (SPEC §2: a
        disciplined clock within ``disciplined_error_s``; one with no time source drifts at
        ``free_run_drift_ppm`` since it was last set, ``holdover_s`` before the run) over
        ``horizon_s`` of service. What an onboard unit can know of the line: which stamping units
        have no GNSS (its line data) and whether its own receiver has any ([interpretation]: the
        two clocks' errors independent; a whole service day, so that the bound holds for any
        run)."""
        c = self._clocks
        free = c.free_run_drift_ppm * PPM * (c.holdover_s + horizon_s)
        wayside = np.where(self._wayside_disc, c.disciplined_error_s, free)
        # The train's clock free-runs only in a shadow (for the minutes it takes to pass it: an
        # hour bounds it, a train held there included) or without GNSS at all.
        in_shadow_s = min(horizon_s, SHADOW_STAY_S) if self._sh_start.size else 0.0
        onboard = c.disciplined_error_s + c.free_run_drift_ppm * PPM * in_shadow_s if self.cfg.gnss else free
        return np.sqrt(wayside * wayside + onboard * onboard)

    def onboard_time_s(self, t_s: float) -> FloatArray:
        """Every train's GNSS clock reading at true time ``t_s`` (n,)."""
        return self.onboard_clock.read(t_s)[:, 0]

    def arrivals(self, t1_s: float) -> Arrivals:
        """The telegrams that have reached their trains by ``t1_s``, through the codec."""
        runs, ids, times, offsets = [], [], [], []
        still: list[_InFlight] = []
        for fl in self._in_flight:
            due = fl.arrival_s <= t1_s + 1e-12
            if due.any():
                got = _codec_round_trip(fl.subset(due).telegrams)
                self.used_codec = True
                runs.append(got.run)
                ids.append(got.circuit_id)
                times.append(got.gnss_time_s)
                offsets.append(fl.wayside_error_s[due] - self.onboard_clock.error_s[got.run, 0])
            if (~due).any():
                still.append(fl.subset(~due))
        self._in_flight = still
        if not runs:
            empty = np.zeros(0)
            return Arrivals(
                run=np.zeros(0, dtype=np.int64),
                circuit_id=np.zeros(0, dtype=np.int64),
                gnss_time_s=empty,
                clock_offset_s=empty,
            )
        return Arrivals(
            run=np.concatenate(runs),
            circuit_id=np.concatenate(ids),
            gnss_time_s=np.concatenate(times),
            clock_offset_s=np.concatenate(offsets),
        )


def _codec_round_trip(telegrams: OccupancyTelegrams) -> OccupancyTelegrams:
    """Each telegram as bytes and back (``railstop.link.codec``, type ``tc-occupancy``): the train
    sees the wire's resolution (0.1 ms of GNSS time). Losses and corruption are not modelled here."""
    ids = np.empty(telegrams.size, dtype=np.int64)
    times = np.empty(telegrams.size)
    for j in range(telegrams.size):
        frame = encode(
            TrackCircuitOccupancy(
                circuit_id=int(telegrams.circuit_id[j]), gnss_time_s=float(telegrams.gnss_time_s[j])
            )
        )
        msg = decode(frame)
        if not isinstance(msg, TrackCircuitOccupancy):  # the codec's own round trip guarantees it
            raise SimulationError(f"tc-occupancy telegram decoded as {type(msg).__name__}")
        ids[j] = msg.circuit_id
        times[j] = msg.gnss_time_s
    return OccupancyTelegrams(run=telegrams.run.copy(), circuit_id=ids, gnss_time_s=times)


@dataclass(frozen=True, slots=True, kw_only=True)
class FixRecord:
    """One telegram a train received (SPEC §2 S30/S40) and what its positioning unit did with it."""

    run: int  # the train (the row of the arrays)
    t_s: float  # true time it was handled
    circuit_id: int
    circuit_start_m: float
    gnss_time_s: float
    outcome: str
    corrected_jump_m: float
    calibrated_jump_m: float
    learned: bool
    gated: bool
    scale_estimate: float
    delay_estimate_s: float
    clock_offset_s: float  # wayside clock error at the occupancy - onboard clock error at the fix


def fix_records(rep: FixReport, got: Arrivals, unit: PositioningUnit, t_s: float) -> list[FixRecord]:
    """The records of the telegrams ``got`` that ``unit`` handled (its report ``rep``) at ``t_s``."""
    out = []
    for j in range(rep.run.size):
        r = int(rep.run[j])
        out.append(
            FixRecord(
                run=r,
                t_s=t_s,
                circuit_id=int(rep.circuit_id[j]),
                circuit_start_m=float(rep.circuit_start_m[j]),
                gnss_time_s=float(got.gnss_time_s[j]),
                outcome=FixOutcome(int(rep.outcome[j])).name.lower(),
                corrected_jump_m=float(rep.corrected_jump_m[j]),
                calibrated_jump_m=float(rep.calibrated_jump_m[j]),
                learned=bool(rep.learned[j]),
                gated=bool(rep.gated[j]),
                scale_estimate=float(unit.scale_estimate[r]),
                delay_estimate_s=float(unit.delay_estimate_s[r]),
                clock_offset_s=float(got.clock_offset_s[j]),
            )
        )
    return out
