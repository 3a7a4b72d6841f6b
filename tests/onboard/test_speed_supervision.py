"""SPEC §3 speed supervision of manual driving: ATS (over the point's limit > 3 s -> emergency
brake) and ATC (over the indicated speed: 3 s grace, then alarm and brake; over permitted: at once)."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from railstop.clock import SimClock
from railstop.control.supervision import EbCause
from railstop.errors import InterlockError
from railstop.messages import Output, SpeedCode, SupervisionState, TrainSpeed
from railstop.onboard.speed_supervision import SpeedSupervision
from railstop.quantities import MPS_PER_KMH


def drive(
    unit: SpeedSupervision, limit_kmh: float, speeds: list[tuple[float, float]], until_s: float
) -> list[tuple[float, SupervisionState]]:
    """Run ``unit`` on the clock: the limit at 0, then (time, speed km/h) changes; what it says."""
    said: list[tuple[float, SupervisionState]] = []
    plan = sorted(speeds)

    class Listener:
        name = "listener"
        accepts = (SupervisionState,)

        def handle(self, message: object, now_s: float) -> list[Output]:
            said.append((now_s, message))  # type: ignore[arg-type]
            return []

        def next_deadline_s(self) -> None:
            return None

        def on_timer(self, now_s: float) -> list[Output]:
            return []

    clock = SimClock([unit, Listener()], step_s=0.1)
    clock.deliver([Output(to=unit.name, message=SpeedCode(limit_mps=limit_kmh * MPS_PER_KMH))])

    def plant(now_s: float, dt: float) -> list[Output]:
        out = []
        while plan and plan[0][0] <= now_s + 1e-9:
            _, v = plan.pop(0)
            out.append(Output(to=unit.name, message=TrainSpeed(speed_mps=v * MPS_PER_KMH)))
        return out

    clock.run(until_s, plant)
    return said


def first_eb(said: list[tuple[float, SupervisionState]]) -> tuple[float, str | None] | None:
    return next(((t, s.cause) for t, s in said if s.emergency_brake), None)


def test_ats_over_the_limit_for_3_s_brakes_whatever_the_aspect() -> None:
    said = drive(SpeedSupervision(mode="ats"), 45.0, [(1.0, 50.0)], 10.0)
    t, cause = first_eb(said)  # type: ignore[misc]
    assert t == pytest.approx(1.0 + 3.0) and cause == EbCause.OVERSPEED_GRACE.label
    assert not any(s.alarm for _, s in said)  # ATS has no alarm stage


def test_ats_a_driver_who_brakes_within_the_grace_is_not_braked() -> None:
    said = drive(SpeedSupervision(mode="ats"), 45.0, [(1.0, 50.0), (3.5, 44.0)], 10.0)
    assert first_eb(said) is None


def test_atc_over_indicated_grace_then_alarm_and_brake_over_permitted_at_once() -> None:
    said = drive(SpeedSupervision(mode="atc"), 40.0, [(1.0, 42.0)], 10.0)
    t, cause = first_eb(said)  # type: ignore[misc]
    assert t == pytest.approx(1.0 + 3.0) and cause == EbCause.OVERSPEED_GRACE.label
    assert any(s.alarm for _, s in said)
    fast = drive(SpeedSupervision(mode="atc"), 40.0, [(1.0, 46.0)], 10.0)
    t, cause = first_eb(fast)  # type: ignore[misc]
    assert t == pytest.approx(1.0) and cause == EbCause.OVER_PERMITTED.label


def test_the_brake_is_latched_to_standstill() -> None:
    u = SpeedSupervision(mode="ats")
    u.handle(SpeedCode(limit_mps=25 * MPS_PER_KMH), 0.0)
    u.handle(TrainSpeed(speed_mps=30 * MPS_PER_KMH), 0.0)
    u.on_timer(3.0)
    assert u.emergency_brake
    u.handle(TrainSpeed(speed_mps=10 * MPS_PER_KMH), 4.0)  # under the limit, still moving
    assert u.emergency_brake
    u.handle(TrainSpeed(speed_mps=0.0), 8.0)
    assert not u.emergency_brake


def test_no_code_or_a_bad_one_is_the_most_restrictive() -> None:
    u = SpeedSupervision(mode="atc")
    u.handle(TrainSpeed(speed_mps=2.0), 0.0)  # no code received: limit 0, 2 m/s over permitted
    assert u.emergency_brake and u.cause == EbCause.OVER_PERMITTED.label
    v = SpeedSupervision(mode="ats")
    v.handle(SpeedCode(limit_mps=float("nan")), 0.0)
    v.handle(TrainSpeed(speed_mps=1.0), 0.0)
    assert v.limit_mps == 0.0 and v.next_deadline_s() == 3.0
    with pytest.raises(InterlockError, match="mode"):
        SpeedSupervision(mode="ctcs")


@settings(max_examples=60, deadline=None)
@given(
    mode=st.sampled_from(["ats", "atc"]),
    limit_kmh=st.floats(min_value=10.0, max_value=80.0),
    over_kmh=st.floats(min_value=0.5, max_value=4.9),
    start_s=st.floats(min_value=0.0, max_value=5.0),
)
def test_a_driver_who_ignores_the_overspeed_is_always_braked_at_3_s(
    mode: str, limit_kmh: float, over_kmh: float, start_s: float
) -> None:
    """The issue's target at unit level: ignoring the overspeed gets the emergency brake in
    every case, when the grace ends (within the plant's 0.1 s step)."""
    said = drive(SpeedSupervision(mode=mode), limit_kmh, [(start_s, limit_kmh + over_kmh)], start_s + 6.0)
    eb = first_eb(said)
    assert eb is not None and eb[1] == EbCause.OVERSPEED_GRACE.label
    assert start_s + 3.0 - 1e-9 <= eb[0] <= start_s + 3.0 + 0.1 + 1e-9
