"""SPEC §3 platform: stop sensors S2/S1, the lamps F / OK / R / S, the PSD relay only under OK,
departure only with the PSD closed, the signal-open switch; the data and the sensor model."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from railstop.config.platform import StopSensors, load_platform, sensor_positions
from railstop.errors import ConfigError, InterlockError
from railstop.messages import PlatformLamps, PsdDoorState, SignalOpenSwitch, StopSensorScan
from railstop.sensors.stop_sensors import sees
from railstop.wayside.platform import PlatformUnit

DATA, _ = load_platform()


def unit(debounce: int = 3) -> PlatformUnit:
    return PlatformUnit(lamp_table=DATA.lamps(), debounce_scans=debounce)


def scan(u: PlatformUnit, s2: bool, s1: bool, standstill: bool = True, n: int = 3) -> PlatformLamps:
    for _ in range(n):
        u.handle(StopSensorScan(s2=s2, s1=s1, standstill=standstill), 0.0)
    return u.lamps()


def test_a_stop_in_the_window_lights_ok_the_psd_operates_then_s() -> None:
    u = unit()
    assert scan(u, False, False, standstill=False).lamp is None  # approaching: no lamp
    ok = scan(u, True, False)
    assert ok == PlatformLamps(lamp="OK", psd_enable=True, departure_permitted=True)
    u.handle(PsdDoorState(closed_locked=False), 0.0)  # the PSD opens (master)
    assert u.lamps().lamp == "OK" and not u.lamps().departure_permitted
    out = u.handle(PsdDoorState(closed_locked=True), 0.0)
    assert out[0].message == PlatformLamps(lamp="S", psd_enable=False, departure_permitted=True)


def test_short_and_overrun_light_f_and_r_and_never_enable_the_psd() -> None:
    u = unit()
    assert scan(u, False, False) == PlatformLamps(lamp="F", psd_enable=False, departure_permitted=True)
    scan(u, False, False, standstill=False)
    assert scan(u, True, True) == PlatformLamps(lamp="R", psd_enable=False, departure_permitted=True)


def test_s1_without_s2_is_a_sensor_fault_no_lamp_psd_held() -> None:
    assert scan(unit(), False, True) == PlatformLamps(lamp=None, psd_enable=False, departure_permitted=True)


def test_debounce_keeps_a_single_s1_dropout_from_lighting_ok_for_an_overrun() -> None:
    for debounce, expect in ((3, "R"), (1, "OK")):
        u = unit(debounce)
        scan(u, True, False, n=1)  # the first scan after the stop: S1 missed the train
        lamp = scan(u, True, True, n=5)
        assert lamp.lamp == expect


def test_the_lamp_holds_at_a_stand_once_the_sensors_have_settled() -> None:
    """A train at a stand does not move: a front standing within a sensor's noise of S1 must not
    flip OK to R (dropping the relay and the PSD in front of open train doors); moving resets."""
    u = unit()
    assert scan(u, True, False).lamp == "OK"
    assert scan(u, True, True, n=10).lamp == "OK"
    assert scan(u, False, False, n=10).lamp == "OK"
    scan(u, True, True, standstill=False, n=1)
    assert scan(u, True, True).lamp == "R"


def test_signal_open_switch_passes_the_train_with_the_psd_held() -> None:
    u = unit()
    u.handle(SignalOpenSwitch(on=True), 0.0)
    assert scan(u, True, False) == PlatformLamps(lamp=None, psd_enable=False, departure_permitted=True)
    u.handle(SignalOpenSwitch(on=False), 0.0)
    assert scan(u, True, False).lamp == "OK"


def test_moving_again_starts_a_new_stop() -> None:
    u = unit()
    scan(u, True, False)
    u.handle(PsdDoorState(closed_locked=False), 0.0)
    u.handle(PsdDoorState(closed_locked=True), 0.0)
    assert u.lamps().lamp == "S"
    scan(u, True, False, standstill=False, n=1)
    assert scan(u, True, False).lamp == "OK"  # the next stop's PSD cycle is its own


def test_an_unsafe_lamp_table_is_refused(tmp_path: Path) -> None:
    from importlib import resources

    text = (resources.files("railstop.data") / "platform.toml").read_text(encoding="utf-8")
    bad = tmp_path / "p.toml"
    bad.write_text(
        text.replace('{ s2 = 1, s1 = 1, lamp = "R" }', '{ s2 = 1, s1 = 1, lamp = "OK" }'), encoding="utf-8"
    )
    with pytest.raises(ConfigError, match=r"lamp_table.*only"):
        load_platform(bad)
    with pytest.raises(InterlockError, match="OK"):
        PlatformUnit(lamp_table={**DATA.lamps(), (True, True): "OK"})


def test_sensor_geometry_noise_and_dropout() -> None:
    s2, s1 = sensor_positions(1200.0, 0.75)
    assert (s2, s1) == (1199.625, 1200.375)
    exact = StopSensors(noise_sd_m=0.0, dropout_probability=0.0)
    fronts = np.array([1199.5, 1200.0, 1200.5])
    rears = fronts - 120.0
    zero, one = np.zeros(3), np.ones(3)
    assert sees(fronts, rears, s2, zero, one, exact).tolist() == [False, True, True]
    assert sees(fronts, rears, s1, zero, one, exact).tolist() == [False, False, True]
    # A dropout reads as "no train".
    lossy = StopSensors(noise_sd_m=0.0, dropout_probability=0.5)
    assert sees(fronts, rears, s2, zero, np.full(3, 0.2), lossy).tolist() == [False, False, False]
    # Noise moves where the sensor sees the front: 1 cm at 0.005 m sd is two sd.
    noisy = StopSensors(noise_sd_m=0.005, dropout_probability=0.0)
    assert sees(np.array([s2 - 0.01]), np.array([0.0]), s2, np.array([2.5]), np.ones(1), noisy).tolist() == [
        True
    ]
