"""Per-run parameters of a stop: what the disturbance draw decides (arrays of shape (n,)).

A record of data (DESIGN rule 3), kept with the disturbance draws that fill it
(``config.disturbances``); the model reads it.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from railstop.config.gradient import GradientProfile
from railstop.config.schema import Station, Vehicle
from railstop.quantities import MPS_PER_KMH

FloatArray = NDArray[np.float64]


@dataclass(frozen=True, slots=True, kw_only=True)
class Scenario:
    """Everything that differs between runs of one station and vehicle."""

    entry_speed_mps: FloatArray
    load_factor: FloatArray
    load_weighing_error: FloatArray  # fraction: ECU mass = actual mass x (1 + error)
    brake_gain: FloatArray  # actual / nominal braking
    dead_time_s: FloatArray
    time_constant_s: FloatArray
    gradient: GradientProfile
    wheel_diameter_m: FloatArray  # actual
    odometer_diameter_error: FloatArray  # fraction: assumed = actual x (1 + error)
    adhesion_mu: FloatArray  # dry rail
    low_mu: FloatArray  # in the low-adhesion patch
    low_mu_start_m: FloatArray  # patch chainage (inf = no patch)
    low_mu_end_m: FloatArray
    radio_latency_s: FloatArray
    radio_loss_probability: FloatArray
    radio_jitter_s: FloatArray  # per-frame delay spread (standard deviation)
    radio_bit_error_rate: FloatArray
    sensor_jitter_s: FloatArray
    sensor_miss_probability: FloatArray
    doppler_noise_frac: FloatArray
    radio_outage_start_s: FloatArray  # after the first telegram the train received
    radio_outage_duration_s: FloatArray  # 0: no outage
    # The medium's bursts (Gilbert-Elliott: enter, exit, loss in a burst) and reordering, per frame.
    radio_burst_enter_probability: FloatArray  # 0: no bursts
    radio_burst_exit_probability: FloatArray
    radio_burst_loss_probability: FloatArray
    radio_reorder_probability: FloatArray

    @property
    def n(self) -> int:
        return int(self.entry_speed_mps.size)

    @classmethod
    def nominal(
        cls,
        station: Station,
        vehicle: Vehicle,
        *,
        n: int = 1,
        load_factor: float = 0.0,
        brake_gain: float = 1.0,
    ) -> Scenario:
        """Nominal vehicle, exact sensors, ideal link; load and brake gain as given."""

        def full(value: float) -> FloatArray:
            return np.full(n, float(value))

        return cls(
            entry_speed_mps=full(station.tasc.entry_speed_kmh * MPS_PER_KMH),
            load_factor=full(load_factor),
            load_weighing_error=full(0.0),
            brake_gain=full(brake_gain),
            dead_time_s=full(vehicle.brake.dead_time_s),
            time_constant_s=full(vehicle.brake.time_constant_s),
            gradient=station_gradient(station, n),
            wheel_diameter_m=full(vehicle.wheel_diameter_m),
            odometer_diameter_error=full(0.0),
            adhesion_mu=full(vehicle.adhesion_mu),
            low_mu=full(vehicle.adhesion_mu),
            low_mu_start_m=full(np.inf),
            low_mu_end_m=full(np.inf),
            radio_latency_s=full(0.0),
            radio_loss_probability=full(0.0),
            radio_jitter_s=full(0.0),
            radio_bit_error_rate=full(0.0),
            sensor_jitter_s=full(0.0),
            sensor_miss_probability=full(0.0),
            doppler_noise_frac=full(0.0),
            radio_outage_start_s=full(0.0),
            radio_outage_duration_s=full(0.0),
            radio_burst_enter_probability=full(0.0),
            radio_burst_exit_probability=full(1.0),
            radio_burst_loss_probability=full(0.0),
            radio_reorder_probability=full(0.0),
        )

    def with_values(self, **changes: object) -> Scenario:
        return replace(self, **changes)  # type: ignore[arg-type]


def station_gradient(station: Station, n: int) -> GradientProfile:
    """The station's gradient profile (gaps between segments are level) for n runs."""
    return GradientProfile.from_segments(station.gradient, n)  # the schema refuses overlaps
