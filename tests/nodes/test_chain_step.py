"""The line's compiled position step (nodes.chain_step) against the units' own array methods.

DESIGN rule 1: the compiled loop calls the same scalar cores as ``Tachometer``, ``GnssClock``,
``TrackCircuitDetector.detect`` and ``PositioningUnit.log``; driven with the same motion, the two
must leave every state the same to the bit (odometers, clocks, detections, telegrams, fixes).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from railstop.config import default_line, default_vehicle
from railstop.config.operation import load_operation
from railstop.sensors.odometer import creep_factor
from railstop.sim.line import LineSettings, LineSimulation, PositionSettings, _feed_chain, _fixes

DT = 0.1


def _line(**position: object) -> LineSimulation:
    line = default_line()
    op = load_operation(None, line)
    return LineSimulation(
        line=line,
        vehicle=default_vehicle(),
        operation=op,
        seed=3,
        settings=LineSettings(position=PositionSettings(**position)),  # type: ignore[arg-type]
    )


def _motion(k: int, n: int, entry_m: float, x: np.ndarray) -> tuple[np.ndarray, ...]:
    """Step k's motion of n trains: train j enters at step 40 j + 1, then runs 12-18 m/s; train 1
    slides and train 2 slips now and then; the last train never enters."""
    on = np.array([k > 40 * j and j < n - 1 for j in range(n)])
    was = np.array([k - 1 > 40 * j and j < n - 1 for j in range(n)])
    v0 = 15.0 + 3.0 * np.sin(0.01 * (k - 1) + np.arange(n))
    v1 = 15.0 + 3.0 * np.sin(0.01 * k + np.arange(n))
    x1 = np.where(on, np.where(was, x + 0.5 * (v0 + v1) * DT, entry_m), -np.inf)
    x0 = np.where(was, x, x1)
    sliding = np.zeros(n, dtype=bool)
    slipping = np.zeros(n, dtype=bool)
    sliding[1] = (k // 50) % 3 == 1
    slipping[2] = (k // 70) % 4 == 2
    return on, x0, x1, v0, v1, sliding & on, slipping & on


@pytest.mark.parametrize("accelerometer", [True, False])
def test_compiled_step_equals_the_units_array_methods(accelerometer: bool) -> None:
    a, b = _line(accelerometer=accelerometer), _line(accelerometer=accelerometer)
    n = len(a.trains)
    entry = a.operation.entry_m
    x = np.full(n, -np.inf)
    fixes = 0
    for k in range(1, 3001):
        now = k * DT
        on, x0, x1, v0, v1, sliding, slipping = _motion(k, n, entry, x)
        x = x1
        # The compiled step.
        step = a._chain_step.step(
            now_s=now,
            dt_s=DT,
            on_line=on,
            x0_m=x0,
            x1_m=x1,
            v0_mps=v0,
            v1_mps=v1,
            sliding=sliding,
            slipping=slipping,
        )
        rep_a, got_a = _fixes(a.chain, a.positioning, now)
        est_a = a.positioning.calibrated_m() if got_a.size else step.calibrated_m
        # The units' array methods, as the line ran them before the compiled step.
        creep = creep_factor(
            sliding,
            slipping,
            slide_slip_ratio=b.vehicle.slide_slip_ratio,
            traction_slip_ratio=b.traction.slip_ratio,
        )
        moved = np.subtract(x1, x0, out=np.zeros(n), where=on)
        b.tacho.advance(moved, creep)
        motion = {
            "t0_s": now - DT,
            "dt_s": DT,
            "x0_m": x0,
            "v0_mps": v0,
            "accel_mps2": np.where(on, 2.0 * (moved - v0 * DT) / (DT * DT), 0.0),
            "x1_m": x1,
        }
        log = {
            "odometer_m": b.tacho.odometer_m(),
            "speed_mps": b.tacho.speed_mps(v1, creep),
            "wsp_active": sliding | slipping,
            "accel_mps2": (v1 - v0) / DT + b.accel_bias if accelerometer else None,
        }
        rep_b, got_b = _feed_chain(b.chain, b.positioning, now, motion, log)
        est_b = b.positioning.calibrated_m()
        assert np.array_equal(est_a, est_b), k
        assert np.array_equal(step.moved_m, moved) and np.array_equal(step.odometer_m, log["odometer_m"])
        assert np.array_equal(got_a.circuit_id, got_b.circuit_id)
        assert (rep_a is None) == (rep_b is None)
        if rep_a is not None and rep_b is not None:
            assert np.array_equal(rep_a.outcome, rep_b.outcome)
        fixes += got_a.size
    # Every state alike to the bit, and the run did reach the rare paths (detections, fixes).
    assert np.array_equal(a.tacho.revolutions, b.tacho.revolutions)
    assert np.array_equal(a.chain.onboard_clock.error_s, b.chain.onboard_clock.error_s)
    assert np.array_equal(a.chain.onboard_clock.disciplined, b.chain.onboard_clock.disciplined)
    assert np.array_equal(a.chain.detector.next_index, b.chain.detector.next_index)
    for name in ("state", "istate", "log_ring"):
        same = np.array_equal(getattr(a.positioning, name), getattr(b.positioning, name), equal_nan=True)
        assert same, name
    assert a.chain.counts == b.chain.counts
    assert fixes > 50 and a.chain.counts.frames > 50
    assert int(a.chain.detector.next_index.max()) > 10
    assert math.isfinite(float(np.nanmax(a.positioning.calibrated_m())))
