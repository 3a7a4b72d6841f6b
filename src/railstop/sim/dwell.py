"""A station dwell in simulated time: arrival -> PSC -> open -> dwell -> close -> start enable.

The dwell is the door units by place of ``nodes.dwell`` (the one wiring that the line and the
live processes run too: the train's :class:`~railstop.nodes.dwell.TrainDoors`, the platform's
:class:`~railstop.nodes.dwell.PlatformDoors`), stepped on one clock by
:class:`~railstop.nodes.dwell.DwellRun` every ``DWELL_STEP_S`` (the live plant's step), with
the door link of SPEC §5 between them (:class:`~railstop.link.door_link.DoorLink`: codec +
EN 50159 safety layer + a medium of ``media.toml``, the ``[link]`` section of the door data).
In automatic mode the train's ATC works the doors, in manual mode the driver's door-side
selector and buttons (SPEC §5); the doors move in the door data's times; an obstacle, a PSD
unit that fails to close and the staff who isolate it are the injected faults. So:

* PSC goes high when the WPCS's reply *arrives*: a request whose replies are all lost (or never
  sent: the WPCS answers only a train its stop sensors see in position) times out like a train
  out of position (SPEC §5);
* with PSC high, the train supervises the status frames: none valid for
  ``supervision_timeout_s`` is a lost link, fault and emergency brake ([interpretation], see
  ``onboard/stop_confirm.py``);
* start enable is given when a status frame reports the PSD closed and locked after the
  train's own doors are (SPEC §5 fig. 7);
* the WPCS acts on the train's last ``door-command`` frame (its door signals, its mode, which
  of its doors are closed and locked): the PSD opens and closes on what the link carried.

Nothing here reads a clock: time is a number the driver advances, and the result is a
timeline of ``(t_s, signal, value)`` events, each signal logged when it changes (times on the
step's grid).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from railstop.config.doors import DoorsConfig
from railstop.config.media import ChannelParams
from railstop.control.doors import DoorState, Side, summarise
from railstop.errors import ConfigError, SimulationError
from railstop.link.channel import media_preset
from railstop.link.door_link import DoorLink, DoorLinkCounts
from railstop.nodes.doors import DoorModel
from railstop.nodes.dwell import DWELL_STEP_S, DwellRun, creep_rng, dwell_ends, model_for
from railstop.onboard import cpcs
from railstop.onboard.stop_confirm import StopPhase
from railstop.wayside.wpcs import answers_psc

__all__ = [
    "MODES",
    "SIGNALS",
    "DwellEvent",
    "DwellResult",
    "SteppedDwell",
    "make_door_link",
    "model_for",
    "run_dwell",
]

MODES = ("auto", "manual")
#: A dwell that has neither given start enable nor faulted by then is "stalled" (a result).
MAX_DWELL_S = 3600.0

# The signals of the timeline, in the order they are logged at one instant.
SIGNALS: tuple[str, ...] = (
    "speed_mps",
    "ZVR",
    "stop_error_m",
    "lamp",
    "PSC_request",
    "PSC",
    "creep",
    "DMC-L",
    "DMC-R",
    "DOA-L",
    "DOA-R",
    "DOC",
    "DCC",
    "PSD",
    "train_doors-L",
    "train_doors-R",
    "start_blocked",
    "start_enable",
    "fault",
    "emergency_brake",
    "interlock_error",
    "link",
)


@dataclass(frozen=True, slots=True, kw_only=True)
class DwellEvent:
    t_s: float
    signal: str
    value: int | float | str


@dataclass(frozen=True, slots=True, kw_only=True)
class DwellResult:
    station: str
    platform_side: str
    mode: str
    stop_error_m: float  # where the train first stopped (+ = overrun)
    final_stop_error_m: float  # after the corrections
    tolerance_m: float
    in_tolerance: bool  # the first stop
    psc_attempts: int
    corrections: int
    fault: bool
    emergency_brake: bool
    start_enable_s: float | None
    dwell_total_s: float  # arrival to start enable (or to the fault / the last event)
    outcome: str  # "start-enable" | "fault" | "stalled"
    timeline: tuple[DwellEvent, ...]
    obstruct_door: int | None = None
    psd_fail: int | None = None
    link: DoorLinkCounts | None = None

    def summary(self) -> dict[str, Any]:
        return {
            "station": self.station,
            "platform_side": self.platform_side,
            "mode": self.mode,
            "stop_error_m": self.stop_error_m,
            "final_stop_error_m": self.final_stop_error_m,
            "tolerance_m": self.tolerance_m,
            "in_tolerance": self.in_tolerance,
            "psc_attempts": self.psc_attempts,
            "corrections": self.corrections,
            "fault": self.fault,
            "emergency_brake": self.emergency_brake,
            "start_enable_s": self.start_enable_s,
            "dwell_total_s": self.dwell_total_s,
            "outcome": self.outcome,
            "obstruct_door": self.obstruct_door,
            "psd_fail": self.psd_fail,
            "link": None if self.link is None else self.link.summary(),
            "timeline": [{"t_s": e.t_s, "signal": e.signal, "value": e.value} for e in self.timeline],
        }


def make_door_link(
    doors: DoorsConfig,
    *,
    seed: int = 0,
    train_id: int = 1,
    counter: int = 0,
    loss_probability: float | None = None,
    outage: tuple[float, float] | None = None,
    medium: ChannelParams | None = None,
) -> DoorLink:
    """The door link of the door data's ``[link]`` section for one dwell.

    Its random streams are a function of (seed, stream, train, counter, direction) only
    (DESIGN rule 7): ``counter`` numbers the dwells of one train.
    ``loss_probability`` overrides the medium's per-frame loss (both ways);
    ``outage`` = (start_s, end_s) loses every frame sent in between (fault injection);
    ``medium``: this medium instead of the door data's.
    """
    cfg = doors.link
    try:
        params = media_preset(cfg.medium) if medium is None else medium
    except ConfigError as exc:  # the bad name is in the door data, not in the media file
        raise ConfigError(doors.source, "link.medium", exc.message, cfg.medium) from None
    if loss_probability is not None:
        params = params.replace(loss_probability=loss_probability)
    return DoorLink(
        params=params,
        train_id=train_id,
        seed=seed,
        dwell=counter,
        category=cfg.category,
        max_age_s=cfg.max_age_s,
        timeout_s=cfg.supervision_timeout_s,
        outage=outage,
    )


class SteppedDwell:
    """One dwell from a train that has just stopped ``stop_error_m`` from its stopping point, driven
    by a caller's clock (:meth:`advance_to`, the dwell's time: 0 at the stand; DESIGN rule 1);
    :func:`run_dwell` runs it to its end at once (as the line does, when the train stands).

    ``obstruct_door`` / ``psd_fail``: the train door / PSD unit (1 = front) on the platform side
    that is obstructed while closing (cleared later) / fails to close (isolated by staff later).
    ``link``: the door link to use (its time starts at the stop); default the door data's link
    drawn from ``seed``. ``creep``: where the correction creeps land; default drawn from ``seed``
    (:func:`creep_rng`). A dwell that has not ended by ``MAX_DWELL_S`` is "stalled".
    """

    def __init__(
        self,
        *,
        doors: DoorsConfig,
        station: str,
        platform_side: Side | str,
        stop_error_m: float,
        mode: str = "auto",
        obstruct_door: int | None = None,
        psd_fail: int | None = None,
        model: DoorModel | None = None,
        link: DoorLink | None = None,
        seed: int = 0,
        creep: np.random.Generator | None = None,
    ) -> None:
        if mode not in MODES:
            raise SimulationError(f"mode: must be one of {', '.join(MODES)} (got {mode!r})")
        if not math.isfinite(stop_error_m):
            raise SimulationError(f"stop_error_m: must be a finite number (got {stop_error_m!r})")
        side = Side(platform_side)
        n = doors.doors_per_side
        for name, unit in (("obstruct_door", obstruct_door), ("psd_fail", psd_fail)):
            if unit is not None and not 1 <= unit <= n:
                raise SimulationError(f"{name}: door units are numbered 1..{n} (got {unit})")
        self._doors, self._station, self._side, self._mode = doors, station, side, mode
        self._stop_error_m, self._obstruct_door, self._psd_fail = stop_error_m, obstruct_door, psd_fail
        self.link = link if link is not None else make_door_link(doors, seed=seed)
        self.train, self.platform = dwell_ends(
            doors, station=station, side=side, error_m=stop_error_m, train_id=self.link.train_id,
            manual=mode == "manual", obstruct=obstruct_door, psd_jam=psd_fail, model=model,
            creep=creep if creep is not None else creep_rng(seed, train_id=self.link.train_id),
        )  # fmt: skip
        self.run = DwellRun(self.train, self.platform, self.link, t0_s=0.0, step_s=DWELL_STEP_S)
        self.timeline: list[DwellEvent] = []
        self._last: dict[str, int | float | str] = {}
        self._last_key: tuple[Any, ...] | None = None
        self.end_s = 0.0
        self._log(0.0)

    def advance_to(self, t_s: float) -> bool:
        """Every step of the dwell due by ``t_s`` (0: the stand); whether the dwell has ended."""
        run = self.run
        while not self.ended and run.t_s <= t_s + 1e-9:
            t = run.t_s
            run.step()
            self.end_s = t
            self._log(t)
        return self.ended

    @property
    def ended(self) -> bool:
        """Start enable, the fault, or ``MAX_DWELL_S`` without either (stalled)."""
        return self.train.done or self.run.t_s > MAX_DWELL_S

    @property
    def error_m(self) -> float:
        """Where the train stands now from its stopping point (after the corrections so far)."""
        return self.train.error_m

    def result(self) -> DwellResult:
        """The dwell's result (once it has ended; before, as far as it has come)."""
        train, wp = self.train, self.platform.state
        if train.start_enable_s is not None:
            outcome = "start-enable"
        elif train.fault is not None:
            outcome = "fault"
        else:
            outcome = "stalled"
        tolerance = self._doors.stop_confirm.tolerance_m
        return DwellResult(
            station=self._station,
            platform_side=self._side.value,
            mode=self._mode,
            stop_error_m=self._stop_error_m,
            final_stop_error_m=round(train.error_m, 6),
            tolerance_m=tolerance,
            in_tolerance=answers_psc(self._stop_error_m, tolerance),
            psc_attempts=train.psc_requests,
            corrections=train.corrections,
            fault=train.fault is not None or train.cpcs.fault or wp.fault,
            emergency_brake=train.emergency_brake,
            start_enable_s=None if train.start_enable_s is None else _r(train.start_enable_s),
            dwell_total_s=_r(self.end_s),
            outcome=outcome,
            timeline=tuple(self.timeline),
            obstruct_door=self._obstruct_door,
            psd_fail=self._psd_fail,
            link=self.link.counts,
        )

    # -- the timeline -----------------------------------------------------------------
    def _snapshot(self) -> dict[str, int | float | str]:
        train, wp = self.train, self.platform.state
        s = train.signals
        phase = train.stop.phase
        confirmed = phase == StopPhase.CONFIRMED
        blocked = "-"
        if train.closing and train.start_enable_s is None:
            # What withholds start enable, as an observer who sees both ends sees it.
            bad = [
                b
                for b in cpcs.start_blockers(
                    train.cpcs,
                    wp.report() if confirmed else None,
                    psc=confirmed,
                    emergency_brake=train.emergency_brake,
                    interlocks=train.model.interlocks,
                )
                if b.endswith((DoorState.OBSTRUCTED.value, DoorState.JAMMED.value)) or "fault" in b
            ]
            blocked = "; ".join(bad) if bad else "-"
        if train.link_lost:
            link = "lost"
        elif phase in (StopPhase.PSC_WAIT, StopPhase.CONFIRMED):
            link = "exchange"
        else:
            link = "-"
        creeping = train.creep_left_m > 0.0
        return {
            "speed_mps": round(abs(train.creep_mps), 3),
            "ZVR": int(not train.moving),
            "stop_error_m": round(train.error_m, 3),
            "lamp": train.lamp,
            "PSC_request": train.stop.attempts if phase == StopPhase.PSC_WAIT else 0,
            "PSC": int(confirmed),
            "creep": train.lamp if creeping else "-",
            "DMC-L": int(s.dmc_l),
            "DMC-R": int(s.dmc_r),
            "DOA-L": int(s.doa_l),
            "DOA-R": int(s.doa_r),
            "DOC": int(s.doc),
            "DCC": int(s.dcc),
            "PSD": summarise(wp.units, f"{wp.side.value}"),
            "train_doors-L": summarise(train.cpcs.left, "L"),
            "train_doors-R": summarise(train.cpcs.right, "R"),
            "start_blocked": blocked,
            # Given when a status frame reports the PSD closed and locked (SPEC §5 fig. 7).
            "start_enable": int(train.start_enable_s is not None),
            "fault": int(train.fault is not None or train.cpcs.fault or wp.fault),
            "emergency_brake": int(train.emergency_brake),
            "interlock_error": train.interlock_error or self.platform.interlock_error or "-",
            "link": link,
        }

    def _log(self, t_s: float) -> None:
        train = self.train
        # Most steps change nothing logged: skip the snapshot then.
        key = (
            train.stop,
            train.cpcs,
            train.signals,
            train.lamp,
            train.moving,
            train.creep_left_m > 0.0,
            train.error_m,
            train.closing,
            train.start_enable_s,
            train.fault,
            train.link_lost,
            self.platform.state,
            self.platform.interlock_error,
        )
        if key == self._last_key:
            return
        self._last_key = key
        snap = self._snapshot()
        t = _r(t_s)
        for name in SIGNALS:
            value = snap[name]
            if name not in self._last or self._last[name] != value:
                self.timeline.append(DwellEvent(t_s=t, signal=name, value=value))
                self._last[name] = value


def run_dwell(
    *,
    doors: DoorsConfig,
    station: str,
    platform_side: Side | str,
    stop_error_m: float,
    mode: str = "auto",
    obstruct_door: int | None = None,
    psd_fail: int | None = None,
    model: DoorModel | None = None,
    link: DoorLink | None = None,
    seed: int = 0,
    creep: np.random.Generator | None = None,
) -> DwellResult:
    """Simulate one dwell to its end at once (:class:`SteppedDwell`, its arguments)."""
    dwell = SteppedDwell(
        doors=doors, station=station, platform_side=platform_side, stop_error_m=stop_error_m, mode=mode,
        obstruct_door=obstruct_door, psd_fail=psd_fail, model=model, link=link, seed=seed, creep=creep,
    )  # fmt: skip
    dwell.advance_to(math.inf)
    return dwell.result()


def _r(t_s: float) -> float:
    return round(t_s, 3)
