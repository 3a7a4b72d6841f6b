"""SPEC §2 S10-S30 from the track to the trains, as one piece a driver steps: the occupancy chain.

For n trains (a "run" of the arrays is one train's passage):

    track-circuit devices (electrical boundary, detection delay: drawn per train and circuit)
        ─> wayside time-stamping unit (its GNSS clock per circuit; free-running in a shadow)
            ─> telegram (circuit ID, GNSS time) ─> codec (the wire's resolution, a CRC)
                ─> the train radio (``ChainSettings.medium``: one ``link.channel.SimChannel`` per
                   train: latency, jitter, loss, bursts, duplicates, reordering, bit errors)
                    ─> the train, with its own GNSS clock (``onboard_time_s``), which takes each
                       telegram once (a duplicate is dropped) and refuses what the CRC refuses

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

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from railstop.config.media import ChannelParams
from railstop.config.schema import Line
from railstop.errors import SimulationError
from railstop.link.channel import LinkStreams, SimChannel, media_preset
from railstop.link.codec import TelegramError, TrackCircuitOccupancy, decode, encode
from railstop.onboard.positioning import FixOutcome, FixReport, PositioningUnit
from railstop.sensors.gnss_clock import PPM, GnssClock, in_sections, sections_array
from railstop.sensors.track_circuit import OccupancyEvents, TrackCircuitDetector
from railstop.streams import RunStreams, Stream
from railstop.wayside.tc_timestamp import Indication, OccupancyTelegrams, TimestampUnit

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


#: The medium of the occupancy telegrams by default: the train radio of a CBTC line
#: (``railstop/data/media.toml``). [interpretation] SPEC §2 sends them "by radio" and names no
#: medium; the trains' data radio is the one a line has.
OCCUPANCY_MEDIUM = "cbtc-radio"


def occupancy_medium() -> ChannelParams:
    """The default medium of the occupancy telegrams (:data:`OCCUPANCY_MEDIUM`)."""
    return media_preset(OCCUPANCY_MEDIUM)


@dataclass(frozen=True, slots=True, kw_only=True)
class ChainSettings:
    """What a run varies in the chain: GNSS time at all, the repeaters of the line data, the age
    of a clock with no time source (None: the line data's), the radio the telegrams go by."""

    gnss: bool = True  # SPEC §2 GNSS time (False: every clock free-runs)
    repeaters: bool = True  # SPEC §2 satellite-signal repeaters where the line data has them
    holdover_s: float | None = None
    # The telegrams' medium (SPEC §2 "by radio"): the one link model of every simulated link.
    medium: ChannelParams = field(default_factory=occupancy_medium)


@dataclass(frozen=True, slots=True, kw_only=True)
class ChainCounts:
    """What the occupancy telegrams' radio did, over every train (the line summary's
    ``occupancy_link``, in the door link's words: frames, lost, rejected)."""

    frames: int  # sent
    delivered: int  # taken by a train (each telegram once)
    lost: int  # by the medium
    rejected: int  # refused by the codec (its CRC: bits the medium flipped)
    duplicates: int  # copies of a telegram a train already had, dropped


#: The service a line's clocks must hold their time over: a day (a line run lasts at most that).
SERVICE_DAY_S = 86400.0
#: The longest a train's clock stays in a GNSS shadow without a repeater ([interpretation]).
SHADOW_STAY_S = 3600.0


def _no_arrivals() -> Arrivals:
    """No telegram (new, empty arrays)."""
    return Arrivals(
        run=np.empty(0, dtype=np.int64),
        circuit_id=np.empty(0, dtype=np.int64),
        gnss_time_s=np.empty(0, dtype=np.float64),
        clock_offset_s=np.empty(0, dtype=np.float64),
    )


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
        self._shadows = [(t.start_m, t.end_m) for t in shadow]
        self.shadow_array = sections_array(self._shadows)  # the same, for the compiled step
        onboard_disc = np.full(n, cfg.gnss) & ~in_sections(start, self._shadows)
        self.onboard_clock = GnssClock.create(
            clocks, train_streams, clock_index=np.array([0]), disciplined=onboard_disc[:, None]
        )
        c_starts = np.array([c.start_m for c in circuits])
        # The time-stamping unit of a circuit sits at its start: in a shadow it has no GNSS.
        self._wayside_disc = np.full(len(circuits), cfg.gnss) & ~in_sections(c_starts, self._shadows)
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
        # The train radio: one direction (wayside -> train) per train, its draws the counter-based
        # streams of (seed, OCCUPANCY_LINK, the train's run index) (DESIGN rule 7).
        self._links = [
            SimChannel(cfg.medium, LinkStreams.for_link(train_streams.seed, Stream.OCCUPANCY_LINK, int(r)))
            for r in train_streams.run_index
        ]
        self._last_send_s = np.full(n, -np.inf)
        self._next_arrival_s = np.inf  # the earliest frame in flight on any train's radio
        # The stamping clock's error of each frame sent (the records' truth, not on the wire).
        self._stamp_error: list[dict[bytes, float]] = [{} for _ in range(n)]
        self._taken: list[dict[int, float]] = [{} for _ in range(n)]  # circuit -> GNSS time taken
        self._sent = 0
        self._delivered = 0
        self._rejected = 0
        self._duplicates = 0
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
        # SPEC §2 clocks: disciplined unless in a GNSS shadow without a repeater.
        onboard_disc = (
            ~in_sections(np.asarray(x1_m, dtype=np.float64), self._shadows)
            if self.cfg.gnss
            else np.zeros(self.n, dtype=bool)
        )
        self.onboard_clock.advance(dt_s, onboard_disc[:, None])
        # SPEC §2 S10: circuits entered; the device declares them after its delay.
        ev = self.detector.detect(x0_m=x0_m, v0_mps=v0_mps, accel_mps2=accel_mps2, x1_m=x1_m, t0_s=t0_s)
        self.detected(ev, t0_s=t0_s, dt_s=dt_s)

    def detected(self, ev: OccupancyEvents, *, t0_s: float, dt_s: float) -> None:
        """The wayside's part of the step from ``t0_s``: the devices have detected ``ev`` and the
        onboard clocks have moved on (in :meth:`advance`, or compiled in ``nodes.chain_step``)."""
        # The wayside clocks' state never changes (a unit stays where it is): they are advanced
        # only when a unit stamps (``_declare``), by the time since, the same error.
        self._wayside_due_s += dt_s
        if ev.size:
            self._pending.append((ev.run, ev.circuit_index, ev.occupied_time_s))
        self._declare(t0_s + dt_s)

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
                    self._send(tel, tt[tel.source], error[tel.source])
            if (~due).any():
                keep.append((run[~due], idx[~due], t_occ[~due]))
        self._pending = keep

    @property
    def idle(self) -> bool:
        """Nothing under way: no occupancy waiting for its device's delay, no telegram in flight."""
        return not self._pending and all(link.in_flight() == 0 for link in self._links)

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
        in_shadow_s = min(horizon_s, SHADOW_STAY_S) if self._shadows else 0.0
        onboard = c.disciplined_error_s + c.free_run_drift_ppm * PPM * in_shadow_s if self.cfg.gnss else free
        return np.sqrt(wayside * wayside + onboard * onboard)

    def onboard_time_s(self, t_s: float) -> FloatArray:
        """Every train's GNSS clock reading at true time ``t_s`` (n,)."""
        return self.onboard_clock.read(t_s)[:, 0]

    def _send(self, telegrams: OccupancyTelegrams, sent_s: FloatArray, stamp_error_s: FloatArray) -> None:
        """Each telegram as bytes (``railstop.link.codec``, type ``tc-occupancy``) onto its train's
        radio at the occupancy instant (SPEC §2 S20: the unit sends as it stamps)."""
        for j in range(telegrams.size):
            r = int(telegrams.run[j])
            frame = encode(
                TrackCircuitOccupancy(
                    circuit_id=int(telegrams.circuit_id[j]), gnss_time_s=float(telegrams.gnss_time_s[j])
                )
            )
            # A radio takes its frames in order: one declared a hair before the last one sent
            # (the devices' delays differ) leaves with it.
            now = max(float(sent_s[j]), self._last_send_s[r])
            self._last_send_s[r] = now
            self._stamp_error[r][frame] = float(stamp_error_s[j])
            self._sent += 1
            arrival = self._links[r].send(frame, now)
            if arrival is not None:
                self._next_arrival_s = min(self._next_arrival_s, arrival)

    def arrivals(self, t1_s: float) -> Arrivals:
        """The telegrams that have reached their trains by ``t1_s``, decoded from the wire: each
        train takes a telegram once (a duplicate copy is dropped) and what the codec refuses (a
        CRC the medium's bit errors broke) is counted, not taken."""
        if self._next_arrival_s > t1_s:
            return _no_arrivals()  # nothing in flight has arrived yet (most steps)
        runs: list[int] = []
        ids: list[int] = []
        times: list[float] = []
        offsets: list[float] = []
        self._next_arrival_s = np.inf
        for r, link in enumerate(self._links):
            nxt = link.next_arrival_s()
            if nxt is None:
                continue
            if nxt <= t1_s:
                self._take(r, link.receive(t1_s), runs, ids, times, offsets)
                nxt = link.next_arrival_s()
            if nxt is not None:
                self._next_arrival_s = min(self._next_arrival_s, nxt)
        return Arrivals(
            run=np.asarray(runs, dtype=np.int64),
            circuit_id=np.asarray(ids, dtype=np.int64),
            gnss_time_s=np.asarray(times, dtype=np.float64),
            clock_offset_s=np.asarray(offsets, dtype=np.float64),
        )

    def _take(
        self,
        r: int,
        frames: list[bytes],
        runs: list[int],
        ids: list[int],
        times: list[float],
        offsets: list[float],
    ) -> None:
        for frame in frames:
            try:
                msg = decode(frame)
            except TelegramError:
                self._rejected += 1  # bits the medium flipped: the CRC refuses the frame
                continue
            if not isinstance(msg, TrackCircuitOccupancy):  # a flipped type byte with a good CRC
                self._rejected += 1
                continue
            self.used_codec = True
            if self._taken[r].get(msg.circuit_id) == msg.gnss_time_s:
                self._duplicates += 1  # the same occupancy again: no second fix from one telegram
                continue
            self._taken[r][msg.circuit_id] = msg.gnss_time_s
            self._delivered += 1
            runs.append(r)
            ids.append(msg.circuit_id)
            times.append(msg.gnss_time_s)
            offsets.append(self._stamp_error[r].pop(frame, np.nan) - float(self.onboard_clock.error_s[r, 0]))

    @property
    def counts(self) -> ChainCounts:
        """The occupancy telegrams' radio so far, over every train."""
        lost = sum(link.stats.lost for link in self._links)
        return ChainCounts(
            frames=self._sent,
            delivered=self._delivered,
            lost=lost,
            rejected=self._rejected,
            duplicates=self._duplicates,
        )


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
