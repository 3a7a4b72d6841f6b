"""The station dwell live (SPEC §5): the door units of ``nodes.dwell`` at the two ends of the door
link as frames. The trains process holds each train's :class:`~railstop.nodes.dwell.TrainDoors`
(:class:`LiveDoors`), the stations process every station's
:class:`~railstop.nodes.dwell.PlatformDoors` (:class:`Platforms`); between them ``door-command``
and ``psd-status`` telegrams through the codec and the EN 50159 safety layer (category 3: UDP is
an open network), and the platform's stop-sensor readings from the plant."""

from __future__ import annotations

import struct
import time
from typing import Any

from railstop.config.doors import DoorsConfig
from railstop.config.schema import Line
from railstop.control.doors import Side
from railstop.link.codec import DoorCommand, PsdStatus, TelegramError, decode, encode
from railstop.link.endpoint import Endpoint
from railstop.link.release_link import WCC_ADDRESS, WccGate, wcc_key
from railstop.link.safety import SafePeers, frame_ids, sum_counts
from railstop.link.udp import Address
from railstop.nodes.dwell import PlatformDoors, TrainDoors, creep_rng, model_for
from railstop.onboard.cpcs import CpcsState

SENSORS_ID = 0x0280  # the trackside sensors (the plant that reads them); as live.tasc's

PLATFORM_BASE = 0x0200  # station i's WPCS: PLATFORM_BASE + i (as door_link's PLATFORM_ID for station 0)
TRAIN_DOORS_BASE = 0x4800  # train k's door end (ATC / CPCS): TRAIN_DOORS_BASE + k
#: A stop-sensor reading on the platform's wiring: train, station, the train's stop error (NaN: no
#: train standing in the platform).
_STOP_SENSED = struct.Struct(">H H d")
MAX_TRAINS = 60  # the most trains a live trains process runs (``railstop live trains --trains``)


def pack_stop_sensed(train: int, station: int, error_m: float) -> bytes:
    return _STOP_SENSED.pack(train, station, error_m)


def unpack_stop_sensed(payload: bytes) -> tuple[int, int, float]:
    """(train, station, error_m); ValueError for a payload of the wrong shape."""
    if len(payload) != _STOP_SENSED.size:
        raise ValueError("stop-sensor frame of the wrong length")
    train, station, error_m = _STOP_SENSED.unpack(payload)
    return train, station, error_m


# ---------------------------------------------------------------------- the processes' ends


class LiveDoors:
    """The trains process's side of the door link: each train's dwell (:meth:`begin` at
    standstill, :meth:`advance` each plant step), its ``door-command`` frames out, the
    ``psd-status`` frames in (category 3: UDP is an open network). The platform's stop sensors
    are read by the plant (``live.plant``)."""

    def __init__(
        self,
        *,
        line: Line,
        doors: DoorsConfig,
        stations: Address,
        master_key: bytes,
        manual: bool = False,
        trains: int = MAX_TRAINS,
        started_s: float | None = None,
        seed: int = 0,
    ) -> None:
        """``manual``: the trains' doors are worked by their drivers (SPEC §5 manual column).
        ``trains``: the trains of this process (0 .. trains - 1): a frame for any other is refused
        before any link state exists. ``started_s``: when this process started on the run's
        clock; statuses sent before it are refused (``old_session``). ``seed``: where the
        correction creeps land (``nodes.dwell.creep_rng``, per train and dwell)."""
        if not 1 <= trains <= MAX_TRAINS:
            raise ValueError(f"trains: 1..{MAX_TRAINS} (got {trains})")
        self.trains = trains
        self.started_s = started_s
        self.not_mine = 0  # frames for a train that is not one of this process's (refused)
        self.manual = manual
        self.seed = seed
        self.dwells_begun: dict[int, int] = {}  # train -> dwells begun (the creep generator's counter)
        self.obstructions: dict[int, int] = {}  # fault injection: train -> door (0 = front), next dwell
        self.line = line
        self.doors = doors
        # Each station's door data (its PSD tolerance), checked before any train runs.
        self._at = [doors.at_station(st, "the line file") for st in line.stations]
        self.model = model_for(doors)
        self.address = stations
        self.master_key = master_key
        n = len(line.stations)
        self._is_platform = lambda p: PLATFORM_BASE <= p < PLATFORM_BASE + n
        self._links: dict[int, Endpoint] = {}
        self.active: dict[int, TrainDoors] = {}
        self.results: list[dict[str, Any]] = []
        self.unexpected = 0

    def _link(self, train: int) -> Endpoint:
        """Train ``train``'s end of the door link (one of this process's trains: the callers
        check); it takes ``psd-status`` telegrams only."""
        if train not in self._links:
            self._links[train] = Endpoint(
                TRAIN_DOORS_BASE + train,
                master_key=self.master_key,
                max_age_s=self.doors.link.max_age_s,
                peers=self._is_platform,
                started_s=self.started_s,
                expects=(PsdStatus,),
            )
        return self._links[train]

    def accepts(self, frame: bytes) -> bool:
        ids = frame_ids(frame)
        return ids is not None and self._is_platform(ids[0])

    def ingest(self, frame: bytes, now_s: float) -> None:
        ids = frame_ids(frame)
        if ids is None:
            return
        train = ids[1] - TRAIN_DOORS_BASE
        if not 0 <= train < self.trains:
            # A destination that is no train of this process: refused before any link is made
            # for it (a forged header must not make the process hold state; DESIGN rule 9).
            self.not_mine += 1
            return
        got = self._link(train).receive(frame, now_s)
        if got is None:
            return  # refused by the safety layer, the codec or its type: counted by the end
        dwell = self.active.get(train)
        status = got[1]
        if dwell is None or not isinstance(status, PsdStatus) or got[0] - PLATFORM_BASE != dwell.station:
            self.unexpected += 1  # no dwell here, or a status from another platform
            return
        dwell.receive(status, now_s)

    def begin(
        self, train: int, station: int, error_m: float, now_s: float, carried: CpcsState | None = None
    ) -> TrainDoors:
        """A train's dwell from its standstill at ``now_s``; ``carried``: its doors as an earlier
        dwell here left them (after that dwell's fault)."""
        st = self.line.stations[station]
        k = self.dwells_begun.get(train, 0)
        self.dwells_begun[train] = k + 1
        dwell = TrainDoors(
            train=train,
            station=station,
            station_name=st.name,
            side=Side(st.platform_side),
            error_m=error_m,
            doors=self._at[station],  # the station's PSD tolerance
            model=self.model,
            t0_s=now_s,
            carried=carried,
            manual=self.manual,
            obstruct=self.obstructions.pop(train, None),
            creep_rng=creep_rng(self.seed, train_id=train, counter=k),
        )
        self.active[train] = dwell
        return dwell

    def advance(self, dwell: TrainDoors, now_s: float, step_s: float) -> list[bytes]:
        """One step of a dwell (its correction creep reaches the plant as the train's drive,
        ``TrainDoors.creep_mps``): the frames to send to the stations process."""
        dwell.step(now_s, step_s)
        platform = PLATFORM_BASE + dwell.station
        end = self._link(dwell.train)
        frames = [f for cmd in dwell.due if (f := end.frame(cmd, platform, now_s)) is not None]
        dwell.due.clear()
        if dwell.done:
            self.active.pop(dwell.train, None)
            self.results.append(dwell.result())
        return frames

    def counts(self) -> dict[str, Any]:
        refused = sum_counts(lk.rejected for lk in self._links.values())
        if self.not_mine:
            refused["not_a_train_here"] = refused.get("not_a_train_here", 0) + self.not_mine
        outcomes = sum_counts({r["outcome"]: 1} for r in self.results)
        dwells = [r["dwell_s"] for r in self.results if r["dwell_s"] is not None]
        return {
            "dwells": len(self.results),
            "outcomes": outcomes,
            "corrections": sum(r["corrections"] for r in self.results),
            "dwell_s_max": max(dwells) if dwells else None,
            "status_frames": sum(lk.delivered for lk in self._links.values()),
            "command_frames": sum(lk.sent for lk in self._links.values()),
            "refused": refused,
            "unexpected": self.unexpected,
        }


class Platforms:
    """The stations process's side of the door link: every station's :class:`PlatformDoors`, the
    stop-sensor and ``door-command`` frames in, the ``psd-status`` frames out, the WCC's commands
    through their gate (``link.release_link.WccGate``)."""

    def __init__(
        self,
        *,
        line: Line,
        doors: DoorsConfig,
        master_key: bytes,
        jams: tuple[tuple[int, int], ...] = (),
        started_s: float | None = None,
    ) -> None:
        """``jams``: fault injection, (station, PSD unit from 0) that fail to close on their next
        closing. ``started_s``: when this process started on the run's clock; frames sent before
        it are refused (``old_session``)."""
        model = model_for(doors)
        self.units = [
            PlatformDoors(
                index=i,
                name=st.name,
                side=Side(st.platform_side),
                doors=doors.at_station(st, "the line file"),  # the station's PSD tolerance
                model=model,
            )
            for i, st in enumerate(line.stations)
        ]
        for station, unit in jams:
            self.units[station].jam(unit)
        n = len(self.units)
        self.links = {
            i: SafePeers(
                PLATFORM_BASE + i,
                master_key,
                max_age_s=doors.link.max_age_s,
                peers=lambda p: p == SENSORS_ID or TRAIN_DOORS_BASE <= p < TRAIN_DOORS_BASE + 0x400,
                started_s=started_s,
            )
            for i in range(n)
        }
        # The WCC link keeps Unix time: commands sent before this process started are refused.
        self.gate = WccGate(key=wcc_key(master_key), not_before_s=None if started_s is None else time.time())
        self.refused: dict[str, int] = {}

    def owns(self, dst: int) -> bool:
        return dst == WCC_ADDRESS or dst - PLATFORM_BASE in self.links

    def _refuse(self, reason: str) -> None:
        self.refused[reason] = self.refused.get(reason, 0) + 1

    def ingest(self, frame: bytes, dst: int, now_s: float, unix_s: float | None = None) -> int | None:
        """A frame for a platform (or the WCC input); the train it came from, if any. ``unix_s``:
        the time on the operator link's clock (the control room keeps Unix time, whatever the run's
        time scale; default ``now_s``)."""
        if dst == WCC_ADDRESS:
            wcc = self.gate.accept(frame, now_s if unix_s is None else unix_s)
            if wcc is not None:
                if wcc.station >= len(self.units):
                    self._refuse("wcc_unknown_station")
                else:
                    self.units[wcc.station].wcc(
                        manual=wcc.manual, panel_open=wcc.panel_open, panel_close=wcc.panel_close, now_s=now_s
                    )
            return None
        i = dst - PLATFORM_BASE
        got = self.links[i].accept(frame, now_s)
        if got is None:
            return None
        peer, delivered = got
        if peer == SENSORS_ID:
            try:
                train, station, error_m = unpack_stop_sensed(delivered.payload)
            except ValueError:
                self._refuse("bad_stop_sensor")
                return None
            if station != i:
                self._refuse("wrong_station")
                return None
            self.units[i].sense(train, error_m, now_s)
            return None  # from the trackside, not from the train
        try:
            cmd = decode(delivered.payload)
        except TelegramError as exc:
            self._refuse(f"codec-{exc.reason}")
            return None
        train = peer - TRAIN_DOORS_BASE
        if not isinstance(cmd, DoorCommand) or cmd.train_id != train:
            self._refuse("unexpected")
            return None
        self.units[i].receive(cmd, now_s)
        return train

    def tick(self, now_s: float) -> list[tuple[int, bytes]]:
        """Every WPCS's cycle; the (train, frame) to send."""
        out = []
        for u in self.units:
            u.tick(now_s)
            for train, status in u.due:
                out.append((train, self.links[u.index].wrap(encode(status), TRAIN_DOORS_BASE + train, now_s)))
            u.due.clear()
        return out

    def delivered(self) -> int:
        """Frames the platforms' links delivered (stop sensors and door commands)."""
        return sum(lk.delivered for lk in self.links.values())

    def take_events(self) -> list[dict[str, Any]]:
        out = [e for u in self.units for e in u.events]
        for u in self.units:
            u.events.clear()
        return sorted(out, key=lambda e: e["t_s"])

    def counts(self) -> dict[str, Any]:
        totals = sum_counts(u.counts for u in self.units)
        refused = sum_counts((lk.rejected for lk in self.links.values()), into=dict(self.refused))
        sum_counts([self.gate.rejected], into=refused, prefix="wcc-")
        return {**totals, "wcc_commands": self.gate.accepted, "refused": refused}
