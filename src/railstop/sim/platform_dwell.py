"""A dwell on a manually driven line (SPEC §3): the stand -> lamps -> doors -> PSD -> departure.

The train stands with its front ``stop_error_m`` from the stopping point (the
driver's last stand, e.g. a ``driver-*`` stop's final error). The driver
wires the real units to a clock and to the people who act on them:

* the stop sensors S2, S1 scan the front (noise, dropouts; ``sensors.stop_sensors``)
  into the platform unit (``wayside.platform.PlatformUnit``), which lights
  the lamp and energises the PSD relay only with OK;
* the driver opens the train doors on the platform side when he sees OK (SPEC
  §3: he opens no doors without it: the PSD would stay closed in front of
  them), keeps them open for the dwell and closes them;
* the CCD camera (``sensors.door_camera``: detection delay, misreads, lost
  frames; "open", "moving", "closed" only when fully shut) shows the doors to
  the PSD control (``wayside.platform.PsdFollower``), which opens the PSD after
  them while the relay is energised and closes it only once the doors have
  been seen shut for long enough to be locked (SPEC §5 order: train doors
  closed and locked, then the PSD); the PSD is faster than the train doors
  (the door data's timings, checked there);
* the platform unit permits departure only with the PSD closed and locked
  (SPEC §3: the PSD is master, the train slave) and then lights S; the driver
  departs when he sees it (at a station without PSD, once his doors are closed
  and locked);
* with the **signal-open switch** on (SPEC §3: a train passing the station)
  no lamp is lit, the PSD stays closed and the driver does not open his doors;
* a lost camera holds the PSD where it is (``PsdFollower``); an open PSD is
  closed by staff at the local panel ``staff_isolation_s`` later (the door
  data's, as for a PSD unit that fails to close in SPEC §5).

Time advances in steps of ``STEP_S``; the sensors scan and the camera takes
frames at their own periods. Nothing reads a clock. The result is a timeline
of ``(t_s, signal, value)`` changes, the same records as ``railstop dwell``'s.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from railstop.config.doors import DoorsConfig
from railstop.config.platform import LAMP_NAMES, PlatformFile, sensor_positions
from railstop.errors import ConfigError, SimulationError
from railstop.messages import (
    DoorCameraFrame,
    PlatformLamps,
    PsdCommand,
    PsdDoorState,
    SignalOpenSwitch,
    StopSensorScan,
)
from railstop.quantities import KMH_PER_MPS
from railstop.sensors.door_camera import classify, true_shape
from railstop.sensors.stop_sensors import sees
from railstop.sim.dwell import DwellEvent
from railstop.streams import Stream, seed_u64
from railstop.wayside.platform import PlatformUnit, PsdFollower

if TYPE_CHECKING:
    from railstop.config.schema import Station
    from railstop.sim.engine import BatchResult
    from railstop.sim.single import StopResult

STEP_S = 0.01
_MAX_T_S = 900.0
#: The signals of the timeline, in the order they are logged at one instant.
SIGNALS: tuple[str, ...] = (
    "moving",
    "signal_open",
    "lamp",
    "psd_relay",
    "driver",
    "train_doors",
    "camera",
    "psd_command",
    "PSD",
    "departure_permitted",
)
OUTCOMES = ("departed", "psd-held", "not-aligned", "staff-closed", "passed")


#: A train running through (signal-open switch) is followed from this far before the stopping point
#: to as far beyond it.
_PASS_FROM_M = 30.0


@dataclass(frozen=True, slots=True, kw_only=True)
class PlatformDwellResult:
    station: str
    stop_error_m: float  # the front from the stopping point at the stand (+ = past it)
    psd: bool  # the station has platform screen doors
    signal_open: bool
    # departed: the doors served the platform and the train left; psd-held: the train doors
    # opened but the PSD never did (the camera was lost); not-aligned: no OK, no doors; staff-closed:
    # a lost camera held the PSD open until staff closed it; passed: the signal-open switch.
    outcome: str
    first_lamp: str | None  # the first lamp lit at the stand
    psd_opened: bool
    doors_open_s: float | None  # the train doors fully open
    departure_s: float | None
    dwell_total_s: float
    camera_frames: int
    camera_misreads: int
    camera_lost_frames: int
    timeline: tuple[DwellEvent, ...]
    passing_kmh: float | None = None  # signal-open switch: the train ran through at this speed

    def summary(self) -> dict[str, Any]:
        return {
            "station": self.station,
            "stop_error_m": self.stop_error_m,
            "psd": self.psd,
            "signal_open": self.signal_open,
            "passing_kmh": self.passing_kmh,
            "outcome": self.outcome,
            "first_lamp": self.first_lamp,
            "psd_opened": self.psd_opened,
            "doors_open_s": self.doors_open_s,
            "departure_s": self.departure_s,
            "dwell_total_s": self.dwell_total_s,
            "camera": {
                "frames": self.camera_frames,
                "misreads": self.camera_misreads,
                "lost_frames": self.camera_lost_frames,
            },
            "timeline": [{"t_s": e.t_s, "signal": e.signal, "value": e.value} for e in self.timeline],
        }


@dataclass(slots=True)
class _Leaves:
    """Door leaves moving between closed (0) and open (1) at their own speeds, then locking."""

    open_s: float
    close_s: float
    lock_s: float
    x: float = 0.0
    target: float = 0.0
    locked_at_s: float | None = 0.0  # when it will be (or was) locked; None while not closed

    def command(self, open_: bool, now_s: float) -> None:
        self.target = 1.0 if open_ else 0.0
        if open_:
            self.locked_at_s = None
        elif self.x == 0.0 and self.locked_at_s is None:
            # Told to close before the leaves had moved: they lock again where they are.
            self.locked_at_s = now_s + self.lock_s

    def step(self, now_s: float, dt: float) -> None:
        # Snapped to the ends within rounding, so that a 3 s motion takes 300 steps of 10 ms.
        if self.target > self.x:
            self.x = self.x + dt / self.open_s
            self.x = 1.0 if self.x > 1.0 - 1e-9 else self.x
        elif self.target < self.x:
            self.x = self.x - dt / self.close_s
            self.x = 0.0 if self.x < 1e-9 else self.x
            if self.x == 0.0:
                self.locked_at_s = now_s + self.lock_s

    def locked(self, now_s: float) -> bool:
        return self.locked_at_s is not None and now_s >= self.locked_at_s - 1e-9

    def state(self, now_s: float) -> str:
        if self.target > self.x:
            return "opening"
        if self.target < self.x:
            return "closing"
        if self.x == 0.0:
            return "closed_locked" if self.locked(now_s) else "closed"
        return "open"


def run_platform_dwell(
    *,
    platform: PlatformFile,
    doors: DoorsConfig,
    station: str,
    stop_error_m: float,
    seed: int = 0,
    counter: int = 0,
    psd: bool = True,
    signal_open: bool = False,
    camera_lost_from_s: float | None = None,
    passing_mps: float | None = None,
) -> PlatformDwellResult:
    """One dwell of a manually driven train standing ``stop_error_m`` from the stopping point.

    ``seed``, ``counter``: the dwell's random generator (sensor noise and dropouts, camera
    misreads and lost frames) is a function of them only (DESIGN rule 7). ``psd``: the station
    has platform screen doors. ``signal_open``: the signal-open switch is on. ``camera_lost_from_s``:
    every camera frame from then on is unreadable (fault injection). ``passing_mps`` (with the
    switch on): the train does not stand but runs through at this speed, its front from
    ``_PASS_FROM_M`` before the stopping point to as far beyond it.
    """
    if not math.isfinite(stop_error_m):
        raise SimulationError(f"stop_error_m: must be a finite number (got {stop_error_m!r})")
    if passing_mps is not None and not (signal_open and math.isfinite(passing_mps) and passing_mps > 0.0):
        raise SimulationError(
            f"passing_mps: a train runs through only with the signal-open switch on, at a speed > 0 "
            f"(got {passing_mps!r})"
        )
    if camera_lost_from_s is not None and not (math.isfinite(camera_lost_from_s) and camera_lost_from_s >= 0):
        raise SimulationError(f"camera_lost_from_s: must be a time >= 0 (got {camera_lost_from_s!r})")
    if platform.camera.lock_confirm_s < doors.timing.train_door_lock_s:
        # SPEC §5 order: the PSD closes after the train doors are locked; the camera cannot see the
        # locks, so its lock confirmation may not be shorter than the doors' lock time.
        raise ConfigError(
            "platform data",
            "camera.lock_confirm_s",
            f"shorter than the train doors' lock time ({doors.source}: timing.train_door_lock_s = "
            f"{doors.timing.train_door_lock_s:g} s)",
            platform.camera.lock_confirm_s,
        )
    rng = np.random.default_rng(
        np.random.SeedSequence([int(seed_u64(seed)), int(Stream.PLATFORM_DWELL), counter])
    )
    run = _PlatformDwell(
        platform=platform,
        doors=doors,
        stop_error_m=stop_error_m,
        rng=rng,
        psd=psd,
        signal_open=signal_open,
        camera_lost_from_s=camera_lost_from_s,
        passing_mps=passing_mps,
    )
    run.run()
    return PlatformDwellResult(
        station=station,
        stop_error_m=stop_error_m,
        psd=psd,
        signal_open=signal_open,
        outcome=run.outcome(),
        first_lamp=run.first_lamp,
        psd_opened=run.psd_opened,
        doors_open_s=run.doors_open_s,
        departure_s=run.departure_s,
        dwell_total_s=round(run.t_s, 3),
        camera_frames=run.frames,
        camera_misreads=run.misreads,
        camera_lost_frames=run.lost_frames,
        timeline=tuple(run.timeline),
        passing_kmh=None if passing_mps is None else round(passing_mps * KMH_PER_MPS, 2),
    )


class _PlatformDwell:
    def __init__(
        self,
        *,
        platform: PlatformFile,
        doors: DoorsConfig,
        stop_error_m: float,
        rng: np.random.Generator,
        psd: bool,
        signal_open: bool,
        camera_lost_from_s: float | None,
        passing_mps: float | None = None,
    ) -> None:
        t = doors.timing
        self.timing = t
        self.sensors = platform.sensors
        self.camera = platform.camera
        self.rng = rng
        self.has_psd = psd
        self.signal_open = signal_open
        self.camera_lost_from_s = camera_lost_from_s
        # The front at the stand, the sensors about the stopping point (chainage 0).
        self.front_m = stop_error_m
        self.s2_m, self.s1_m = sensor_positions(0.0, self.sensors.spacing_m)
        self.unit = PlatformUnit(lamp_table=platform.lamps(), debounce_scans=self.sensors.debounce_scans)
        self.follower = PsdFollower(
            confirm_frames=self.camera.confirm_frames,
            lost_limit_frames=self.camera.lost_limit_frames,
            lock_frames=self.camera.lock_frames,
        )
        self.lamps = PlatformLamps(lamp=None, psd_enable=False, departure_permitted=True)
        self.command = PsdCommand(open=False, camera_ok=True)
        self.doors = _Leaves(t.train_door_open_s, t.train_door_close_s, t.train_door_lock_s)
        self.psd = _Leaves(t.psd_open_s, t.psd_close_s, t.psd_lock_s)
        self.psd_locked = True  # what the PSD last told the platform unit
        self.t_s = 0.0
        self.steps = 0
        self.moving = False
        self.history: list[float] = []  # the train doors' opening, one value per step (the camera's past)
        self.timeline: list[DwellEvent] = []
        self.last: dict[str, int | float | str] = {}
        # What the driver does, and when.
        self.action = "stand"
        self.pending: tuple[float, str] | None = None
        self.first_lamp: str | None = None
        self.psd_opened = False
        self.doors_open_s: float | None = None
        self.departure_s: float | None = None
        self.staff_at_s: float | None = None
        self.staff_closed = False
        self.frames = self.misreads = self.lost_frames = 0
        self.passing_mps = passing_mps
        if passing_mps is not None:
            # SPEC §3 signal-open switch: the train runs through; it never stands.
            self.front_m = -_PASS_FROM_M
            self.moving = True
            self.action = "pass"
            self.departure_s = round(2.0 * _PASS_FROM_M / passing_mps, 3)
        self.scan_every = max(1, round(self.sensors.scan_period_s / STEP_S))
        self.frame_every = max(1, round(self.camera.frame_period_s / STEP_S))
        self.delay_steps = round(self.camera.processing_delay_s / STEP_S)

    # -- the loop -------------------------------------------------------------
    def run(self) -> None:
        if self.signal_open:
            self._deliver_unit(SignalOpenSwitch(on=True))
        self._log()
        while self.departure_s is None or self.t_s < self.departure_s + 2 * self.sensors.scan_period_s:
            if self.t_s > _MAX_T_S:
                raise SimulationError(f"the platform dwell did not end within {_MAX_T_S:g} s")
            self._step()
            self._log()
            self.steps += 1
            self.t_s = round(self.steps * STEP_S, 9)

    def _step(self) -> None:
        now = self.t_s
        if self.passing_mps is not None:
            self.front_m += self.passing_mps * STEP_S
        self.doors.step(now, STEP_S)
        self.psd.step(now, STEP_S)
        self.history.append(self.doors.x)
        if self.steps % self.scan_every == 0:
            self._scan()
        if self.has_psd:
            self._psd_state()
            if self.steps % self.frame_every == 0:
                self._frame()
            self._staff()
        self._driver()

    # -- the wayside ------------------------------------------------------------
    def _deliver_unit(self, message: Any) -> None:
        for out in self.unit.handle(message, self.t_s):
            assert isinstance(out.message, PlatformLamps)
            self.lamps = out.message
            if self.has_psd:
                self._deliver_follower(out.message)

    def _deliver_follower(self, message: Any) -> None:
        for out in self.follower.handle(message, self.t_s):
            assert isinstance(out.message, PsdCommand)
            self.command = out.message
            if self.staff_at_s is None and not out.message.camera_ok and self.psd.x > 0.0:
                # DESIGN rule 10: the PSD is held open; staff come to close it by hand.
                self.staff_at_s = self.t_s + self.timing.staff_isolation_s
            if not self.staff_closed:
                if out.message.open and not self.psd.target:
                    self.psd_opened = True
                self.psd.command(out.message.open, self.t_s)

    def _scan(self) -> None:
        z = self.rng.standard_normal(2)
        u = self.rng.random(2)
        rear = self.front_m - 1000.0  # the train body covers both sensors once its front is past them
        s2 = bool(sees(self.front_m, rear, self.s2_m, z[0], u[0], self.sensors))
        s1 = bool(sees(self.front_m, rear, self.s1_m, z[1], u[1], self.sensors))
        self._deliver_unit(StopSensorScan(s2=s2, s1=s1, standstill=not self.moving))
        if self.first_lamp is None and self.lamps.lamp is not None:
            self.first_lamp = self.lamps.lamp

    def _frame(self) -> None:
        u_lost, u_misread = self.rng.random(2)
        self.frames += 1
        past = self.history[max(0, len(self.history) - 1 - self.delay_steps)]
        lost = self.camera_lost_from_s is not None and self.t_s >= self.camera_lost_from_s
        seen = None if lost else classify(past, float(u_lost), float(u_misread), self.camera)
        if seen is None:
            self.lost_frames += 1
        elif seen != true_shape(past, self.camera):
            self.misreads += 1
        self._deliver_follower(DoorCameraFrame(shape=seen))

    def _psd_state(self) -> None:
        locked = self.psd.locked(self.t_s)
        if locked != self.psd_locked:
            self.psd_locked = locked
            self._deliver_unit(PsdDoorState(closed_locked=locked))

    def _staff(self) -> None:
        if self.staff_at_s is not None and not self.staff_closed and self.t_s >= self.staff_at_s:
            self.staff_closed = True  # the local panel: the PSD closes whatever the control says
            self.psd.command(False, self.t_s)

    # -- the driver -------------------------------------------------------------
    def _departure_permitted(self) -> bool:
        return self.lamps.departure_permitted and self.doors.locked(self.t_s)

    def _driver(self) -> None:
        if self.action == "pass":
            return  # running through: nothing to do at the platform
        t = self.timing
        now = self.t_s
        if self.pending is not None and now >= self.pending[0] - 1e-9:
            _, what = self.pending
            self.pending = None
            self.action = what
            if what == "open doors":
                if self.lamps.lamp == "OK":
                    self.doors.command(True, now)
                else:  # the lamp changed while he reached for the button: he waits for OK again
                    self.action = "stand"
            elif what == "close doors":
                self.doors.command(False, now)
            elif what == "depart":
                if self._departure_permitted():
                    self.moving = True
                    self.departure_s = now
                else:
                    self.action = "wait"
        if self.pending is not None or self.moving:
            return
        if self.action == "stand":
            if self.signal_open:
                # SPEC §3: the train passes the station; no lamp, no doors.
                self.pending = (now + t.driver_action_s, "depart")
            elif self.lamps.lamp == "OK":
                self.pending = (now + t.driver_action_s, "open doors")
            elif now >= t.dwell_s:
                # No OK in a whole dwell (the corrections ran out, a sensor fault): he serves
                # no doors here and departs when permitted.
                self.pending = (now, "depart")
        elif self.action == "open doors" and self.doors.state(now) == "open":
            if self.doors_open_s is None:
                self.doors_open_s = round(now, 3)
            self.pending = (now + t.dwell_s, "close doors")
        elif self.action in ("close doors", "wait") and self._departure_permitted():
            self.pending = (now + t.driver_action_s, "depart")

    # -- the record -------------------------------------------------------------
    def outcome(self) -> str:
        if self.signal_open:
            return "passed"
        if self.staff_closed:
            return "staff-closed"
        if self.doors_open_s is None:
            return "not-aligned"
        if self.has_psd and not self.psd_opened:
            return "psd-held"
        return "departed"

    def _values(self) -> dict[str, int | float | str]:
        now = self.t_s
        values: dict[str, int | float | str] = {
            "moving": int(self.moving),
            "signal_open": int(self.signal_open),
            "lamp": self.lamps.lamp or "-",
            "psd_relay": int(self.lamps.psd_enable),
            "driver": self.action,
            "train_doors": self.doors.state(now),
        }
        if self.has_psd:
            f = self.follower
            # What the PSD control knows of the train doors: "closed_locked" once it counts them so.
            values["camera"] = (
                "lost" if not f.camera_ok() else "closed_locked" if f.doors_locked() else (f.shape or "-")
            )
            values["psd_command"] = "open" if self.command.open else "close"
            values["PSD"] = (
                "closed_locked (staff)" if self.staff_closed and self.psd.locked(now) else self.psd.state(now)
            )
        values["departure_permitted"] = int(self._departure_permitted())
        return values

    def _log(self) -> None:
        values = self._values()
        for name in SIGNALS:
            if name in values and self.last.get(name) != values[name]:
                self.timeline.append(DwellEvent(t_s=round(self.t_s, 3), signal=name, value=values[name]))
                self.last[name] = values[name]


def stand_events(
    batch: BatchResult, *, stop_point_m: float, run: int = 0
) -> tuple[list[DwellEvent], float | None]:
    """SPEC §3 from a driver stop's trace (``run_batch`` with recording): the lamp at each stand
    and where the front stood (``stand_error_m``), on the run's clock; and when the train came to
    its final stand (None: it did not come to rest)."""
    trace = batch.trace
    if trace is None:
        raise SimulationError("the stop was run without a trace")
    final = float(batch.detector_passages_s[run, 0] + batch.stop_time_s[run])
    rows = np.flatnonzero(np.isfinite(trace.t_s[:, run]) & np.isfinite(trace.lamp[:, run]))
    events: list[DwellEvent] = []
    last = 0
    for j in rows:
        lamp = int(trace.lamp[j, run])
        if lamp == last:
            continue
        t = round(float(trace.t_s[j, run]), 3)
        events.append(DwellEvent(t_s=t, signal="lamp", value=LAMP_NAMES.get(lamp, "-")))
        # A lamp lights at a stand and goes dark when the driver moves the train again.
        events.append(DwellEvent(t_s=t, signal="moving", value=int(not lamp)))
        if lamp:
            err = round(float(trace.position_m[j, run]) - stop_point_m, 4)
            events.append(DwellEvent(t_s=t, signal="stand_error_m", value=err))
        last = lamp
    return events, (final if math.isfinite(final) else None)


def driver_stop_timeline(
    batch: BatchResult, dwell: PlatformDwellResult, *, stop_point_m: float, run: int = 0
) -> list[DwellEvent]:
    """The whole lamp and PSD timeline of a driver stop, on the run's clock: the lamps of its
    stands (the F / R corrections), then the dwell from its final stand."""
    events, final = stand_events(batch, stop_point_m=stop_point_m, run=run)
    if final is None:
        return events
    lamp = next((e.value for e in reversed(events) if e.signal == "lamp"), "-")
    out = list(events)
    settled = False
    for e in dwell.timeline:
        if e.signal == "lamp" and not settled:
            # The dwell's platform unit settles on the stand the trace already shows lit: its
            # dark start and a first lamp equal to the stand's are not changes.
            if e.value == "-":
                continue
            settled = True
            if e.value == lamp:
                continue
        out.append(DwellEvent(t_s=round(final + e.t_s, 3), signal=e.signal, value=e.value))
    return out


def dwell_after_stop(
    result: StopResult,
    batch: BatchResult,
    *,
    station: Station,
    platform: PlatformFile,
    doors: DoorsConfig,
    psd: bool = True,
    signal_open: bool = False,
    camera_lost_from_s: float | None = None,
) -> tuple[PlatformDwellResult, list[DwellEvent]]:
    """The dwell at a driver stop's final stand and the stop's whole lamp and PSD timeline (its
    generator: the stop's seed and run, DESIGN rule 7). A run through the station with the
    signal-open switch on (``result.signal_open``) is the platform as the train passes it: the
    timeline is the dwell's own, from the train 30 m before the stopping point."""
    if result.signal_open:
        if result.passed_kmh is None:
            raise SimulationError(f"the run at {station.name} never reached the stopping point")
        dwell = run_platform_dwell(
            platform=platform,
            doors=doors,
            station=station.name,
            stop_error_m=0.0,
            seed=result.seed,
            counter=result.run,
            psd=psd,
            signal_open=True,
            camera_lost_from_s=camera_lost_from_s,
            passing_mps=result.passed_kmh / KMH_PER_MPS,
        )
        return dwell, list(dwell.timeline)
    if not result.stopped:
        raise SimulationError(f"the stop at {station.name} did not come to rest: there is no dwell")
    dwell = run_platform_dwell(
        platform=platform,
        doors=doors,
        station=station.name,
        stop_error_m=result.stop_error_m,
        seed=result.seed,
        counter=result.run,
        psd=psd,
        signal_open=signal_open,
        camera_lost_from_s=camera_lost_from_s,
    )
    return dwell, driver_stop_timeline(batch, dwell, stop_point_m=station.stop_point_m)


_OUTCOME_WORDS = {
    "departed": "the doors served the platform",
    "psd-held": "the train doors opened but the PSD stayed closed (camera lost)",
    "not-aligned": "no OK lamp: the doors stayed closed",
    "staff-closed": "the camera was lost with the PSD open: staff closed it",
    "passed": "signal-open switch: the train passed",
}


def dwell_sentence(d: PlatformDwellResult) -> str:
    """One line on a dwell, as the commands print it."""
    if d.passing_kmh is not None:
        # SPEC §3 signal-open switch: what the platform did while the train ran through.
        lamp = "no lamp lit" if d.first_lamp is None else f"lamp {d.first_lamp} lit"
        psd = "the PSD opened" if d.psd_opened else "PSD closed throughout"
        doors = "train doors inhibited" if d.doors_open_s is None else "train doors opened"
        return (
            f"signal-open switch: the train ran through at {d.passing_kmh:g} km/h, {lamp}, {psd}, {doors}, "
            f"camera {d.camera_frames} frames"
        )
    parts = [f"lamp {d.first_lamp or 'none'} at the stand", _OUTCOME_WORDS[d.outcome]]
    if d.doors_open_s is not None:
        parts.append(f"train doors open {d.doors_open_s:g} s after the stand")
    if d.psd_opened:
        parts.append("PSD opened after them")
    if d.departure_s is not None:
        parts.append(f"departure {d.departure_s:g} s after the stand")
    parts.append(
        f"camera {d.camera_frames} frames, {d.camera_misreads} misread, {d.camera_lost_frames} unreadable"
    )
    return ", ".join(parts)
