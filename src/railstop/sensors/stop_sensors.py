"""The platform's stop sensors of SPEC §3: S2 then S1, 750 mm apart, seeing the train front.

Optical or ultrasonic time-of-flight against a reflector (SPEC §3). A sensor
at chainage p sees the train when the train body covers p: its front is at
or beyond p (as the sensor measures it, with ``noise_sd_m``) and its rear
before p. A scan may miss a train that is there (``dropout_probability``):
a miss reads as "no train". The randomness is passed in (standard normals
and uniforms, one per sensor and scan; DESIGN rule 7), so the same draws
give the same readings, for one train or for arrays of runs.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from railstop.config.platform import StopSensors


def sees(
    front_m: ArrayLike,
    rear_m: ArrayLike,
    sensor_m: float,
    normal: ArrayLike,
    uniform: ArrayLike,
    params: StopSensors,
) -> NDArray[np.bool_]:
    """Whether the sensor at ``sensor_m`` reports a train (front, rear chainages) in this scan."""
    front = np.asarray(front_m, dtype=np.float64) + params.noise_sd_m * np.asarray(normal, dtype=np.float64)
    there = (front >= sensor_m) & (np.asarray(rear_m, dtype=np.float64) <= sensor_m)
    return there & (np.asarray(uniform, dtype=np.float64) >= params.dropout_probability)
