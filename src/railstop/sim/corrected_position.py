"""Position fixes of the ``ato-corrected`` baseline: SPEC §2 corrections from track circuits.

The conventional onboard ATO (``railstop.onboard.ato``) stops from its own
odometry. ``ato-corrected`` is the same ATO whose position is corrected by
the method of SPEC §2 instead of station transponders: the wayside
time-stamps each track-circuit occupancy with GNSS time, the train corrects
its odometer position against the circuit's surveyed start
(:class:`~railstop.onboard.positioning.PositioningUnit`). A competent ATO
knows the line's nominal detection delay: it uses the unit's calibrated
position, which adds delay × speed to each fix (the document method alone
leaves the train that far behind its true position, metres at approach
speeds) and learns scale and delay over the few fixes of the approach.

Assumptions of this driver (documented, not drawn): GNSS-disciplined clocks
on both sides (offsets of ~100 ns, negligible); the occupancy telegram goes
on the radio with the run's latency (the positioning unit uses the time in
the telegram, so the latency only delays the fix); its GNSS time has the
codec's 0.1 ms resolution. Before the simulated approach the train was
corrected at the last circuit boundary behind it, so it starts with that
fix's error (detection delay × speed, boundary uncertainty) plus its
odometer's scale error over the distance since.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from railstop.config.schema import Track, Vehicle
from railstop.errors import SimulationError
from railstop.link.codec import TrackCircuitOccupancy, quantize
from railstop.onboard.positioning import PositioningUnit
from railstop.sensors.track_circuit import TrackCircuitDetector
from railstop.streams import RunStreams

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
BoolArray = NDArray[np.bool_]

LOG_WINDOW_S = 2.0  # covers the detection delay and the radio latency of a telegram


@dataclass(slots=True)
class TrackCircuitFixes:
    """Track-circuit occupancies -> (circuit, GNSS time) telegrams -> corrected positions, n runs."""

    detector: TrackCircuitDetector
    unit: PositioningUnit
    odometer_m: FloatArray  # cumulative odometer reading
    pending_circuit: IntArray  # circuit id of the telegram on its way (-1: none)
    pending_time_s: FloatArray  # its GNSS time
    pending_arrival_s: FloatArray  # when it reaches the train
    start_position_m: FloatArray  # the corrected position at the start of the simulation

    @classmethod
    def create(
        cls,
        *,
        track: Track | None,
        vehicle: Vehicle,
        streams: RunStreams,
        start_m: FloatArray,
        speed_mps: FloatArray,
        tach_scale: FloatArray,
        dt_s: float,
    ) -> TrackCircuitFixes:
        if track is None or not track.circuits:
            raise SimulationError("ato-corrected needs the line's track circuits ([track] circuits)")
        n = streams.n
        detector = TrackCircuitDetector.create(
            track.circuits, track.detection, streams, start_position_m=start_m
        )
        rows = np.arange(n)
        last = detector.next_index - 1
        if np.any(last < 0):
            raise SimulationError("ato-corrected: the approach starts before the first track circuit")
        # SPEC §2 S40 at the last boundary behind the train: when the wayside declared
        # the occupancy the front was delay × speed past the electrical boundary; the
        # train put itself at the surveyed start plus the nominal delay × its speed;
        # since then its odometer counted with its scale error.
        d0 = track.detection.delay_mean_s
        at_fix = detector.boundary_m[rows, last] + speed_mps * detector.delay_s[rows, last]
        start_belief = detector.starts_m[last] + d0 * speed_mps * tach_scale + (start_m - at_fix) * tach_scale
        settings = vehicle.positioning.model_copy(update={"log_window_s": LOG_WINDOW_S})
        unit = PositioningUnit(
            circuits=track.circuits,
            settings=settings,
            n=n,
            cycle_s=dt_s,
            start_position_m=start_belief,
            boundary_sd_m=[track.detection.boundary_sd_m(c.kind) for c in track.circuits],
            delay_spread_s=track.detection.delay_spread_s,
            nominal_delay_s=d0,
        )
        return cls(
            detector=detector,
            unit=unit,
            odometer_m=np.zeros(n),
            pending_circuit=np.full(n, -1, dtype=np.int64),
            pending_time_s=np.full(n, np.inf),
            pending_arrival_s=np.full(n, np.inf),
            start_position_m=start_belief,
        )

    def step(
        self,
        *,
        t0_s: float,
        dt_s: float,
        x0_m: FloatArray,
        v0_mps: FloatArray,
        accel_mps2: FloatArray,
        x1_m: FloatArray,
        odometer_increment_m: FloatArray,
        tach_speed_mps: FloatArray,
        sliding: BoolArray,
        latency_s: FloatArray,
    ) -> tuple[IntArray, FloatArray]:
        """One step: log the odometer, detect occupancies, take telegrams that arrived.

        Returns the runs corrected now and their corrected positions (chainage).
        """
        now = t0_s + dt_s
        self.odometer_m = self.odometer_m + odometer_increment_m
        # GNSS-disciplined onboard clock: its reading is the true time.
        self.unit.log(
            clock_time_s=np.full(self.odometer_m.size, now),
            odometer_m=self.odometer_m,
            speed_mps=tach_speed_mps,
            wsp_active=sliding,
        )
        ev = self.detector.detect(x0_m=x0_m, v0_mps=v0_mps, accel_mps2=accel_mps2, x1_m=x1_m, t0_s=t0_s)
        if ev.size:
            # SPEC §2 S20: (circuit ID, occupancy instant in GNSS time), on the radio.
            gnss = quantize(TrackCircuitOccupancy, "gnss_time_s", ev.occupied_time_s)
            self.pending_circuit[ev.run] = self.detector.ids[ev.circuit_index]
            self.pending_time_s[ev.run] = gnss
            self.pending_arrival_s[ev.run] = ev.occupied_time_s + latency_s[ev.run]
        due = np.flatnonzero(self.pending_arrival_s <= now + 1e-9)
        if due.size == 0:
            return due, np.zeros(0)
        report = self.unit.handle(
            run=due, circuit_id=self.pending_circuit[due], gnss_time_s=self.pending_time_s[due]
        )
        self.pending_circuit[due] = -1
        self.pending_time_s[due] = np.inf
        self.pending_arrival_s[due] = np.inf
        ok = due[report.accepted]
        # The position with the line's nominal detection delay taken into account
        # (and whatever the unit learned of scale and delay since).
        return ok, self.unit.calibrated_m()[ok]
