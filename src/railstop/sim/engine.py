"""The stop engine's front: controllers, results, and ``run_batch`` over the compiled kernel.

``run_batch`` simulates n stops through :mod:`railstop.model.run` (the one
compiled model, DESIGN rule 1): the detailed stop is n = 1 with recording
on, a campaign block is n = 10^4 with recording off, and each run is the
same machine code whatever block it is in. With recording on, the braking
telegrams of the detailed stop also go through the real byte path: the
codec and the EN 50159 safety layer (:class:`~railstop.link.tasc_link.ByteLink`)
replay every transmission attempt the kernel decided (loss, corruption and
the flipped bit, delay, staleness) and must deliver exactly the telegrams
the kernel delivered, with the same contents; a disagreement is an error.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from railstop.config.driver import DriverFile
from railstop.config.platform import PlatformFile
from railstop.config.scenario import Scenario
from railstop.config.schema import SIM_STEP_S, Station, Track, Vehicle
from railstop.controllers import (
    ATO_CONTROLLERS,
    CONTROLLERS,
    ONBOARD_CONTROLLERS,
    TASC_CONTROLLERS,
    is_onboard,
    known_controllers,
)
from railstop.errors import SimulationError
from railstop.link.codec import Telegram, decode, encode
from railstop.link.tasc_link import (
    ByteLink,
    command_records,
    from_message,
    telegram_of,
    to_message,
)
from railstop.messages import TEL_FIELDS
from railstop.model.build import KernelModel
from railstop.model.gpu import run_on
from railstop.model.records import (
    LA_ARRIVAL,
    LA_CORRUPT,
    LA_FLIP,
    LA_LOST,
    LA_STEP,
    RES_EB,
    RES_EB_T,
    RES_ERROR,
    RES_FILLED,
    RES_FIRST_ERROR,
    RES_ID_DELAY,
    RES_ID_LAG,
    RES_LAMP,
    RES_LEVEL,
    RES_MAX_JERK,
    RES_NOTCH_CHANGES,
    RES_RECEIVED,
    RES_RESTOPS,
    RES_SENT,
    RES_SLID,
    RES_STOP_TIME,
    RES_STOPPED,
    TR_ACCEL,
    TR_ACTION,
    TR_BRAKE,
    TR_DEMAND,
    TR_DUTY,
    TR_LAMP,
    TR_LIMIT,
    TR_NOTCH,
    TR_OWN,
    TR_SLIDE,
    TR_SUPERVISION,
    TR_SWITCH,
    TR_T,
    TR_TARGET,
    TR_V,
    TR_X,
)
from railstop.model.run import KernelRecord
from railstop.streams import RunStreams
from railstop.wayside.tasc_unit import SignalForm, TascTelegrams

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
BoolArray = NDArray[np.bool_]

__all__ = [
    "ATO_CONTROLLERS",
    "CONTROLLERS",
    "ONBOARD_CONTROLLERS",
    "TASC_CONTROLLERS",
    "BatchResult",
    "Trace",
    "run_batch",
]

DT_S = SIM_STEP_S  # the stop model's step (config.schema: the radar samples once a step)
MAX_TIME_S = 150.0


@dataclass(frozen=True, slots=True, kw_only=True)
class Trace:
    """Time series of every run, shape (steps, n)."""

    t_s: FloatArray
    position_m: FloatArray
    speed_mps: FloatArray
    target_decel_mps2: FloatArray  # what the onboard receiver aims at
    demand_decel_mps2: FloatArray  # what the ECU is asked for (notch or duty)
    brake_decel_mps2: FloatArray  # what the brakes give
    accel_mps2: FloatArray  # the train's total acceleration
    notch: IntArray  # step-coded trains (-1 for PWM trains)
    duty: FloatArray  # PWM trains (NaN for step trains)
    # TASC trains: the train's own brake demand (station.tasc.initial_brake_notch; NaN for the
    # ATO controllers) and config 2's changeover switch position (0 the train's command,
    # 1 in transfer, 2 the onboard unit's; -1 without a switching unit).
    own_demand_mps2: FloatArray
    switch: IntArray
    # SPEC §3 driver controllers (NaN otherwise): the held limit / indicated speed (m/s), the
    # driver's action (onboard.driver ACT_*), the supervision (0 quiet, 1 alarm, 2 emergency
    # brake) and the lamp at a stand (config.platform LAMP_CODES; 0 none).
    limit_mps: FloatArray
    driver_action: FloatArray
    supervision: FloatArray
    lamp: FloatArray
    sliding: FloatArray  # 1 where the wheels slide (the WSP acting), else 0


@dataclass(frozen=True, slots=True, kw_only=True)
class BatchResult:
    stop_error_m: FloatArray  # front at rest minus stopping point (+ = overrun)
    stop_time_s: FloatArray  # from the first detector to standstill
    max_jerk_mps3: FloatArray
    notch_changes: IntArray
    commands_sent: IntArray
    commands_received: IntArray
    stopped: BoolArray
    slid: BoolArray
    # DESIGN rule 10: the emergency brake's cause (control.supervision EB_*; 0 none) and when
    # it was applied, from the first detector (NaN: never).
    emergency_brake: IntArray
    emergency_brake_s: FloatArray
    # The brake response the wayside identified from its radar (control.brake_ident): equivalent
    # dead time and build-up lag, NaN where it did not (no radar, no braking step, no fit).
    brake_delay_identified_s: FloatArray
    brake_lag_identified_s: FloatArray
    detectors_filled: IntArray  # passages the wayside filled in from its radar (missed detectors)
    detector_passages_s: FloatArray  # (n, D) true passage times (NaN if never)
    # SPEC §3 driver controllers: the error at the first standstill, the F / R corrections and
    # the lamp at the end (LAMP_CODES; OK: the PSD may operate). The others: the error, 0, 0.
    first_stop_error_m: FloatArray
    restops: IntArray
    lamp: IntArray
    driver_level: IntArray  # the driver's skill level (its index in the driver data; -1: none)
    trace: Trace | None = None
    commands: list[dict[str, Any]] = field(default_factory=list)
    # The detailed stop's braking-telegram frames: sent, delivered and rejected by reason.
    link_frames: dict[str, int] = field(default_factory=dict)


def run_batch(
    *,
    station: Station,
    vehicle: Vehicle,
    scenario: Scenario,
    controller: str,
    streams: RunStreams,
    form: SignalForm | None = None,
    record: bool = False,
    dt_s: float = DT_S,
    max_time_s: float = MAX_TIME_S,
    track: Track | None = None,
    driver: DriverFile | None = None,
    platform: PlatformFile | None = None,
    incapacitated: bool = False,
    signal_open: bool = False,
    device: str = "cpu",
) -> BatchResult:
    """Simulate ``scenario.n`` stops at ``station`` (runs ``streams.run_index``); see the module docstring.

    ``device``: ``cpu``, or ``gpu`` (:mod:`railstop.model.gpu`; no recording there).

    ``track``: the line's track circuits (``ato-corrected`` needs them); ``driver``,
    ``platform``, ``incapacitated``, ``signal_open``: the driver controllers' (``KernelModel.create``).
    """
    if controller not in known_controllers():
        names = ", ".join(known_controllers())
        raise SimulationError(f"unknown controller {controller!r}; choose one of: {names}")
    n = scenario.n
    if streams.n != n:
        raise SimulationError(f"{streams.n} random streams for {n} runs")
    first = int(streams.run_index[0]) if n else 0
    if n and not np.array_equal(streams.run_index, np.arange(first, first + n)):
        raise SimulationError("the kernel simulates consecutive runs")
    model = KernelModel.create(
        station=station,
        vehicle=vehicle,
        controller=controller,
        form=form,
        dt_s=dt_s,
        max_time_s=max_time_s,
        track=track,
        driver=driver,
        platform=platform,
        incapacitated=incapacitated,
        signal_open=signal_open,
    )
    res, passages, rec = run_on(
        device, model, scenario, seed=streams.seed, first_run=first, record=record and n == 1
    )
    trace = None
    commands: list[dict[str, Any]] = []
    frames: dict[str, int] = {}
    if rec is not None:
        trace = _trace(rec.trace)
        commands = command_records(rec.commands, model.form, rec.sends)
        if not is_onboard(controller):
            frames = check_byte_link(rec, station, model.form, dt_s)
    return BatchResult(
        stop_error_m=res[:, RES_ERROR].copy(),
        stop_time_s=res[:, RES_STOP_TIME].copy(),
        max_jerk_mps3=res[:, RES_MAX_JERK].copy(),
        notch_changes=res[:, RES_NOTCH_CHANGES].astype(np.int64),
        commands_sent=res[:, RES_SENT].astype(np.int64),
        commands_received=res[:, RES_RECEIVED].astype(np.int64),
        stopped=res[:, RES_STOPPED] > 0.0,
        slid=res[:, RES_SLID] > 0.0,
        emergency_brake=res[:, RES_EB].astype(np.int64),
        emergency_brake_s=res[:, RES_EB_T].copy(),
        brake_delay_identified_s=res[:, RES_ID_DELAY].copy(),
        brake_lag_identified_s=res[:, RES_ID_LAG].copy(),
        detectors_filled=res[:, RES_FILLED].astype(np.int64),
        detector_passages_s=passages,
        first_stop_error_m=res[:, RES_FIRST_ERROR].copy(),
        restops=res[:, RES_RESTOPS].astype(np.int64),
        lamp=res[:, RES_LAMP].astype(np.int64),
        driver_level=res[:, RES_LEVEL].astype(np.int64),
        trace=trace,
        commands=commands,
        link_frames=frames,
    )


def _trace(tr: FloatArray) -> Trace:
    def col(j: int) -> FloatArray:
        return tr[:, j : j + 1].copy()

    return Trace(
        t_s=col(TR_T),
        position_m=col(TR_X),
        speed_mps=col(TR_V),
        target_decel_mps2=col(TR_TARGET),
        demand_decel_mps2=col(TR_DEMAND),
        brake_decel_mps2=col(TR_BRAKE),
        accel_mps2=col(TR_ACCEL),
        notch=tr[:, TR_NOTCH : TR_NOTCH + 1].astype(np.int64),
        duty=col(TR_DUTY),
        own_demand_mps2=col(TR_OWN),
        switch=np.nan_to_num(tr[:, TR_SWITCH : TR_SWITCH + 1], nan=-1.0).astype(np.int64),
        limit_mps=col(TR_LIMIT),
        driver_action=col(TR_ACTION),
        supervision=col(TR_SUPERVISION),
        lamp=col(TR_LAMP),
        sliding=col(TR_SLIDE),
    )


def check_byte_link(rec: KernelRecord, station: Station, form: SignalForm, dt_s: float) -> dict[str, int]:
    """Replay the kernel's link decisions through the real frames; return the frame counts.

    Every attempt the kernel did not lose is encoded, wrapped in a safety
    frame, bit-flipped when the kernel corrupted it, and handed to the
    safety receiver at its arrival step; the receiver must deliver exactly as
    many frames at each step as the kernel delivered, and every decoded
    telegram must equal the command's message, which is checked to carry the
    kernel's telegram field by field. The run ends at its stop:
    a frame still in the air then is never received (nor checked).
    """
    tasc = station.tasc
    link = ByteLink(category=tasc.safety_category, max_age_s=tasc.max_telegram_age_s)
    sends = {int(c[-1]): i for i, c in enumerate(rec.commands)}
    attempts: dict[int, FloatArray] = {int(a[LA_STEP]): a for a in rec.attempts}
    delivered = Counter(int(k) for k in rec.deliveries)
    last = rec.trace.shape[0] - 1  # the step in which the train came to a stand
    arrival_steps = (int(np.ceil((a[LA_ARRIVAL] - 1e-9) / dt_s)) for a in rec.attempts if not a[LA_LOST])
    arrivals = {k for k in arrival_steps if k <= last}
    message: Telegram | None = None
    payload = b""
    for k in sorted(set(sends) | set(attempts) | set(delivered) | arrivals):
        now = k * dt_s
        if k in sends:
            pending = rec.sends[sends[k]]
            # The command's message, checked once to carry exactly the kernel's telegram: every
            # copy on the air is then checked against the message.
            payload = encode(to_message(telegram_of(pending, form), 0))
            message = decode(payload)  # at the wire's resolution
            _check_fields(from_message(message, form), pending, now)
            link.drop_genuine()
        a = attempts.get(k)
        if a is not None and not a[LA_LOST] and message is not None:
            flip = float(a[LA_FLIP]) if a[LA_CORRUPT] else None
            link.transmit(payload, now, float(a[LA_ARRIVAL]), flip)
        got = link.arrive(now)
        if len(got) != delivered.get(k, 0):
            raise SimulationError(f"t = {now:.2f} s: the byte link and the kernel's link model disagree")
        for msg in got:
            if msg != message:
                raise SimulationError(f"t = {now:.2f} s: decoded {msg}, kernel sent {message}")
    return {"sent": link.frames_sent, **link.receiver.counts}


def _check_fields(got: TascTelegrams, pending: FloatArray, now: float) -> None:
    for j, name in enumerate(TEL_FIELDS):
        value = float(getattr(got, name)[0])
        if not (value == pending[j] or (np.isnan(value) and np.isnan(pending[j]))):
            raise SimulationError(
                f"t = {now:.2f} s: telegram field {name}: decoded {value}, kernel {pending[j]}"
            )
