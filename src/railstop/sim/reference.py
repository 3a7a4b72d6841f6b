"""The array (numpy) engine that the compiled kernel replaces (``railstop.sim.kernel``).

Kept for two uses only, both temporary: the ``ato-corrected`` baseline,
whose SPEC §2 positioning is not yet in the kernel, and the tests that prove
the kernel reproduces this engine bit for bit. Nothing else may call it.

``run_batch`` simulates n stops in lockstep, every 10 ms (the Doppler sample
period of SPEC §1), through the same physics, sensors, wayside unit, link and
onboard receiver for every driver: the single detailed stop is n = 1 with
recording on, a campaign chunk is n = 10^4 with recording off.

One step at time t:
    sensors (Doppler sample at t; passages found during the last step)
    -> wayside TASC unit -> radio link (latency, loss) -> onboard receiver
    -> brake signal -> ECU (load compensation) -> actuator (dead time, jerk
    limit, lag) -> train dynamics t -> t + dt -> wheel sensors.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from railstop.config.schema import Station, Track, Vehicle
from railstop.controllers import ATO_CORRECTED
from railstop.errors import RailstopError, SimulationError
from railstop.link.channel import (
    ChannelParams,
    corruption_probability,
    delivery_delay_s,
    media_preset,
)
from railstop.onboard.ato import AtoController
from railstop.onboard.tasc_receiver import OnboardConfig, TascReceiver
from railstop.physics.brake import (
    ActuatorState,
    actuator_step,
    braking_decel_mps2,
    decode_step,
    ecu_demand_mps2,
)
from railstop.physics.train import (
    MotionState,
    TrainMass,
    motion_step,
    odometer_increment_m,
    tachometer_speed_mps,
)
from railstop.sensors.wayside import WheelSensors, doppler_sample
from railstop.sim.corrected_position import TrackCircuitFixes
from railstop.sim.engine import ATO_CONTROLLERS, CONTROLLERS, DT_S, MAX_TIME_S, BatchResult, Trace
from railstop.sim.scenario import Scenario
from railstop.sim.tasc_link import ByteLink, frame_bytes, quantize_telegrams
from railstop.streams import RunStreams, Stream
from railstop.wayside.tasc_unit import GroundTascUnit, SignalForm, TascTelegrams

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
BoolArray = NDArray[np.bool_]


@dataclass(slots=True)
class _Link:
    """The braking-telegram link (SPEC §1 RF, SPEC §5 media) with one pending telegram per run.

    The wayside repeats its latest telegram every ``repeat_s`` (cyclic
    transmission, as train radio links do); the receiver discards repeats of
    a telegram it already has, so a repeat only matters when every earlier
    copy failed. A newer telegram replaces the one not yet delivered: it
    carries newer measurements, and the wayside sends only its latest.

    Each attempt of run r, counter c = its attempt number, is decided by the
    run's streams (the same numbers in every driver):

    * lost: uniform(RADIO_LOSS, c) < radio_loss_probability;
    * corrupted: uniform(RADIO_CORRUPT, 2c) < 1 − (1 − BER)^(8 · frame bytes)
      (``channel.corruption_probability``): the safety layer rejects it;
    * delay: ``channel.delivery_delay_s`` of the station's medium (poll-cycle
      wait from uniform(RADIO_CYCLE, c), airtime of the safety frame,
      latency + jitter · normal(RADIO_LATENCY, c));
    * stale: older than ``max_telegram_age_s`` when the step that receives it
      comes (the safety layer's check, in its millisecond arithmetic).

    A failed attempt (lost, corrupted or stale) is repeated ``repeat_s``
    later. With ``bytes_link`` (the detailed stop, n = 1) every attempt that
    is not lost is a real frame: encoded, wrapped, bit-flipped when corrupted,
    and checked and decoded by the safety receiver on arrival.
    """

    pending: TascTelegrams | None
    due_s: FloatArray  # delivery time of the pending telegram (inf: none in flight)
    next_try_s: FloatArray  # next transmission attempt of an undelivered telegram
    count: IntArray  # attempts so far (the streams' counter)
    repeat_s: float
    medium: ChannelParams
    frame_bytes: int
    max_age_s: float
    dt_s: float
    bytes_link: ByteLink | None = None

    @classmethod
    def create(cls, n: int, station: Station, form: SignalForm, dt_s: float, *, as_bytes: bool) -> _Link:
        tasc = station.tasc
        try:
            medium = media_preset(tasc.medium)
        except RailstopError as exc:
            raise SimulationError(f"station {station.name}: tasc.medium: {exc}") from None
        return cls(
            pending=None,
            due_s=np.full(n, np.inf),
            next_try_s=np.full(n, np.inf),
            count=np.zeros(n, dtype=np.int64),
            repeat_s=tasc.repeat_period_s,
            medium=medium,
            frame_bytes=frame_bytes(form, tasc.safety_category),
            max_age_s=tasc.max_telegram_age_s,
            dt_s=dt_s,
            bytes_link=ByteLink(category=tasc.safety_category, max_age_s=tasc.max_telegram_age_s)
            if as_bytes
            else None,
        )

    def send(self, tele: TascTelegrams) -> None:
        """A new telegram for the runs of ``tele.mask``: it goes on the air at the next attempt."""
        go = tele.mask
        if self.pending is None:
            self.pending = tele
        else:
            for name in TascTelegrams.__dataclass_fields__:
                if name == "form":
                    continue
                old = getattr(self.pending, name)
                if name == "mask":
                    setattr(self.pending, name, old | go)
                else:
                    setattr(self.pending, name, np.where(go, getattr(tele, name), old))
        if self.bytes_link is not None and go[0]:
            self.bytes_link.drop_genuine()
        self.due_s = np.where(go, np.inf, self.due_s)
        self.next_try_s = np.where(go, -np.inf, self.next_try_s)

    def transmit(self, now_s: float, scenario: Scenario, streams: RunStreams) -> None:
        """Transmission attempts due now; a copy that gets through arrives after its delay."""
        rows = np.flatnonzero(self.next_try_s <= now_s + 1e-9)
        if rows.size == 0:
            return
        sub = streams.subset(rows)
        c = self.count[rows]
        self.count[rows] += 1
        lost = sub.uniform(Stream.RADIO_LOSS, c) < scenario.radio_loss_probability[rows]
        corrupt = np.zeros(rows.size, dtype=bool)
        ber = scenario.radio_bit_error_rate[rows]
        if np.any(ber > 0.0):
            p = corruption_probability(self.medium, self.frame_bytes, bit_error_rate=ber)
            corrupt = ~lost & (sub.uniform(Stream.RADIO_CORRUPT, 2 * c) < p)
        u = sub.uniform(Stream.RADIO_CYCLE, c) if self.medium.cycle_s > 0.0 else 0.0
        jitter = scenario.radio_jitter_s[rows]
        z = sub.normal(Stream.RADIO_LATENCY, c) if np.any(jitter > 0.0) else 0.0
        delay = delivery_delay_s(
            self.medium, self.frame_bytes, u, z, latency_s=scenario.radio_latency_s[rows], jitter_s=jitter
        )
        arrival = now_s + np.asarray(delay)
        # The step that receives the frame, and the safety layer's age check there.
        receive_s = np.ceil((arrival - 1e-9) / self.dt_s) * self.dt_s
        age_ms = np.round(receive_s * 1000.0) - round(now_s * 1000.0)
        stale = age_ms > self.max_age_s * 1000.0
        ok = ~lost & ~corrupt & ~stale
        self.due_s[rows[ok]] = arrival[ok]
        self.next_try_s[rows[ok]] = np.inf
        self.next_try_s[rows[~ok]] = now_s + self.repeat_s
        if self.bytes_link is not None and self.pending is not None and not lost[0]:
            flip = float(sub.uniform(Stream.RADIO_CORRUPT, 2 * c + 1)[0]) if corrupt[0] else None
            self.bytes_link.transmit(self.pending, now_s, float(arrival[0]), flip)

    def deliver(self, now_s: float) -> tuple[BoolArray, TascTelegrams | None]:
        """Runs whose telegram arrives now, and what they receive."""
        due = self.due_s <= now_s + 1e-9
        self.due_s = np.where(due, np.inf, self.due_s)
        if self.bytes_link is None or self.pending is None:
            return due, self.pending
        got = self.bytes_link.arrive(now_s, self.pending.form)
        if bool(due[0]) != (got is not None):
            raise SimulationError(f"t = {now_s:.2f} s: the byte link and the link model disagree")
        return due, got


def run_batch_reference(
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
) -> BatchResult:
    """Simulate ``scenario.n`` TASC stops at ``station``; see the module docstring."""
    if controller not in CONTROLLERS:
        raise SimulationError(f"unknown controller {controller!r}; choose one of: {', '.join(CONTROLLERS)}")
    n = scenario.n
    if streams.n != n:
        raise SimulationError(f"{streams.n} random streams for {n} runs")
    is_ato = controller in ATO_CONTROLLERS
    form = SignalForm(station.tasc.signal_form if form is None else form)
    if station.tasc.doppler is not None and abs(station.tasc.doppler.sample_period_s - dt_s) > 1e-12:
        raise SimulationError(
            f"station {station.name}: tasc.doppler.sample_period_s = "
            f"{station.tasc.doppler.sample_period_s} must equal the simulation step {dt_s} s"
        )
    brake = vehicle.brake
    mass = TrainMass.create(vehicle, scenario.load_factor, scenario.load_weighing_error)
    det_pos = np.asarray(station.detector_positions_m(), dtype=np.float64)
    start_m = det_pos[0] - np.maximum(20.0, scenario.entry_speed_mps * 1.5)
    motion = MotionState(
        position_m=start_m.copy(),
        speed_mps=scenario.entry_speed_mps.copy(),
        accel_mps2=np.zeros(n),
        stopped=np.zeros(n, dtype=bool),
        stop_time_s=np.full(n, np.nan),
        sliding=np.zeros(n, dtype=bool),
    )
    sensors = WheelSensors.create(det_pos, scenario.sensor_jitter_s, scenario.sensor_miss_probability)
    # Exact, never-missing detectors at the same places: the true passages,
    # for the stop time and the plots.
    truth = WheelSensors.create(det_pos, np.zeros(n), np.zeros(n))
    passages = np.full((n, det_pos.size), np.nan)
    unit = GroundTascUnit(
        station=station,
        vehicle=vehicle,
        gradient=scenario.gradient,
        n=n,
        dt_s=dt_s,
        form=form,
        record=record,
    )
    # The odometer assumes the actual diameter with its error (Scenario: assumed = actual × (1 + error)).
    assumed_diam = scenario.wheel_diameter_m * (1.0 + scenario.odometer_diameter_error)
    tach_scale = assumed_diam / scenario.wheel_diameter_m
    receiver: TascReceiver | AtoController
    fixes: TrackCircuitFixes | None = None
    if is_ato:
        receiver = AtoController(station=station, vehicle=vehicle, gradient=scenario.gradient, n=n, dt_s=dt_s)
        transponders = WheelSensors.create(receiver.transponders_m, np.zeros(n), np.zeros(n))
        if controller == ATO_CORRECTED:
            # No transponders: the position comes from SPEC §2 track-circuit corrections.
            fixes = TrackCircuitFixes.create(
                track=track,
                vehicle=vehicle,
                streams=streams,
                start_m=start_m,
                speed_mps=scenario.entry_speed_mps,
                tach_scale=tach_scale,
                dt_s=dt_s,
            )
            receiver.fix(np.arange(n), station.stop_point_m - fixes.start_position_m)
    else:
        receiver = TascReceiver(
            config=OnboardConfig(controller),
            station=station,
            vehicle=vehicle,
            gradient=scenario.gradient,
            n=n,
            dt_s=dt_s,
            form=form,
        )
    actuator = ActuatorState.create(
        n=n,
        dt_s=dt_s,
        dead_time_s=scenario.dead_time_s,
        time_constant_s=scenario.time_constant_s,
        jerk_limit_mps3=brake.jerk_limit_mps3,
        emergency_mps2=brake.emergency_decel_mps2,
    )
    link = _Link.create(n, station, form, dt_s, as_bytes=record and n == 1 and not is_ato)
    radar = station.tasc.doppler
    doppler_on = radar is not None
    noisy_doppler = bool(np.any(scenario.doppler_noise_frac > 0))
    doppler_reach = station.stop_point_m + (radar.beyond_stop_m if radar is not None else 0.0)
    doppler_range = radar.range_m if radar is not None else 0.0

    max_jerk = np.zeros(n)
    slid = np.zeros(n, dtype=bool)
    prev_accel = np.zeros(n)
    prev_counted = np.zeros(n, dtype=bool)
    notch_changes = np.zeros(n, dtype=np.int64)
    prev_notch = np.zeros(n, dtype=np.int64)
    rec: dict[str, list[NDArray[Any]]] = {k: [] for k in Trace.__dataclass_fields__}

    steps = round(max_time_s / dt_s)
    passed = np.zeros(n, dtype=bool)  # detector reports found during the last step
    det_idx = np.zeros(n, dtype=np.int64)
    pass_t = np.zeros(n)
    k = 0
    for k in range(steps):
        t = k * dt_s
        # Sensors: a Doppler sample now (the radar sees trains within its range).
        dop = None
        if doppler_on and not is_ato:
            in_range = (doppler_reach - motion.position_m) <= doppler_range
            v_meas = (
                doppler_sample(motion.speed_mps, scenario.doppler_noise_frac, streams, k)
                if noisy_doppler
                else motion.speed_mps
            )
            dop = np.where(in_range, v_meas, 0.0)
        # The tachometer's speed: wheel speed (slower when sliding) with the assumed diameter.
        tach_v = tachometer_speed_mps(
            motion.speed_mps, motion.sliding, scale=tach_scale, slide_slip_ratio=vehicle.slide_slip_ratio
        )
        if isinstance(receiver, AtoController):
            signal = receiver.output(t, tach_v)
        else:
            # Wayside unit -> radio link -> onboard receiver.
            tele = unit.step(t, passed=passed, detector=det_idx, passage_s=pass_t, doppler_mps=dop)
            if tele is not None:
                # What the train can receive: the codec's resolution (SPEC §5 telegrams).
                link.send(quantize_telegrams(tele))
            link.transmit(t, scenario, streams)
            delivered, received = link.deliver(t)
            if received is not None and delivered.any():
                receiver.receive(received, delivered, t)
            receiver.observe_tachometer(tach_v)
            signal = receiver.output(tach_v)
        # Onboard -> ECU -> actuator -> brakes.
        demand = ecu_demand_mps2(line=signal.line, duty=signal.duty, emergency=signal.emergency, brake=brake)
        if signal.line is not None:
            notch = decode_step(signal.line)
            notch_changes += (notch != prev_notch) & ~motion.stopped
            prev_notch = notch
        out = actuator_step(actuator, demand)
        brake_decel = braking_decel_mps2(
            out,
            brake_gain=scenario.brake_gain,
            believed_effective_kg=mass.believed_effective_kg,
            effective_kg=mass.effective_kg,
        )
        in_patch = (motion.position_m >= scenario.low_mu_start_m) & (
            motion.position_m < scenario.low_mu_end_m
        )
        mu = np.where(in_patch, scenario.low_mu, scenario.adhesion_mu)
        x0 = motion.position_m
        v0 = motion.speed_mps
        hold = ~receiver.braking
        motion_step(
            motion,
            vehicle=vehicle,
            mass=mass,
            brake_decel_mps2=brake_decel,
            mean_gradient=scenario.gradient.mean_gradient(motion.position_m, vehicle.length_m),
            adhesion_mu=mu,
            speed_hold=hold,
            t_s=t,
            dt_s=dt_s,
        )
        slid |= motion.sliding & ~motion.stopped
        # Jerk while moving under TASC braking (not across the traction cut-off
        # or the standstill step).
        counted = ~hold & ~motion.stopped
        jerk = np.abs(motion.accel_mps2 - prev_accel) / dt_s
        max_jerk = np.where(counted & prev_counted, np.maximum(max_jerk, jerk), max_jerk)
        prev_accel = motion.accel_mps2
        prev_counted = counted
        # True passages (for the record) and the detectors' reports (for the wayside).
        acc = motion.accel_mps2
        crossed, idx, tc = truth.detect(
            x0_m=x0, v0_mps=v0, accel_mps2=acc, x1_m=motion.position_m, t0_s=t, streams=streams
        )
        passages[crossed, idx[crossed]] = tc[crossed]
        if isinstance(receiver, AtoController):
            odo = odometer_increment_m(
                motion.position_m - x0,
                motion.sliding,
                actual_diameter_m=scenario.wheel_diameter_m,
                assumed_diameter_m=assumed_diam,
                slide_slip_ratio=vehicle.slide_slip_ratio,
            )
            receiver.odometer(odo)
            if fixes is None:
                read, t_idx, _ = transponders.detect(
                    x0_m=x0, v0_mps=v0, accel_mps2=acc, x1_m=motion.position_m, t0_s=t, streams=streams
                )
                receiver.transponder(read, t_idx)
            else:
                rows, corrected = fixes.step(
                    t0_s=t,
                    dt_s=dt_s,
                    x0_m=x0,
                    v0_mps=v0,
                    accel_mps2=acc,
                    x1_m=motion.position_m,
                    odometer_increment_m=odo,
                    tach_speed_mps=tachometer_speed_mps(
                        motion.speed_mps,
                        motion.sliding,
                        scale=tach_scale,
                        slide_slip_ratio=vehicle.slide_slip_ratio,
                    ),
                    sliding=motion.sliding,
                    latency_s=scenario.radio_latency_s,
                )
                receiver.fix(rows, station.stop_point_m - corrected)
        else:
            passed, det_idx, pass_t = sensors.detect(
                x0_m=x0, v0_mps=v0, accel_mps2=acc, x1_m=motion.position_m, t0_s=t, streams=streams
            )
        if record:
            rec["t_s"].append(np.full(n, t + dt_s))
            rec["position_m"].append(motion.position_m.copy())
            rec["speed_mps"].append(motion.speed_mps.copy())
            rec["target_decel_mps2"].append(np.where(receiver.active, receiver.target_mps2, np.nan))
            rec["demand_decel_mps2"].append(demand)
            rec["brake_decel_mps2"].append(np.where(motion.stopped, 0.0, brake_decel))
            rec["accel_mps2"].append(motion.accel_mps2.copy())
            rec["notch"].append(decode_step(signal.line) if signal.line is not None else np.full(n, -1))
            rec["duty"].append(signal.duty if signal.duty is not None else np.full(n, np.nan))
        if motion.stopped.all():
            break
    stop_error = motion.position_m - station.stop_point_m
    first = passages[:, 0]
    stop_time = np.where(motion.stopped, motion.stop_time_s - first, np.nan)
    trace = None
    if record:
        trace = Trace(**{key: np.asarray(v) for key, v in rec.items()})
    return BatchResult(
        stop_error_m=stop_error,
        stop_time_s=stop_time,
        max_jerk_mps3=max_jerk,
        notch_changes=notch_changes,
        commands_sent=np.zeros(n, dtype=np.int64) if is_ato else unit.sent.copy(),
        # The ATO receives no telegrams.
        commands_received=(
            receiver.received.copy() if isinstance(receiver, TascReceiver) else np.zeros(n, dtype=np.int64)
        ),
        stopped=motion.stopped.copy(),
        slid=slid,
        detector_passages_s=passages,
        trace=trace,
        commands=unit.records,
        link_frames=(
            {"sent": link.bytes_link.frames_sent, **link.bytes_link.receiver.counts}
            if link.bytes_link is not None
            else {}
        ),
    )
