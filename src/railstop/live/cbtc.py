"""The CBTC line live (issue 17 item 1): the zone controller and the trains as processes over UDP.

Two kinds of process, each a :class:`~railstop.live.clock.WallClock` driving
the same pure units as the line simulation (``wayside.zone_controller``,
``onboard.cbtc``); only the clock and the transport differ:

* **zone controller** (:func:`run_zone_controller`): the SPEC §4 controller.
  Reports arrive as UDP datagrams (``cbtc-report`` codec frames in EN 50159
  category-3 safety frames, a key per train and direction), commands leave
  the same way to the address each train reports from.
* **trains** (:func:`run_trains`): every train's onboard units (one process
  for all trains): the CBTC unit, the ATO's driving as drives to the plant
  (``live.plant``: a process of its own, or in this one), the onboard TASC
  unit and the dwell. A train runs under its authority and its speed limit,
  stops at each station for the dwell, brakes at the emergency rate while
  its unit's emergency brake is applied; at the line's end it starts again
  from the first station once the start of the line is clear.

Both report to the management office (``live.office``): the trains their
state every ``state_period_s`` (position, speed, emergency brake and cause),
the zone controller every change of its protection zones.

Fail safe (DESIGN rule 10): a zone controller process that dies stops
answering; each train's unit counts its missed commands and applies the
emergency brake at the second (SPEC §4). A zone controller answers no train
until every train the operation runs has reported ([interpretation]: it cannot
grant an authority past a train it has not heard from), then serves them all;
a train in emergency brake is released at standstill by a fresh command. It
keeps its state on disk (every change, before the commands that carry it
leave); started again it restores it (a flagged train stays flagged), and
without a usable state it holds every train until the operator releases it.
A trains process started again reports no train before the plant has told it
where the train is.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import os
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from railstop.config.schema import Line, Vehicle
from railstop.control.line_ato import HOLD_BACK_M, LOOKAHEAD_S, profile_at, static_profile
from railstop.control.supervision import EbCause
from railstop.errors import RailstopError
from railstop.link.cbtc_radio import TRAIN_BASE, CbtcEndpoint
from railstop.link.release_link import OPERATOR_ADDRESS, ReleaseGate, release_key
from railstop.link.safety import frame_ids, sum_counts
from railstop.link.udp import Address, UdpEndpoint, local_for, open_endpoint
from railstop.live.clock import TimeBase, WallClock
from railstop.live.drive import HOLD, STOP_SENSOR_SPAN_M, Drive, emergency_drive
from railstop.live.office import OfficeClient
from railstop.messages import OnboardPosition, Output, PositionReport
from railstop.nodes.dwell import DWELL_STEP_S
from railstop.nodes.train import make_onboard_cbtc
from railstop.nodes.zone import make_zone_controller
from railstop.onboard.cbtc import OnboardCbtc, permitted_speed_mps
from railstop.onboard.restricted_mode import RestrictedMode
from railstop.wayside.zone_controller import ZoneController, ZoneMode

# Lazy imports (start-up): live.plant and live.tasc load the compiled model, onboard.tasc_receiver
# the TASC kernel; the functions that drive trains import them, so that the zone controller's
# process (run_zone_controller) starts without them.
if TYPE_CHECKING:  # ground TASC loads the stop kernel: only a trains process with --stations needs it
    from railstop.live.doors import LiveDoors
    from railstop.live.plant import PlantPort, TrainState
    from railstop.live.tasc import FloatArray, LiveTasc, TascOnboard
    from railstop.nodes.dwell import TrainDoors
    from railstop.onboard.cpcs import CpcsState

STEP_S = DWELL_STEP_S  # the plant step (simulated seconds): the dwell's step, one clock (nodes.dwell)


# ---------------------------------------------------------------------- the zone controller


async def run_zone_controller(
    *,
    line: Line,
    vehicle: Vehicle,
    trains: int,
    local: Address,
    base: TimeBase,
    master_key: bytes,
    stop: asyncio.Event,
    office: OfficeClient | None = None,
    on_ready: Callable[[Address], None] | None = None,
    state: Path | None = None,
    new: bool = False,
    note: Callable[[str], None] | None = None,
) -> dict[str, Any]:
    """Serve the trains until ``stop``; return the counts.

    ``state``: the controller's durable state file, written atomically on every change of a
    train's status, zone or furthest authority (before the commands that change it leave) and read
    at the start. ``new``: the operation's start (no train known yet: nothing is read); otherwise a
    restart, restored from ``state`` or, without a usable one, with every train unknown and held
    (:func:`restore_zone_controller`). ``note``: told, once the controller is ready, how it
    started (one line)."""
    # Only the operation's trains are peers, only reports are taken, and nothing sent before this
    # process started is delivered (EN 50159 repetition across a restart of the controller).
    radio = CbtcEndpoint.zone_controller(master_key, trains=trains, started_s=base.now_s())
    zc = make_zone_controller(line, vehicle, ZoneMode.MINIMAL)
    zc.downlink = radio.name
    started = restore_zone_controller(zc, state, new=new, trains=trains, now_s=base.now_s())
    store = StateFile(state) if state is not None else None
    # The operator's link keeps Unix time: releases sent before this process started are refused.
    gate = ReleaseGate(key=release_key(master_key), not_before_s=time.time())
    clock = WallClock([zc, radio], step_s=STEP_S, base=base)
    addresses: dict[int, Address] = {}
    heard: set[int] = set()
    zones_seen: dict[int, tuple[float, float, str]] = {}
    if office is not None:
        # The zones the start set (a restore loses every tracked train) go to the office at once:
        # on a loaded host the first reports may re-detect a train, and release its zone, before
        # the first step compares zones with what the office was told.
        _report_zones(zc, zones_seen, office, base.now_s())
    held = 0
    unsaved = 0  # commands not sent because the state they change could not be saved
    saved_key: object = None
    async with await open_endpoint(local) as ep:
        if on_ready is not None:
            on_ready(ep.local_address)
        if note is not None:
            note(started["note"])

        def poll(now_s: float) -> list[Output]:
            out: list[Output] = []
            while (got := ep.take()) is not None:
                frame, addr = got
                if (frame_ids(frame) or (-1, -1))[0] == OPERATOR_ADDRESS:
                    # SPEC §4 step 5: the operator's release, only through the authenticated link
                    # (its timestamps are Unix time, the control room's clock).
                    release = gate.accept(frame, time.time())
                    if release is not None:
                        out.append(Output(to=zc.name, message=release))
                    continue
                for m in radio.ingest(frame, now_s, to=lambda _k: zc.name):
                    if not isinstance(m.message, PositionReport):
                        # DESIGN rule 9: refused and counted, never an assert (which a key holder's
                        # command frame would trip, and which ``python -O`` removes).
                        radio.links.reject("unexpected-type")
                        continue
                    addresses[m.message.train_id] = addr
                    heard.add(m.message.train_id)
                    out.append(m)
            return out

        def plant(now_s: float, step_s: float) -> list[Output]:
            nonlocal held, unsaved, saved_key
            # Durable before it acts: a change of a train's status, zone or furthest authority is
            # on disk before the commands that carry it leave (a restart then knows every
            # authority given). A state that cannot be saved sends no command (the trains brake on
            # their missed commands, SPEC §4) and leaves no stale file behind (DESIGN rule 10).
            key = _state_key(zc)
            saved = store is None or key == saved_key
            if not saved and store is not None:
                saved = store.save(zc.state_bytes(now_s))
                saved_key = key if saved else None
            # Fail safe: no command leaves before every train of the operation has reported.
            ready = len(heard) >= trains
            for frame, peer in radio.outgoing:
                addr = addresses.get(peer - TRAIN_BASE)
                if not ready:
                    held += 1
                elif not saved:
                    unsaved += 1
                elif addr is not None:
                    ep.send(frame, addr)
            radio.outgoing.clear()
            if office is not None:
                _report_zones(zc, zones_seen, office, now_s)
            return []

        await clock.run_live(plant, poll, stop)
    c = zc.counts
    return {
        "reports": c.reports,
        "commands": c.commands,
        "lost_trains": c.lost,
        "auto_releases": c.auto_releases,
        "flagged": c.flagged,
        "commands_held_at_start": held,
        **clock.timing(),
        "radio": {"delivered": radio.links.delivered, "rejected": radio.links.rejected},
        "manual_releases": c.manual_releases,
        "releases_refused": gate.rejected,
        "state": {
            "started": started["how"],
            "restored_trains": started["trains"],
            "writes": 0 if store is None else store.writes,
            "write_errors": 0 if store is None else store.errors,
            "commands_not_sent_unsaved": unsaved,
        },
        "released_by": gate.released_by,  # operator id -> releases (the telegrams name the operator)
    }


def restore_zone_controller(
    zc: ZoneController, path: Path | None, *, new: bool, trains: int, now_s: float
) -> dict[str, Any]:
    """How a zone controller process starts: ``new`` (the operation's start: no train known yet, as
    the first reports make them known), or a restart from the durable state at ``path``
    (``ZoneController.restore_state``: every tracked train lost with its SPEC §4 zone, a flagged
    one kept flagged), or, with no usable state (no path, no file, unreadable, damaged, another
    version), every train of the operation unknown: flagged and held at authority 0 until an
    operator releases it (``ZoneController.restore_unknown``, [interpretation], DESIGN rule 10).
    Returns {how, trains, note}: ``note`` says it in one line."""
    if new:
        return {"how": "new", "trains": 0, "note": "zone controller: a new operation (no train known yet)"}
    why = "no state file given (--state)"
    if path is not None:
        try:
            n = zc.restore_state(path.read_bytes())
        except OSError as exc:
            why = f"{path}: {exc.strerror or exc}"
        except RailstopError as exc:
            why = str(exc)
        else:
            return {
                "how": "restored",
                "trains": n,
                "note": f"zone controller: restored {n} train(s) from {path}; each tracked one lost "
                "until its next report re-detects it (SPEC §4)",
            }
    zc.restore_unknown(range(trains), now_s)
    return {
        "how": "unknown",
        "trains": 0,
        "note": f"zone controller: no usable state ({why}): every train is unknown, held at authority 0 "
        "until an operator releases it after visual confirmation",
    }


def _state_key(zc: ZoneController) -> tuple[object, ...]:
    """What the durable state must follow: every train's status, zone and furthest authority end,
    and the trains that left."""
    rows = tuple((k, t.status, t.zone, t.furthest_end) for k, t in sorted(zc.trains.items()))
    return rows, tuple(sorted(zc.left))


class StateFile:
    """A file replaced atomically: the new contents go to a temporary file beside it, which is
    flushed to the disk (fsync) and renamed over the old one (the directory fsynced too), so that
    a process killed at any instant leaves the old contents or the new, never a mixture."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.writes = 0
        self.errors = 0

    def save(self, data: bytes) -> bool:
        """Whether ``data`` is on disk; on a failure the old file is removed (a stale state must
        not be restored as if it were current) and False returned."""
        tmp = self.path.with_name(self.path.name + ".tmp")
        try:
            with open(tmp, "wb") as f:
                f.write(data)
                f.flush()
                os.fsync(f.fileno())
            os.replace(tmp, self.path)
            fd = os.open(self.path.parent, os.O_RDONLY)
            try:
                os.fsync(fd)
            finally:
                os.close(fd)
        except OSError:
            self.errors += 1
            with contextlib.suppress(OSError):
                self.path.unlink()
            return False
        self.writes += 1
        return True


def _report_zones(
    zc: ZoneController, seen: dict[int, tuple[float, float, str]], office: OfficeClient, now_s: float
) -> None:
    now = {z.train_id: (z.start_m, z.end_m, zc.trains[z.train_id].status.value) for z in zc.zones()}
    for train, (a, b, status) in now.items():
        if seen.get(train) != (a, b, status):
            office.report(
                "zone-event",
                {"train": train, "start_m": a, "end_m": b, "active": True, "status": status,
                 "t_s": round(now_s, 2)},
            )  # fmt: skip
    for train in [t for t in seen if t not in now]:
        a, b, _ = seen[train]
        office.report(
            "zone-event", {"train": train, "start_m": a, "end_m": b, "active": False, "t_s": round(now_s, 2)}
        )
    seen.clear()
    seen.update(now)


# ---------------------------------------------------------------------- the trains


@dataclass
class _TrainState:
    k: int
    unit: OnboardCbtc
    x_m: float  # where the plant says the train is
    restricted: RestrictedMode  # its driver's restricted mode while its radio is dead (SPEC §4)
    v_mps: float = 0.0
    next_station: int = 0
    dwell_until_s: float = -math.inf
    last_state_s: float = -math.inf
    eb_reported: bool = False
    stopped_at: int | None = None  # the station it has just stopped at (reported once)
    tasc: TascOnboard | None = None  # the station stop under ground TASC in progress
    visits: int = 0  # station stops begun (the disturbance draw of each)
    arrived: tuple[int, float] | None = None  # stopped at a platform (station, error): its dwell begins
    dwell: TrainDoors | None = None  # the dwell over the door link in progress
    retry: tuple[int, float, CpcsState] | None = None  # after a dwell fault: the dwell to begin again
    relocating: float | None = None  # sent back into service there; until the plant says it is
    localised: bool = False  # this process has the plant's state of the train (see ``_localise``)


class _Trains:
    """The trains process's state and its two callbacks on the wall clock (``poll``: the frames
    received; ``step``: each plant step). Built by :func:`run_trains`."""

    def __init__(
        self,
        *,
        line: Line,
        vehicle: Vehicle,
        trains: int,
        spacing_m: float,
        base: TimeBase,
        master_key: bytes,
        dwell_s: float,
        office: OfficeClient | None,
        state_period_s: float,
        outage: set[int] | None,
        tasc: LiveTasc | None,
        doors: LiveDoors | None,
        plant: Address | None,
    ) -> None:
        from railstop.live.plant import Plant, PlantPort, TascPlantData, initial_positions  # lazy

        self.line, self.vehicle, self.dwell_s, self.office = line, vehicle, dwell_s, office
        self.state_period_s, self.tasc, self.doors = state_period_s, tasc, doors
        self.dead = outage if outage is not None else set()
        self.order = sorted(range(len(line.stations)), key=lambda i: line.stations[i].stop_point_m)
        self.stations = [line.stations[i].stop_point_m for i in self.order]
        end_m = line.end_m
        # Each train talks to the zone controller with its own safety-layer id.
        # Each train hears only the zone controller, takes only commands, and refuses what was sent
        # before this process started (a restarted process never re-delivers a command).
        started_s = base.now_s()
        self.radios = {
            k: CbtcEndpoint.train(k, master_key, name=f"radio-{k}", started_s=started_s)
            for k in range(trains)
        }
        self.fleet: list[_TrainState] = []
        for k, x in enumerate(initial_positions(line, vehicle, trains, spacing_m)):
            # Silent until localised: its first position (from the plant) starts its reports.
            unit = make_onboard_cbtc(line, vehicle, k, uplink=self.radios[k].name)
            ahead = next((i for i, st in enumerate(self.stations) if st > x + 1.0), len(self.stations))
            restricted = RestrictedMode(brake_mps2=vehicle.brake.full_service_mps2)
            self.fleet.append(_TrainState(k=k, unit=unit, x_m=x, restricted=restricted, next_station=ahead))
        self.unlocalised_steps = 0  # train-steps held under emergency brake, waiting for the plant's state
        self.local: Plant | None = None
        if plant is None:
            plant_tasc = None
            if tasc is not None:
                plant_tasc = TascPlantData(tasc.models[0].model.controller, tasc.dist, tasc.seed)
            self.local = Plant(
                line=line, vehicle=vehicle, trains=trains, spacing_m=spacing_m, master_key=master_key,
                tasc=plant_tasc,
            )  # fmt: skip
        self.port = PlantPort(
            trains, plant=self.local, address=plant, master_key=master_key, onboard=self.onboard,
            started_s=started_s,
        )  # fmt: skip
        self.profile = static_profile(line, end_m, vehicle.brake.full_service_mps2 * 0.8)
        self.clock = WallClock(
            [*(t.unit for t in self.fleet), *self.radios.values()], step_s=STEP_S, base=base
        )
        self.ebs: dict[str, int] = {}
        self.eb_times: list[dict[str, Any]] = []  # each emergency brake applied: train, time, cause
        self.misdirected = 0  # frames for no train of this process
        self.cut_short = 0  # TASC stops cut short by a plant started again
        self.sensors_to = tasc.address if tasc is not None else (doors.address if doors is not None else None)
        self.ep: UdpEndpoint | None = None  # the socket to the zone controller (run_trains opens it)
        self.zc: Address | None = None

    def onboard(self, train: int, t_s: float, sense: Any) -> Any:
        """The onboard TASC unit's cycle on the train's sensing (the CBTC unit's brake on wire e). A
        train this process has not localised is under a stop it did not begin (the plant's, from
        before this process started): its brakes get the emergency brake (DESIGN rule 10)."""
        if not self.fleet[train].localised:
            from railstop.live.tasc import BrakeDrive  # lazy (start-up), see the top

            return BrakeDrive(sense.k, self.vehicle.brake.emergency_decel_mps2, True, True)
        tasc = self.tasc
        return None if tasc is None else tasc.cycle(train, t_s, sense, self.fleet[train].unit.emergency_brake)

    def poll(self, now_s: float) -> list[Output]:
        """The frames received since the last poll: PSD status, braking telegrams, commands."""
        assert self.ep is not None
        out: list[Output] = []
        doors, tasc = self.doors, self.tasc
        while (got := self.ep.take()) is not None:
            frame, _ = got
            if doors is not None and doors.accepts(frame):
                doors.ingest(frame, now_s)  # a PSD status from a platform's WPCS
                continue
            if tasc is not None and tasc.accepts(frame):
                tasc.ingest(frame, now_s)  # a braking telegram from a station
                continue
            dst = (frame_ids(frame) or (-1, -1))[1]
            r = self.radios.get(dst - TRAIN_BASE)
            if r is None:
                self.misdirected += 1
                continue
            if dst - TRAIN_BASE in self.dead:
                continue  # the train's radio is dead: lost
            out.extend(r.ingest(frame, now_s, to=lambda k: f"cbtc-{k}"))
        return out

    def step(self, now_s: float, step_s: float) -> list[Output]:
        """One plant step: the radios' frames out, the plant's step, every train's drive and
        reports; the onboard positions for the CBTC units."""

        ep, zc, port, tasc = self.ep, self.zc, self.port, self.tasc
        assert ep is not None and zc is not None
        out: list[Output] = []
        for k, r in self.radios.items():
            for frame, _ in r.outgoing:
                if k not in self.dead:
                    ep.send(frame, zc)
            r.outgoing.clear()
        port.tick(now_s, step_s, ep, self.sensors_to)  # in this process: the plant's steps
        if tasc is not None:
            for frame in tasc.hello(now_s):
                ep.send(frame, tasc.address)
        for t in self.fleet:
            state = port.states.get(t.k)
            if not t.localised and not _localise(t, state, self.stations):
                # No report (to the zone controller, to the office) nor drive before the plant
                # says where the train is: it stays under the emergency brake (a restarted
                # process's start is not the train's position; DESIGN rule 10).
                self.unlocalised_steps += 1
                port.drive(t.k, emergency_drive(self.vehicle))
                continue
            drive = self._drive(t, state, now_s, step_s)
            if drive is not None:
                port.drive(t.k, drive)
                if math.isfinite(drive.relocate_m):
                    t.relocating, t.x_m, t.v_mps = drive.relocate_m, drive.relocate_m, 0.0
            u = t.unit.params.position_uncertainty_m  # the plant's position: the declared bound
            out.append(
                Output(
                    to=t.unit.name,
                    message=OnboardPosition(position_m=t.x_m, speed_mps=t.v_mps, uncertainty_m=u),
                )
            )
            self._report(t, now_s)
        port.flush(now_s)  # between processes: the drives to the plant
        return out

    def _drive(self, t: _TrainState, state: TrainState | None, now_s: float, step_s: float) -> Drive | None:
        """The train's drive this step (None: the plant goes on as it is), after taking the
        plant's state of it."""

        port, tasc, doors = self.port, self.tasc, self.doors
        fresh = state is not None and state.fresh
        if state is None or fresh:
            pass  # a plant that does not know where the train is: placed below
        elif t.relocating is None:
            t.x_m, t.v_mps = state.x_m, state.v_mps
        elif abs(state.x_m - t.relocating) < 1.0:
            t.relocating = None  # the plant has it back in service
        if fresh:
            # A plant that knows nothing of the trains (its start, or its start again in the
            # running line): each train stands where this process last knew it (they
            # were braked when the plant fell silent) [interpretation: the simulated world
            # resumes from the onboard units' view]. A TASC stop under way is cut short:
            # the train stands EB_RESET_S, then is driven onto the platform.
            if t.tasc is not None and tasc is not None:
                tasc.end(t.k)
                t.tasc = None
                t.dwell_until_s = now_s + EB_RESET_S
                self.cut_short += 1
            port.place(t.k, t.x_m)
            t.v_mps = 0.0
            return None
        if port.lost:
            return emergency_drive(self.vehicle)  # fail safe: the plant is silent, nothing is known
        if t.relocating is not None:
            return Drive(0.0, 0.0, math.inf, t.relocating)  # sent again until the plant has it
        if doors is not None:
            assert self.ep is not None
            drive = _dwell_step(t, doors, self.ep, now_s, step_s, self.office)
            if drive is not None:
                return drive  # standing at the platform for its dwell (or creeping to correct its stop)
        if tasc is not None and _tasc_step(t, tasc, port, now_s, self.order, self.dwell_s, self.office):
            return None  # the onboard TASC unit drives it (in lock step with the plant)
        drive = _move(
            t, now_s, step_s, self.vehicle, self.stations, self.dwell_s, self.fleet, t.k in self.dead, tasc,
            self.order, self.profile,
        )  # fmt: skip
        if t.stopped_at is not None:
            t.arrived = (self.order[t.stopped_at], t.x_m - self.stations[t.stopped_at])
        return drive

    def _report(self, t: _TrainState, now_s: float) -> None:
        """The train's emergency brake counted once applied; its stop and state to the office."""
        office, port = self.office, self.port
        eb_now = t.unit.emergency_brake or port.lost
        if eb_now and not t.eb_reported:
            # The unit's own emergency brake names its cause; else it is the plant's silence.
            own = t.unit.eb_cause
            cause = (own if own is not None else EbCause.PLANT_LOST).label
            self.ebs[cause] = self.ebs.get(cause, 0) + 1
            self.eb_times.append({"train": t.k, "t_s": round(now_s, 3), "cause": cause})
        t.eb_reported = eb_now
        if t.stopped_at is not None and office is not None:
            st = self.line.stations[self.order[t.stopped_at]]
            office.report(
                "stop-result",
                {
                    "station": st.name,
                    "train": t.k,
                    # Not a TASC stop: the live plant is a point mass stopping where it aims.
                    "controller": "live plant",
                    "error_m": round(t.x_m - st.stop_point_m, 3),
                    "within": abs(t.x_m - st.stop_point_m) <= st.psd_tolerance_m,
                    "t_s": round(now_s, 2),
                },
            )
        t.stopped_at = None
        if office is not None and now_s - t.last_state_s >= self.state_period_s:
            t.last_state_s = now_s
            state_report = {
                "train": t.k,
                "position_m": round(t.x_m, 1),
                "speed_mps": round(t.v_mps, 2),
                # The CBTC unit's emergency brake, or the dwell's (SPEC §5 fault) while the
                # train stands for its reset, or the plant's silence.
                "emergency_brake": eb_now or t.retry is not None,
                "cause": _state_cause(t.unit.eb_cause, port.lost, t.retry is not None),
                "radio": "dead" if t.k in self.dead else "ok",
                "doors": None if t.dwell is None else t.dwell.phase,
                "t_s": round(now_s, 2),
            }
            office.report("train-state", state_report)

    def counts(self) -> dict[str, Any]:
        """What :func:`run_trains` returns: emergency brakes by cause, timing, link and plant counts."""
        tasc, doors, local = self.tasc, self.doors, self.local
        return {
            "emergency_brakes": self.ebs,
            "emergency_brake_times": self.eb_times,
            **self.clock.timing(),
            "commands": sum(t.unit.commands for t in self.fleet),
            "radio_delivered": sum(r.links.delivered for r in self.radios.values()),
            "radio_rejected": _rejected(self.radios.values(), self.misdirected),
            "tasc": None if tasc is None else tasc.counts(),
            "dwells": None if doors is None else doors.counts(),
            "plant": {
                **self.port.counts(),
                **(local.counts() if local is not None else {}),
                "tasc_stops_cut_short": self.cut_short,
                "unlocalised_train_steps": self.unlocalised_steps,
            },
        }


async def run_trains(
    *,
    line: Line,
    vehicle: Vehicle,
    trains: int,
    spacing_m: float,
    zc: Address,
    base: TimeBase,
    master_key: bytes,
    stop: asyncio.Event,
    dwell_s: float = 20.0,
    office: OfficeClient | None = None,
    state_period_s: float = 1.0,
    outage: set[int] | None = None,
    tasc: LiveTasc | None = None,
    doors: LiveDoors | None = None,
    plant: Address | None = None,
) -> dict[str, Any]:
    """Run every train until ``stop``; return the counts (emergency brakes by cause, ...).

    ``outage``: the trains whose radio is dead now (fault injection; the caller may change the set
    while the trains run): every frame to or from them is lost. ``tasc``: the stations process
    (``live.tasc.run_stations``) stops the trains by ground TASC (without it the plant stops them
    where they aim, a point mass). ``plant``: the plant process (``live.plant.run_plant``) that
    moves the trains; without it the plant runs in this process."""
    run = _Trains(
        line=line, vehicle=vehicle, trains=trains, spacing_m=spacing_m, base=base, master_key=master_key,
        dwell_s=dwell_s, office=office, state_period_s=state_period_s, outage=outage, tasc=tasc,
        doors=doors, plant=plant,
    )  # fmt: skip
    async with contextlib.AsyncExitStack() as stack:
        run.ep = await stack.enter_async_context(await open_endpoint(local_for(zc)))
        run.zc = zc
        if plant is not None:
            port = run.port
            port.ep = await stack.enter_async_context(await open_endpoint(local_for(plant)))
            port.heard_s = base.now_s()  # its first frames have a period of grace
            serving = asyncio.create_task(port.serve(base, stop))
            stack.callback(serving.cancel)
        await run.clock.run_live(run.step, run.poll, stop)
    return run.counts()


def _localise(t: _TrainState, state: TrainState | None, stations: list[float]) -> bool:
    """Whether the train is localised now: this process (started, or started again in a running
    line) takes the plant's state of the train before it reports or drives it. A plant that knows
    nothing of the trains (``fresh``: it started with this process) is told where they are (the
    configured start); a plant that knows them gives the train's position, once it stands (under
    the emergency brake until then: this process has no authority for it, and its onboard unit
    would find it over its authority) and no ground-TASC stop is under way for it (one begun
    before this process started: it ends under the emergency brake first). Re-localised, the
    train's next station is the first whose stopping point it has not passed by more than the
    stop sensors' span (a train standing at a platform does its dwell there again: this process
    does not know whether it was done). [interpretation] SPEC §2 keeps the position in the train;
    here the trains' process holds no memory of it, and the plant stands for the train's own
    sensors."""

    if state is None:
        return False
    if not state.fresh:
        if state.sense is not None or state.v_mps != 0.0:
            return False
        t.x_m, t.v_mps = state.x_m, state.v_mps
        span = STOP_SENSOR_SPAN_M
        t.next_station = next((i for i, st in enumerate(stations) if st > t.x_m - span), len(stations))
    t.localised = True
    return True


def _rejected(radios: Iterable[CbtcEndpoint], misdirected: int) -> dict[str, int]:
    """The frames the trains' radios refused, by reason, summed over the trains."""
    out: dict[str, int] = {"wrong_destination": misdirected} if misdirected else {}
    return sum_counts((r.links.rejected for r in radios), into=out)


def _move(
    t: _TrainState,
    now_s: float,
    step_s: float,
    vehicle: Vehicle,
    stations: list[float],
    dwell_s: float,
    fleet: list[_TrainState],
    radio_dead: bool = False,
    tasc: LiveTasc | None = None,
    order: list[int] | None = None,
    profile: FloatArray | None = None,
) -> Drive:
    """The driving the ATO does under the onboard unit's limits, as the drive to the plant. With
    ground TASC it runs at the station's entry speed to the hand-over point, where the stop is
    taken over (``_tasc_step``); short of an authority there, it stops where it aims."""

    unit = t.unit
    brake = vehicle.brake
    # Back into service 200 m before the first station; with ground TASC, 150 m before its
    # hand-over point (so that its stop is a TASC stop).
    reentry = stations[0] - 200.0
    if tasc is not None and order is not None:
        reentry = min(reentry, tasc.handover_m(order[0], tasc.entry_mps(order[0])) - 150.0)
    turn = _turn(t, now_s, stations, fleet, reentry)
    if turn is not None:
        return turn
    # SPEC §4, restricted mode (onboard.restricted_mode, the line's lost trains too): with the radio
    # dead its driver moves the train on sight, 150 m behind the train ahead's rear.
    ahead = min((o.x_m - vehicle.length_m for o in fleet if o.x_m > t.x_m), default=math.inf)
    restricted = t.restricted.step(
        now_s=now_s, step_s=step_s, position_m=t.x_m, speed_mps=t.v_mps, radio_dead=radio_dead,
        emergency_brake=unit.emergency_brake, ahead_m=ahead,
    )  # fmt: skip
    if restricted is not None:
        return Drive(restricted.target_mps, restricted.accel_mps2, restricted.decel_mps2)
    if unit.emergency_brake:
        return emergency_drive(vehicle)
    if now_s < t.dwell_until_s:
        return HOLD
    # The line's static profile (civil limits, each approached on a braking curve), read here
    # and LOOKAHEAD_S ahead as the line simulation's ATO reads it: the zone controller's
    # command carries only the limit where the train is.
    target = unit.permitted_mps()
    if profile is not None:
        ahead = t.x_m + t.v_mps * LOOKAHEAD_S
        target = min(target, profile_at(profile, t.x_m), profile_at(profile, ahead))
    permitted = target
    if t.next_station < len(stations):
        to_stop = stations[t.next_station] - t.x_m
        plan = brake.full_service_mps2 * 0.8
        to_handover, entry, waiting = -1.0, 0.0, False
        if tasc is not None and order is not None:
            station = order[t.next_station]
            entry = tasc.entry_mps(station)
            to_handover = tasc.handover_m(station, entry) - t.x_m
            if unit.distance_to_end_m() < to_stop:
                # The platform is not free (the authority ends short of the stopping point): wait
                # HOLD_BACK_M before the hand-over point, as the line simulation's trains do.
                to_handover -= HOLD_BACK_M
                entry, waiting = 0.0, True
        if to_handover > 0.0:
            # The station's entry speed at the hand-over point (SPEC §1: the TASC zone's speed).
            target = min(target, math.sqrt(entry * entry + 2.0 * plan * to_handover))
        elif waiting and to_handover > -HOLD_BACK_M:
            target = 0.0  # waiting for the platform
        else:
            target = min(target, permitted_speed_mps(max(to_stop, 0.0), plan, 0.5))
        if to_stop <= 0.05 and t.v_mps < 0.3:
            t.dwell_until_s = now_s + dwell_s
            t.stopped_at = t.next_station
            t.next_station += 1
            return HOLD
    creep = t.next_station < len(stations) and stations[t.next_station] - t.x_m > 0.05 and target > 0.0
    target = max(0.0, target - 0.3)
    if creep:
        target = max(target, min(0.2, permitted))  # the last centimetres: creep, do not stall
    max_accel = vehicle.traction.max_accel_mps2 if vehicle.traction is not None else 1.0
    return Drive(target, max_accel, brake.full_service_mps2)


def _tasc_step(
    t: _TrainState,
    tasc: LiveTasc,
    port: PlantPort,
    now_s: float,
    order: list[int],
    dwell_s: float,
    office: OfficeClient | None,
) -> bool:
    """Ground TASC drives the train from the station's hand-over point to standstill (SPEC §1):
    the stop starts there once the train's CBTC authority reaches the stopping point; the plant
    sends its readings to the station, the station's telegrams come to the train's onboard unit,
    whose drive the plant follows in lock step. Returns whether the stop holds the train."""
    if t.tasc is None:
        if (
            t.next_station >= len(order)
            or now_s < t.dwell_until_s
            or t.unit.emergency_brake
            or t.x_m < tasc.handover_m(order[t.next_station], t.v_mps)
            or t.x_m >= tasc.models[order[t.next_station]].first_detector_m  # inside the zone already
            or t.unit.distance_to_end_m() < tasc.models[order[t.next_station]].station.stop_point_m - t.x_m
        ):
            return False
        t.tasc = tasc.begin(t.k, order[t.next_station])
        port.ended.pop(t.k, None)
        port.begin_tasc(t.k, order[t.next_station], t.visits)
        t.visits += 1
        return True
    ended = port.ended.pop(t.k, None)
    if ended is None:
        return True
    from railstop.live.tasc import stop_result  # lazy (start-up), see the top
    from railstop.onboard.tasc_receiver import RX_EB_T  # lazy (start-up), see the top

    onboard = t.tasc
    tasc.end(t.k)
    t.tasc = None
    st = onboard.st
    t.x_m, t.v_mps = ended.x_m, 0.0
    error = ended.x_m - st.station.stop_point_m
    cause = onboard.eb_cause()
    eb_t = float(onboard.rx[RX_EB_T])
    result = stop_result(
        st, t.k, error, True, ended.jerk_mps3, ended.stop_time_s, cause, eb_t, onboard.extra_eb
    )
    result["t_s"] = round(now_s, 2)
    if result["emergency_brake"] is not None and error < -st.station.psd_tolerance_m:
        # [interpretation] Short of the platform after an emergency brake: the train stands
        # EB_RESET_S (the brake is reset at standstill), then is driven onto the platform under
        # the plant's control (its stop reported as a point-mass stop); SPEC §1 says nothing
        # of the recovery. Past the platform it dwells where it stands.
        t.dwell_until_s = now_s + EB_RESET_S
    else:
        t.dwell_until_s = now_s + dwell_s
        t.next_station += 1
        t.arrived = (st.index, error)
    tasc.results.append(result)
    if office is not None:
        office.report("stop-result", result)
    return True


def _dwell_step(
    t: _TrainState,
    doors: LiveDoors,
    ep: UdpEndpoint,
    now_s: float,
    step_s: float,
    office: OfficeClient | None,
) -> Drive | None:
    """The dwell over the door link (SPEC §5, ``live.doors``): begun when the train stops at a
    platform; it holds the train (or creeps it to correct its stop) until start enable. After the
    SPEC §5 fault (no PSC after the last attempt, or the link lost with PSC high: emergency
    brake) the train stands ``DWELL_FAULT_HOLD_S``, then its confirmation begins again
    [interpretation]: staff reset the ATC; SPEC §5 says nothing of the recovery. Returns the
    drive that holds (or creeps) the train, None when no dwell holds it."""

    carried = None
    if t.retry is not None and now_s >= t.dwell_until_s:
        station, error_m, carried = t.retry
        t.arrived, t.retry = (station, error_m), None
    if t.arrived is not None:
        station, error_m = t.arrived
        t.arrived = None
        t.dwell = doors.begin(t.k, station, error_m, now_s, carried)
        t.dwell_until_s = math.inf
    dwell = t.dwell
    if dwell is None:
        return HOLD if t.retry is not None else None  # waiting for the reset after a fault
    frames = doors.advance(dwell, now_s, step_s)
    for frame in frames:
        ep.send(frame, doors.address)
    creep = dwell.creep_mps
    if dwell.done:
        t.dwell = None
        result = {**dwell.result(), "t_s": round(now_s, 2)}
        if dwell.fault is None:
            t.dwell_until_s = now_s  # start enable: it departs
        else:
            t.dwell_until_s = now_s + DWELL_FAULT_HOLD_S
            t.retry = (dwell.station, dwell.error_m, dwell.cpcs)  # its doors stay as they are
        if office is not None:
            office.report("dwell-result", result)
    # The correction creep (SPEC §5) at its speed, at once (the point-mass plant); else standing.
    return Drive(creep, math.inf, math.inf) if creep != 0.0 else HOLD


def _state_cause(unit_cause: EbCause | None, plant_lost: bool, dwell_fault: bool) -> str | None:
    """A train state's ``cause``: its CBTC unit's emergency brake, else the plant's silence, else
    the dwell's fault (the train stands for its reset); None: no emergency brake."""
    if unit_cause is not None:
        return unit_cause.label
    if plant_lost:
        return EbCause.PLANT_LOST.label
    return EbCause.DWELL_FAULT.label if dwell_fault else None


DWELL_FAULT_HOLD_S = 60.0  # after a dwell's fault, the train stands this long before it tries again
EB_RESET_S = 10.0  # after a TASC emergency stop short of the platform, the train stands this long


def _turn(
    t: _TrainState, now_s: float, stations: list[float], fleet: list[_TrainState], reentry_m: float
) -> Drive | None:
    """After its dwell at the last station a train leaves service there and comes back into service
    at ``reentry_m`` once that stretch is clear (the line has one direction): the drive that
    relocates it, or holds it until then; None before its last station's dwell has ended."""

    if t.next_station < len(stations) or now_s < t.dwell_until_s or t.unit.emergency_brake:
        return None
    if all(o is t or not (reentry_m - 400.0 < o.x_m < stations[0] + 200.0) for o in fleet):
        t.next_station = 0
        return Drive(0.0, 0.0, math.inf, reentry_m)
    return HOLD
