"""SPEC §3 dwell on a manually driven line with platform screen doors: the PSD control that follows
the train doors through the CCD camera (``PsdFollower``), the camera's frames, the dwell from a
stand (lamps -> train doors -> PSD -> departure), the commands that run and store it, and the
driver / platform data given as files."""

from __future__ import annotations

import json
import subprocess
from importlib import resources
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

from railstop.cli import app
from railstop.config import default_line, default_vehicle
from railstop.config.disturbances import load_disturbances
from railstop.config.doors import load_doors
from railstop.config.driver import DriverFile, default_driver
from railstop.config.platform import DoorCamera, PlatformFile, default_platform, load_platform
from railstop.errors import ConfigError, InterlockError, RailstopError, SimulationError
from railstop.messages import (
    DoorCameraFrame,
    PlatformLamps,
    PsdCommand,
    PsdDoorState,
    StopSensorScan,
)
from railstop.sim.campaign import CampaignSpec, spec_from_manifest
from railstop.sim.dwell import DwellEvent
from railstop.sim.platform_dwell import (
    OUTCOMES,
    SIGNALS,
    STEP_S,
    PlatformDwellResult,
    _Leaves,
    dwell_after_stop,
    dwell_sentence,
    run_platform_dwell,
    stand_events,
)
from railstop.sim.single import run_stop
from railstop.store import open_store
from railstop.wayside.platform import PlatformUnit, PsdFollower
from zygote import run_cli

PLATFORM, _ = load_platform()
DOORS = load_doors(None)
TIMING = DOORS.timing
CAMERA = PLATFORM.camera
LINE, VEHICLE = default_line(), default_vehicle()
STATION = LINE.stations[0]
HALF_WINDOW_M = 0.5 * PLATFORM.sensors.spacing_m
PSD_SIGNALS = {"camera", "psd_command", "PSD"}


# ----------------------------------------------------------------------------- helpers


def dwell(stop_error_m: float, seed: int = 1, **kw: Any) -> PlatformDwellResult:
    kw.setdefault("platform", PLATFORM)
    return run_platform_dwell(doors=DOORS, station=STATION.name, stop_error_m=stop_error_m, seed=seed, **kw)


def instants(timeline: Any) -> list[tuple[float, dict[str, Any]]]:
    """Replay a timeline: the value of every signal at each instant that changes one (each
    signal's last value at that instant, in the logged order)."""
    events = [
        (e["t_s"], e["signal"], e["value"]) if isinstance(e, dict) else (e.t_s, e.signal, e.value)
        for e in timeline
    ]
    times = [t for t, _, _ in events]
    assert times == sorted(times), "a timeline runs forward"
    now: dict[str, Any] = {}
    out: list[tuple[float, dict[str, Any]]] = []
    for t, signal, value in events:
        now[signal] = value
        if out and out[-1][0] == t:
            out[-1] = (t, dict(now))
        else:
            out.append((t, dict(now)))
    return out


def becomes(
    states: list[tuple[float, dict[str, Any]]], signal: str, value: Any
) -> list[tuple[float, dict[str, Any]]]:
    """The instants after the start where ``signal`` changes to ``value``."""
    hits = []
    before = states[0][1]
    for t, s in states[1:]:
        if s.get(signal) == value and before.get(signal) != value:
            hits.append((t, s))
        before = s
    return hits


def first(states: list[tuple[float, dict[str, Any]]], signal: str, value: Any) -> float:
    hits = becomes(states, signal, value)
    assert hits, f"{signal} never became {value!r}"
    return hits[0][0]


def values(result: PlatformDwellResult, signal: str) -> set[Any]:
    return {e.value for e in result.timeline if e.signal == signal}


def psd_locked(value: Any) -> bool:
    return str(value).startswith("closed_locked")  # "closed_locked" or "closed_locked (staff)"


def cli(tmp_path: Path, *args: str) -> subprocess.CompletedProcess[str]:
    return run_cli(*args, cwd=tmp_path)  # forked from a warm zygote (tests/zygote.py)


def one_error_line(proc: subprocess.CompletedProcess[str]) -> str:
    assert proc.returncode == 2, (proc.stdout, proc.stderr)
    assert "Traceback" not in proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error:"), proc.stderr
    return lines[0]


def expert_only() -> DriverFile:
    data = default_driver().model_dump()
    for name in data["levels"]:
        data["levels"][name]["share"] = 1.0 if name == "expert" else 0.0
    return DriverFile.model_validate(data)


# ----------------------------------------------------------------------------- PsdFollower

OPEN_, MOVING_, CLOSED_ = "open", "moving", "closed"
OPEN_CMD = PsdCommand(open=True, camera_ok=True)
CLOSE_CMD = PsdCommand(open=False, camera_ok=True)


def follower(confirm: int = 3, lost: int = 10, lock: int = 5) -> PsdFollower:
    return PsdFollower(confirm_frames=confirm, lost_limit_frames=lost, lock_frames=lock)


def relay(f: PsdFollower, on: bool) -> list[PsdCommand]:
    return commands(
        f.handle(PlatformLamps(lamp="OK" if on else "F", psd_enable=on, departure_permitted=True), 0.0)
    )


def frames(f: PsdFollower, *seen: str | None) -> list[PsdCommand]:
    got: list[PsdCommand] = []
    for s in seen:
        got += commands(f.handle(DoorCameraFrame(shape=s), 0.0))
    return got


def commands(outputs: list[Any]) -> list[PsdCommand]:
    msgs = [o.message for o in outputs]
    assert all(isinstance(m, PsdCommand) for m in msgs)
    return msgs


def opened(f: PsdFollower, confirm: int = 3) -> PsdFollower:
    """A follower with its relay energised and the doors confirmed open (the PSD told to open)."""
    relay(f, True)
    got = frames(f, *[OPEN_] * confirm)
    assert got == [OPEN_CMD]
    return f


@pytest.mark.parametrize("confirm", [2, 3, 5])
def test_fewer_misread_frames_than_confirm_never_move_the_command(confirm: int) -> None:
    f = follower(confirm)
    relay(f, True)
    assert frames(f, *[CLOSED_] * 40) == []  # closed and locked: still closed, nothing to say
    # Runs of confirm-1 "open" misreads, each broken by a true "closed" frame, unreadable frames
    # in between (they neither confirm nor break a run).
    burst = [OPEN_, None] * (confirm - 1) + [CLOSED_]
    assert frames(f, *burst * 20) == []
    assert not f.command.open
    # One more "open" in the run is the confirmed shape: the PSD opens.
    assert frames(f, *[OPEN_, None] * (confirm - 1), OPEN_) == [OPEN_CMD]
    # The same the other way round: misread "closed" frames do not shut an open PSD.
    assert frames(f, *([CLOSED_] * (confirm - 1) + [OPEN_]) * 20) == []
    assert f.command.open


@pytest.mark.parametrize(("confirm", "lock"), [(1, 0), (2, 3), (3, 5), (4, 2)])
def test_the_psd_closes_only_after_a_run_of_closed_frames_that_outlasts_misreads_and_the_lock(
    confirm: int, lock: int
) -> None:
    """SPEC §5 order (train doors closed and locked, then the PSD): "closed" frames, readable and in
    a row, enough that with confirm - 1 misreads at either end lock + 1 true ones remain."""
    f = opened(follower(confirm, lock=lock), confirm)
    need = 2 * (confirm - 1) + lock + 1
    assert f.locked_after_frames() == need
    assert frames(f, *[MOVING_] * 30) == []  # the doors on their way: held open
    assert frames(f, *[CLOSED_] * (need - 1)) == [] and f.command.open
    # An unreadable frame, or any other shape, starts the count again.
    for breaker in (None, MOVING_, OPEN_):
        assert frames(f, breaker, *[CLOSED_] * (need - 1)) == [] and f.command.open
    assert frames(f, CLOSED_) == [CLOSE_CMD]
    assert f.doors_locked()


def test_without_the_relay_the_psd_never_opens_whatever_the_camera_says() -> None:
    f = follower()
    relay(f, False)
    assert frames(f, *[OPEN_] * 50, *[None] * 5, *[OPEN_] * 50) == []
    assert f.shape == OPEN_ and not f.command.open  # it sees the doors open and still keeps shut


def test_the_relay_dropping_holds_an_open_psd_until_the_doors_are_seen_locked() -> None:
    """[interpretation] DESIGN rule 10: OK going dark (signal-open switch, a moved train) does not
    shut the PSD on train doors that are not closed and locked; nothing opens without it."""
    f = opened(follower())
    assert relay(f, False) == []  # held open
    assert frames(f, *[OPEN_] * 20, *[MOVING_] * 20, *[CLOSED_] * (f.locked_after_frames() - 1)) == []
    assert f.command.open
    assert frames(f, CLOSED_) == [CLOSE_CMD]
    assert frames(f, *[OPEN_] * 20) == []  # no relay: it does not open again


def test_the_relay_dropping_leaves_an_open_psd_held_by_a_lost_camera_for_staff() -> None:
    f = opened(follower(lost=4))
    assert frames(f, *[None] * 4) == [PsdCommand(open=True, camera_ok=False)]
    assert relay(f, False) == []
    assert f.command == PsdCommand(open=True, camera_ok=False)


@pytest.mark.parametrize("lost", [1, 4, 10])
def test_a_lost_camera_holds_an_open_psd_open(lost: int) -> None:
    f = opened(follower(lost=lost))
    assert frames(f, *[None] * (lost - 1)) == []  # not yet lost
    assert f.camera_ok()
    assert frames(f, None) == [PsdCommand(open=True, camera_ok=False)]  # lost: held open
    assert frames(f, *[None] * 50) == []
    assert f.command == PsdCommand(open=True, camera_ok=False) and f.shape is None


def test_a_lost_camera_holds_a_closed_psd_closed() -> None:
    f = follower(lost=5)
    relay(f, True)
    frames(f, *[CLOSED_] * 3)
    assert frames(f, *[None] * 5) == [PsdCommand(open=False, camera_ok=False)]
    assert frames(f, *[None] * 50) == []
    assert not f.command.open


@pytest.mark.parametrize("confirm", [1, 3, 4])
def test_a_recovered_camera_needs_the_whole_run_again(confirm: int) -> None:
    lost = 6
    # Held open: the readable frames after the loss do not close it before a whole locked run.
    f = opened(follower(confirm, lost), confirm)
    frames(f, *[None] * lost)
    got = frames(f, *[CLOSED_] * (f.locked_after_frames() - 1))
    assert all(c.open for c in got) and f.command.open
    assert frames(f, CLOSED_) == [CLOSE_CMD]
    # Held closed: "open" frames seen before the loss do not count towards the run after it.
    f = follower(confirm, lost)
    relay(f, True)
    frames(f, *[CLOSED_] * confirm, *[OPEN_] * (confirm - 1), *[None] * lost)
    assert not f.command.open and not f.camera_ok()
    got = frames(f, *[OPEN_] * (confirm - 1))
    assert not any(c.open for c in got) and not f.command.open
    assert frames(f, OPEN_) == [OPEN_CMD]


def test_unreadable_frames_short_of_the_limit_neither_confirm_nor_break_a_run() -> None:
    f = follower(confirm=3, lost=4)
    relay(f, True)
    assert frames(f, OPEN_, None, None, None, OPEN_, None, None, None) == []
    assert frames(f, OPEN_) == [OPEN_CMD]  # the third "open" frame


def test_a_frame_of_unknown_shape_counts_unreadable_and_is_refused() -> None:
    f = opened(follower(lost=1))
    with pytest.raises(InterlockError, match="unknown shape"):
        f.handle(DoorCameraFrame(shape="ajar"), 0.0)
    # DESIGN rule 10 first: counted unreadable (here: the camera lost), the PSD held open.
    assert not f.camera_ok() and f.command.open and f.closed_run == 0


@pytest.mark.parametrize(
    "message", [StopSensorScan(s2=True, s1=False, standstill=True), PsdDoorState(closed_locked=False)]
)
def test_the_psd_control_refuses_a_message_it_does_not_take(message: Any) -> None:
    f = opened(follower())
    with pytest.raises(InterlockError, match="psd-control"):
        f.handle(message, 0.0)
    assert f.command.open  # nothing changed


def test_a_psd_control_needs_at_least_one_frame() -> None:
    with pytest.raises(InterlockError):
        PsdFollower(confirm_frames=0)
    with pytest.raises(InterlockError):
        PsdFollower(lost_limit_frames=0)
    with pytest.raises(InterlockError):
        PsdFollower(lock_frames=-1)
    with pytest.raises(InterlockError, match="platform"):
        PlatformUnit(lamp_table=PLATFORM.lamps()).handle(DoorCameraFrame(shape=OPEN_), 0.0)


_EVENTS = st.one_of(
    st.booleans().map(lambda b: ("relay", b)),
    st.sampled_from([OPEN_, MOVING_, CLOSED_, None]).map(lambda s: ("frame", s)),
)


@settings(max_examples=300, deadline=None)
@given(
    confirm=st.integers(1, 4),
    lost=st.integers(1, 6),
    lock=st.integers(0, 4),
    events=st.lists(_EVENTS, max_size=80),
)
def test_the_psd_command_follows_only_confirmed_shapes_under_the_relay(
    confirm: int, lost: int, lock: int, events: list[tuple[str, Any]]
) -> None:
    """Against a plain reading of the rules, for any sequence of relay changes and frames."""
    f = follower(confirm, lost, lock)
    on = False
    readable: list[str] = []  # the readable frames since the camera was last lost
    shape: str | None = None  # the last shape seen in confirm readable frames in a row since then
    since: list[str | None] = []  # every frame, to find the last run of "closed" ones
    unreadable = 0
    cmd = PsdCommand(open=False, camera_ok=True)
    for kind, value in events:
        if kind == "relay":
            on = bool(value)
            got = relay(f, on)
        else:
            got = frames(f, value)
            since.append(value)
            if value is None:
                unreadable += 1
                if unreadable >= lost:
                    readable, shape = [], None
            else:
                unreadable = 0
                readable.append(value)
                if len(readable) >= confirm and len(set(readable[-confirm:])) == 1:
                    shape = value
        closed_run = 0
        for v in reversed(since):
            if v != CLOSED_:
                break
            closed_run += 1
        locked = closed_run >= 2 * (confirm - 1) + lock + 1
        assert f.camera_ok() == (unreadable < lost)
        assert got == ([] if f.command == cmd else [f.command])  # a message only on a change
        if f.command.open and not cmd.open:
            assert on and shape == OPEN_ and f.camera_ok()  # never opens without the relay
        if cmd.open and not f.command.open:
            assert locked  # SPEC §5 order: never closes before the doors count as locked
        if not f.camera_ok():
            assert f.command.open == cmd.open  # lost: held where it was
        cmd = f.command


# ----------------------------------------------------------------------------- the camera


def test_classify_three_shapes_lost_frames_and_misreads() -> None:
    from railstop.sensors.door_camera import classify, true_shape

    p = DoorCamera(lost_frame_probability=0.1, misread_probability=0.2, open_fraction=0.3)
    # "closed" only fully shut; "open" from open_fraction; "moving" in between.
    cases = {0.0: CLOSED_, 1e-6: MOVING_, 0.29: MOVING_, 0.3: OPEN_, 1.0: OPEN_}
    for x, truth in cases.items():
        assert true_shape(x, p) == truth
        # A draw below the lost probability: unreadable, whatever the doors and the misread draw.
        assert classify(x, 0.0, 0.9, p) is None and classify(x, 0.099, 0.0, p) is None
        assert classify(x, 0.1, 0.9, p) == truth and classify(x, 0.99, 0.2, p) == truth
        # A draw below the misread probability: one of the two other shapes, each half the time.
        low, high = classify(x, 0.5, 0.0, p), classify(x, 0.5, 0.199, p)
        assert {low, high} == {OPEN_, MOVING_, CLOSED_} - {truth}
        assert classify(x, 0.5, 0.099, p) == low and classify(x, 0.5, 0.1, p) == high
    perfect = DoorCamera(lost_frame_probability=0.0, misread_probability=0.0)
    assert classify(0.9, 0.0, 0.0, perfect) == OPEN_ and classify(0.01, 0.0, 0.0, perfect) == MOVING_


def test_the_dwell_refuses_a_lock_confirmation_shorter_than_the_doors_lock() -> None:
    camera = PLATFORM.camera.model_copy(update={"lock_confirm_s": TIMING.train_door_lock_s / 2})
    with pytest.raises(ConfigError, match=r"camera\.lock_confirm_s"):
        dwell(0.1, platform=PLATFORM.model_copy(update={"camera": camera}))


@pytest.mark.parametrize(
    ("old", "new", "field", "value"),
    [
        ("confirm_frames = 3", "confirm_frames = 0", "camera.confirm_frames", "0"),
        ("lost_limit_frames = 10", "lost_limit_frames = 0", "camera.lost_limit_frames", "0"),
        ("misread_probability = 0.01", "misread_probability = 0.5", "camera.misread_probability", "0.5"),
        ("open_fraction = 0.3", "open_fraction = 1.0", "camera.open_fraction", "1.0"),
        ("frame_period_s = 0.1", "frame_period_s = -0.1", "camera.frame_period_s", "-0.1"),
        ("processing_delay_s = 0.3", "processing_delay_s = nan", "camera.processing_delay_s", "nan"),
    ],
)
def test_a_bad_camera_value_is_refused_naming_file_field_and_value(
    tmp_path: Path, old: str, new: str, field: str, value: str
) -> None:
    text = (resources.files("railstop.data") / "platform.toml").read_text(encoding="utf-8")
    assert old in text
    bad = tmp_path / "platform.toml"
    bad.write_text(text.replace(old, new), encoding="utf-8")
    with pytest.raises(ConfigError) as exc:
        load_platform(bad)
    msg = str(exc.value)
    assert str(bad) in msg and field in msg and value in msg


def test_the_embedded_camera_needs_more_than_one_frame_to_move_the_psd() -> None:
    # platform.toml: "a misread frame cannot move the PSD"; the default is the embedded file's.
    assert PLATFORM.camera == default_platform().camera
    assert CAMERA.confirm_frames >= 2


# ----------------------------------------------------------------------------- the dwell


@pytest.mark.parametrize("seed", [1, 2, 3])
@pytest.mark.parametrize("stop_error_m", [-0.2, 0.0, 0.2])
def test_a_stand_in_the_window_serves_the_platform_psd_master_train_slave(
    seed: int, stop_error_m: float
) -> None:
    r = dwell(stop_error_m, seed)
    assert r.outcome == "departed" and r.first_lamp == "OK" and r.psd_opened
    assert r.doors_open_s is not None and r.departure_s is not None
    assert r.departure_s > r.doors_open_s + TIMING.dwell_s  # the doors stayed open a full dwell
    assert {e.signal for e in r.timeline} <= set(SIGNALS)
    states = instants(r.timeline)
    assert set(states[0][1]) == set(SIGNALS)  # every signal is logged at the start
    assert states[0][1]["PSD"] == "closed_locked" and states[0][1]["lamp"] == "-"
    for t, s in states:
        # SPEC §3: departure only with the PSD closed and locked; the train moves only with it.
        if s["departure_permitted"] == 1:
            assert psd_locked(s["PSD"]), (t, s)
        if s["moving"] == 1:
            assert psd_locked(s["PSD"]) and s["train_doors"] == "closed_locked", (t, s)
        assert not (s["psd_command"] == "open" and s["psd_relay"] == 0), (t, s)
    for t, s in becomes(states, "PSD", "opening"):
        assert s["psd_relay"] == 1 and s["lamp"] == "OK", t  # the PSD opens only under OK
    # The PSD follows the train doors (the camera's delay): opens after them, closes after them.
    assert first(states, "PSD", "opening") > first(states, "train_doors", "opening")
    assert first(states, "PSD", "closing") > first(states, "train_doors", "closing")
    # SPEC §5 order (closing: train doors first, then the PSD): it starts closing only once they
    # are closed and locked.
    for t, s in becomes(states, "PSD", "closing"):
        assert s["train_doors"] == "closed_locked", (t, s)
    moved = first(states, "moving", 1)
    assert moved == pytest.approx(r.departure_s)
    assert moved > first(states, "PSD", "closed_locked") > first(states, "PSD", "closing")
    # S: the PSD has operated and is closed again, before the train leaves.
    assert first(states, "PSD", "closing") < first(states, "lamp", "S") <= moved
    assert "PSD opened" in dwell_sentence(r) and r.summary()["outcome"] == "departed"


@pytest.mark.parametrize(("stop_error_m", "lamp"), [(0.6, "R"), (-0.6, "F"), (1.5, "R"), (-2.0, "F")])
def test_a_stand_outside_the_window_never_opens_a_door(stop_error_m: float, lamp: str) -> None:
    assert abs(stop_error_m) > HALF_WINDOW_M + 0.1
    r = dwell(stop_error_m)
    assert r.outcome == "not-aligned" and r.first_lamp == lamp and not r.psd_opened
    assert values(r, "lamp") == {"-", lamp}
    assert values(r, "psd_relay") == {0} and values(r, "psd_command") == {"close"}
    assert values(r, "PSD") == {"closed_locked"} and values(r, "train_doors") == {"closed_locked"}
    assert r.doors_open_s is None and r.departure_s is not None
    assert r.departure_s >= TIMING.dwell_s  # he waits a whole dwell for an OK that never comes
    assert "PSD opened" not in dwell_sentence(r)


@pytest.mark.parametrize(("stop_error_m", "key"), [(0.6, (True, True)), (-0.6, (False, False))])
def test_a_fault_in_the_lamp_table_lights_nothing_and_holds_the_psd(
    stop_error_m: float, key: tuple[bool, bool]
) -> None:
    """A valid lamp table that calls a combination a sensor fault: no lamp, no relay, no doors."""
    data = PLATFORM.model_dump()
    data["lamp_table"] = [
        {**row, "lamp": "fault"} if (bool(row["s2"]), bool(row["s1"])) == key else row
        for row in data["lamp_table"]
    ]
    faulty = PlatformFile.model_validate(data)
    r = dwell(stop_error_m, platform=faulty)
    assert r.outcome == "not-aligned" and r.first_lamp is None
    assert values(r, "lamp") == {"-"} and values(r, "psd_relay") == {0}
    assert values(r, "PSD") == {"closed_locked"} and values(r, "train_doors") == {"closed_locked"}
    assert r.departure_s is not None and r.departure_s >= TIMING.dwell_s


def test_a_camera_lost_with_the_psd_open_holds_it_open_until_staff_close_it() -> None:
    normal = dwell(0.1, seed=2)
    opened_at = first(instants(normal.timeline), "PSD", "opening")
    lost_from = opened_at + 4.0  # well after the PSD opened, long before the doors close
    assert lost_from + CAMERA.lost_limit_frames * CAMERA.frame_period_s < normal.doors_open_s + TIMING.dwell_s
    r = dwell(0.1, seed=2, camera_lost_from_s=lost_from)
    assert r.outcome == "staff-closed" and r.psd_opened and r.camera_lost_frames > 0
    states = instants(r.timeline)
    t_lost = first(states, "camera", "lost")
    assert lost_from <= t_lost <= lost_from + CAMERA.lost_limit_frames * CAMERA.frame_period_s + STEP_S
    # Held open: the train doors close and lock while the PSD stays open (DESIGN rule 10).
    t_doors = first(states, "train_doors", "closed_locked")
    assert t_doors > t_lost
    for t, s in states:
        if t_lost <= t < t_doors + 5.0:
            assert s["PSD"] == "open" and s["psd_command"] == "open" and s["departure_permitted"] == 0, (t, s)
    # Staff close it at the local panel staff_isolation_s after the control lost the doors.
    t_staff = first(states, "PSD", "closing")
    assert t_staff == pytest.approx(t_lost + TIMING.staff_isolation_s, abs=2 * STEP_S)
    t_locked = first(states, "PSD", "closed_locked (staff)")
    for t, s in states:
        if s["departure_permitted"] == 1 or s["moving"] == 1:
            assert psd_locked(s["PSD"]), (t, s)
    assert r.departure_s is not None and normal.departure_s is not None
    assert r.departure_s > t_locked and r.departure_s > normal.departure_s
    assert "staff" in dwell_sentence(r)


def test_a_camera_lost_from_the_start_keeps_the_psd_shut_in_front_of_open_train_doors() -> None:
    r = dwell(0.1, seed=2, camera_lost_from_s=0.0)
    assert r.outcome == "psd-held" and not r.psd_opened and r.first_lamp == "OK"
    assert r.doors_open_s is not None  # the driver had OK and opened his doors
    assert r.camera_lost_frames == r.camera_frames
    assert values(r, "PSD") == {"closed_locked"} and values(r, "psd_command") == {"close"}
    assert "open" in values(r, "train_doors") and "lost" in values(r, "camera")
    assert r.departure_s is not None
    for t, s in instants(r.timeline):
        if s["moving"] == 1:
            assert s["train_doors"] == "closed_locked", (t, s)


def test_the_signal_open_switch_passes_the_train_with_no_lamp_and_no_door() -> None:
    r = dwell(0.0, signal_open=True)
    assert r.outcome == "passed" and r.first_lamp is None and not r.psd_opened
    assert values(r, "signal_open") == {1} and values(r, "lamp") == {"-"}
    assert values(r, "psd_relay") == {0} and values(r, "PSD") == {"closed_locked"}
    assert values(r, "train_doors") == {"closed_locked"} and r.doors_open_s is None
    assert r.departure_s is not None and r.departure_s < TIMING.dwell_s  # no dwell at all


def test_a_train_running_through_with_the_switch_on_lights_no_lamp_and_moves_no_door() -> None:
    # SPEC §3: the signal-open switch lets a train pass the station: it never stands; its front
    # crosses both stop sensors at speed, no lamp lights, the PSD relay stays off.
    r = dwell(0.0, signal_open=True, passing_mps=15.0)
    assert r.outcome == "passed" and r.passing_kmh == pytest.approx(54.0)
    assert r.first_lamp is None and not r.psd_opened and r.doors_open_s is None
    assert values(r, "lamp") == {"-"} and values(r, "psd_relay") == {0}
    assert values(r, "PSD") == {"closed_locked"} and values(r, "train_doors") == {"closed_locked"}
    assert values(r, "moving") == {1}  # never a stand
    assert "no lamp lit, PSD closed throughout, train doors inhibited" in dwell_sentence(r)
    # Running through needs the switch, and a speed.
    for bad in ({"signal_open": False, "passing_mps": 15.0}, {"signal_open": True, "passing_mps": 0.0}):
        with pytest.raises(SimulationError, match="passing_mps"):
            dwell(0.0, **bad)


def test_platform_dwell_with_the_switch_on_runs_a_drivers_train_through(tmp_path: Path) -> None:
    res = CliRunner().invoke(
        app, ["platform", "dwell", "--signal-open", "--db", str(tmp_path / "d.db"), "--json"]
    )
    assert res.exit_code == 0, res.output
    out = json.loads(res.output)
    assert out["outcome"] == "passed" and out["first_lamp"] is None and not out["psd_opened"]
    assert out["passing_kmh"] > 40.0 and "run through the station" in out["source"]


def test_a_station_without_psd_departs_once_the_train_doors_are_locked() -> None:
    r = dwell(0.1, psd=False)
    assert r.outcome == "departed" and r.first_lamp == "OK" and not r.psd_opened
    assert not ({e.signal for e in r.timeline} & PSD_SIGNALS)
    assert r.camera_frames == 0
    states = instants(r.timeline)
    assert set(states[0][1]) == set(SIGNALS) - PSD_SIGNALS
    assert (
        first(states, "moving", 1)
        > first(states, "train_doors", "closed_locked")
        > first(states, "train_doors", "open")
    )
    # The same stand with the PSD takes longer: the PSD closes after the train doors.
    with_psd = dwell(0.1)
    assert with_psd.departure_s is not None and r.departure_s is not None
    assert with_psd.departure_s > r.departure_s


def test_a_dwell_is_a_function_of_its_seed_and_counter() -> None:
    a = dwell(0.1, seed=5)
    assert dwell(0.1, seed=5) == a  # identical, timeline included
    others = [dwell(0.1, seed=s) for s in (6, 7, 8)] + [dwell(0.1, seed=5, counter=1)]
    draws = {(r.camera_misreads, r.camera_lost_frames, r.timeline) for r in [a, *others]}
    assert len(draws) > 1


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), float("-inf")])
def test_a_non_finite_stand_or_fault_time_is_refused(bad: float) -> None:
    with pytest.raises(SimulationError, match="stop_error_m"):
        dwell(bad)
    with pytest.raises(SimulationError, match="camera_lost_from_s"):
        dwell(0.0, camera_lost_from_s=bad)
    with pytest.raises(SimulationError, match="camera_lost_from_s"):
        dwell(0.0, camera_lost_from_s=-1.0)


# ----------------------------------------------------------------------------- after a driver stop


@pytest.mark.parametrize("seed", [0, 1, 3, 13])
def test_a_driver_stop_timeline_has_one_stand_per_stop_then_its_dwell(seed: int) -> None:
    result, batch = run_stop(line=LINE, station=STATION, vehicle=VEHICLE, controller="driver-ats", seed=seed)
    assert result.stopped
    d, timeline = dwell_after_stop(result, batch, station=STATION, platform=PLATFORM, doors=DOORS)
    assert d.stop_error_m == result.stop_error_m and d.outcome in OUTCOMES
    events, final = stand_events(batch, stop_point_m=STATION.stop_point_m)
    assert final is not None
    stands = [e.value for e in events if e.signal == "stand_error_m"]
    assert len(stands) == result.restops + 1  # each stand lights a lamp; a re-stop is a stand
    assert stands[0] == pytest.approx(result.first_stop_error_m, abs=1e-4)
    assert stands[-1] == pytest.approx(result.stop_error_m, abs=1e-4)
    times = [e.t_s for e in timeline]
    assert times == sorted(times)
    assert all(e.t_s >= final - 1e-3 for e in timeline[len(events) :])  # the dwell from the last stand
    assert len(timeline) > len(events)


def test_custom_driver_data_decides_the_level_and_the_key() -> None:
    experts = expert_only()
    for seed in range(10):
        own, _ = run_stop(
            line=LINE, station=STATION, vehicle=VEHICLE, controller="driver-ats", seed=seed, driver=experts
        )
        assert own.driver_level == "expert" and own.manual_data_sha256 is not None
        assert f"|manual-data={own.manual_data_sha256[:16]}" in own.run_key
    embedded = [
        run_stop(line=LINE, station=STATION, vehicle=VEHICLE, controller="driver-ats", seed=s)[0]
        for s in range(10)
    ]
    assert {r.driver_level for r in embedded} != {"expert"}  # the embedded shares draw other levels
    assert all(r.manual_data_sha256 is None and "manual-data" not in r.run_key for r in embedded)
    assert own.run_key != embedded[-1].run_key and own.inputs_sha256 != embedded[-1].inputs_sha256


def test_a_campaign_manifest_names_custom_manual_data_only() -> None:
    def spec(**kw: Any) -> CampaignSpec:
        return CampaignSpec(
            line=LINE,
            vehicle=VEHICLE,
            station=STATION.name,
            controller="driver-ats",
            runs=100,
            seed=1,
            disturbances=load_disturbances("standard"),
            **kw,
        )

    embedded = spec().manifest()
    assert "manual_data_sha256" not in embedded
    custom = spec(driver=expert_only()).manifest()
    plat = spec(platform=PLATFORM.model_copy(update={"camera": DoorCamera(confirm_frames=5)})).manifest()
    assert custom["manual_data_sha256"] != plat["manual_data_sha256"]
    assert {k: v for k, v in custom.items() if k != "manual_data_sha256"} == embedded
    assert len({spec().identity(), spec(driver=expert_only()).identity()}) == 2
    # A resume must be given the same data.
    with pytest.raises(RailstopError, match="driver or platform data"):
        spec_from_manifest(custom, LINE, VEHICLE, "m.json")
    with pytest.raises(RailstopError, match="driver or platform data"):
        spec_from_manifest(embedded, LINE, VEHICLE, "m.json", driver=expert_only())
    again = spec_from_manifest(custom, LINE, VEHICLE, "m.json", driver=expert_only())
    assert again.manifest() == custom


# ----------------------------------------------------------------------------- commands


def test_cli_platform_dwell_from_a_given_stand_saves_its_timeline(tmp_path: Path) -> None:
    proc = cli(tmp_path, "platform", "dwell", "--stop-error-m", "0.1", "--db", "d.db", "--json")
    assert proc.returncode == 0, proc.stderr
    out = json.loads(proc.stdout)
    assert out["outcome"] == "departed" and out["stop_error_m"] == 0.1
    with open_store(tmp_path / "d.db") as store:
        assert store.dwell_keys() == [out["dwell_key"]]
        saved = store.dwell_events(out["dwell_key"])
    assert len(saved) == len(out["timeline"]) > 0
    assert [(e["t_s"], e["signal"], e["value"]) for e in saved] == [
        (e["t_s"], e["signal"], e["value"]) for e in out["timeline"]
    ]
    for t, s in instants(saved):
        if s["departure_permitted"] == 1:
            assert psd_locked(s["PSD"]), (t, s)


def test_cli_platform_dwell_refuses_a_stand_that_is_not_a_number(tmp_path: Path) -> None:
    line = one_error_line(cli(tmp_path, "platform", "dwell", "--stop-error-m", "abc", "--db", "d.db"))
    assert "--stop-error-m" in line and "abc" in line
    assert not (tmp_path / "d.db").exists()  # refused before anything was written


def test_cli_platform_dwell_takes_only_a_driver_controller(tmp_path: Path) -> None:
    line = one_error_line(cli(tmp_path, "platform", "dwell", "--controller", "tasc-pwm", "--db", "d.db"))
    assert "--controller" in line and "tasc-pwm" in line
    assert not (tmp_path / "d.db").exists()


def test_cli_platform_dwell_after_a_driver_stop_plots_and_saves_the_stands(tmp_path: Path) -> None:
    proc = cli(tmp_path, "platform", "dwell", "--seed", "3", "--plot", "p.png", "--db", "d.db", "--json")
    assert proc.returncode == 0, proc.stderr
    out = json.loads(proc.stdout)
    png = tmp_path / "p.png"
    assert png.exists() and png.stat().st_size > 0 and png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    with open_store(tmp_path / "d.db") as store:
        (key,) = store.dwell_keys()
        saved = store.dwell_events(key)
    assert key == out["dwell_key"] and "|platform-dwell" in key and key.startswith("stop|")
    stands = [e["value"] for e in saved if e["signal"] == "stand_error_m"]
    assert stands and stands[-1] == pytest.approx(out["stop_error_m"], abs=1e-4)
    assert len(saved) == len(out["timeline"])


def test_cli_stop_with_a_driver_runs_the_dwell_and_saves_its_timeline(tmp_path: Path) -> None:
    proc = cli(tmp_path, "stop", "--controller", "driver-ats", "--seed", "3", "--db", "s.db", "--json")
    assert proc.returncode == 0, proc.stderr
    out = json.loads(proc.stdout)
    pd = out["platform_dwell"]
    assert pd["outcome"] in OUTCOMES and pd["stop_error_m"] == out["stop_error_m"]
    with open_store(tmp_path / "s.db") as store:
        keys = [k for k in store.dwell_keys() if k.endswith("|platform-dwell")]
        assert len(keys) == 1 and keys[0].startswith("stop|") and "driver-ats" in keys[0]
        saved = store.dwell_events(keys[0])
    assert {"lamp", "stand_error_m", "train_doors"} <= {e["signal"] for e in saved}


def test_cli_stop_prints_a_dwell_line_only_for_a_driver() -> None:
    runner = CliRunner()
    res = runner.invoke(app, ["stop", "--controller", "driver-ats", "--seed", "3", "--no-db"])
    assert res.exit_code == 0, res.output
    assert sum(line.startswith("dwell: ") for line in res.stdout.splitlines()) == 1
    res = runner.invoke(app, ["stop", "--controller", "tasc-pwm", "--seed", "3", "--no-db", "--json"])
    assert res.exit_code == 0, res.output
    assert "platform_dwell" not in json.loads(res.stdout)


def test_cli_stop_refuses_driver_data_for_a_tasc_controller(tmp_path: Path) -> None:
    data = (resources.files("railstop.data") / "driver.toml").read_text(encoding="utf-8")
    (tmp_path / "driver.toml").write_text(data, encoding="utf-8")
    line = one_error_line(
        cli(tmp_path, "stop", "--controller", "tasc-pwm", "--driver", "driver.toml", "--no-db")
    )
    assert "--driver" in line and "tasc-pwm" in line


def test_cli_stop_refuses_a_bad_driver_file_naming_it(tmp_path: Path) -> None:
    data = (resources.files("railstop.data") / "driver.toml").read_text(encoding="utf-8")
    assert "share = 0.6" in data
    (tmp_path / "mine.toml").write_text(data.replace("share = 0.6", "share = 0.5"), encoding="utf-8")
    line = one_error_line(
        cli(tmp_path, "stop", "--controller", "driver-ats", "--driver", "mine.toml", "--db", "s.db")
    )
    assert "mine.toml" in line and "levels" in line
    assert not (tmp_path / "s.db").exists()


def test_dwell_event_is_what_the_store_takes(tmp_path: Path) -> None:
    r = dwell(0.0)
    with open_store(tmp_path / "x.db") as store:
        store.save_dwell(key="k", station=STATION.name, events=r.timeline)
        store.save_dwell(key="k", station=STATION.name, events=r.timeline)  # again: not duplicated
        assert store.dwell_keys() == ["k"]
        back = store.dwell_events("k")
    assert [DwellEvent(t_s=e["t_s"], signal=e["signal"], value=e["value"]) for e in back] == list(r.timeline)


# ----------------------------------------------------------------------------- regressions
# Each of these once failed: a dwell that never ended, doors opened without OK, the PSD shut in
# front of open train doors by sensor noise at a window edge.


def test_psd_leaves_told_to_open_and_close_before_moving_lock_again() -> None:
    psd = _Leaves(TIMING.psd_open_s, TIMING.psd_close_s, TIMING.psd_lock_s)
    psd.command(True, 0.0)
    psd.command(False, 0.0)
    for i in range(round((TIMING.psd_lock_s + 1.0) / STEP_S)):
        psd.step(i * STEP_S, STEP_S)
    assert psd.state(TIMING.psd_lock_s + 1.0) == "closed_locked"


def test_the_driver_opens_the_train_doors_only_under_ok_at_a_window_edge() -> None:
    for seed in range(6):
        for err in (-(HALF_WINDOW_M + 0.005), HALF_WINDOW_M + 0.005):
            r = dwell(err, seed)
            for t, s in becomes(instants(r.timeline), "train_doors", "opening"):
                assert s["lamp"] == "OK", (seed, err, t, s["lamp"])


def test_the_psd_never_starts_closing_onto_open_train_doors_at_a_stand_inside_the_window() -> None:
    for seed in range(6):
        for err in (-(HALF_WINDOW_M - 0.005), HALF_WINDOW_M - 0.005):
            r = dwell(err, seed)
            for t, s in becomes(instants(r.timeline), "PSD", "closing"):
                assert s["train_doors"] not in ("open", "opening"), (seed, err, t)


@pytest.mark.parametrize("seed", range(1, 13))
def test_the_psd_never_starts_closing_before_the_train_doors_are_closed_and_locked(seed: int) -> None:
    """SPEC §3 with the camera, SPEC §5 order: over stands across the window and many camera draws
    (misreads at a tenth of the frames), every PSD closing starts with the train doors locked."""
    camera = PLATFORM.camera.model_copy(update={"misread_probability": 0.1})
    platform = PLATFORM.model_copy(update={"camera": camera})
    stand = -0.3 + 0.05 * (seed - 1)
    r = dwell(stand, seed=seed, platform=platform)
    assert r.outcome == "departed"
    states = instants(r.timeline)
    closings = becomes(states, "PSD", "closing")
    assert closings
    for t, s in closings:
        assert s["train_doors"] == "closed_locked" and s["camera"] == "closed_locked", (t, s)
    assert first(states, "PSD", "closing") > first(states, "train_doors", "closed_locked")
