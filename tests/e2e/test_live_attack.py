"""The live line under attack (``benchmarks/live_attack.py``, reduced) and the rules it checks: the
restart floor of every live link, no link made for a forged destination, no assert on received
data. Real processes and real sockets on loopback."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from bench_loader import load_benchmark
from railstop.config import default_line, default_vehicle
from railstop.config.doors import load_doors
from railstop.link.cbtc_radio import TRAIN_BASE, ZC_ADDRESS, CbtcEndpoint, to_telegram
from railstop.link.codec import encode
from railstop.link.safety import SafePeers
from railstop.live.doors import PLATFORM_BASE, TRAIN_DOORS_BASE, LiveDoors
from railstop.messages import MovementCommand, PositionReport

KEY = os.urandom(32)
ENV = {**os.environ, "RAILSTOP_OFFICE_KEY": KEY.hex()}


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _start(args: list[str], ready: str, *, optimise: bool = False) -> tuple[subprocess.Popen[str], str]:
    """The process started, and the line it said when ready."""
    exe = [sys.executable, *(["-O"] if optimise else []), "-m", "railstop.cli"]
    p = subprocess.Popen([*exe, *args], env=ENV, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert p.stderr is not None
    line = p.stderr.readline()
    if ready not in line:
        p.kill()
        raise AssertionError(f"{args[:2]} did not start: {line}{p.communicate()[1]}")
    return p, line


def _stop(p: subprocess.Popen[str]) -> dict[str, object]:
    p.send_signal(signal.SIGTERM)
    out, err = p.communicate(timeout=30)
    assert p.returncode == 0, err
    return dict(json.loads(out.strip().splitlines()[-1]))


def _report(train: int, x_m: float, t_s: float) -> PositionReport:
    u = default_line().cbtc.position_uncertainty_m
    return PositionReport(
        train_id=train, position_m=x_m, speed_mps=0.0, direction="R", time_s=t_s, uncertainty_m=u
    )


# ---------------------------------------------------------------------- the restart floor


def test_a_restarted_plant_refuses_a_drive_captured_before_its_restart_and_replayed_after_it() -> None:
    """EN 50159 repetition across a restart of the receiver: a drive the plant delivered, captured
    on the wire, is replayed to the plant started again (kill -9) while still fresh (the run's clock
    at scale 0.1: a second of frame age is ten wall seconds). The new plant refuses it
    (``old_session``: sent before it started) and answers nothing; a drive sent after its start is
    delivered (the refusal is the floor's, not a broken link)."""
    from railstop.live.plant import PLANT_ID, TRAINS_WIRING_ID, Drive, pack_drives

    scale, epoch, port = 0.1, time.time(), _free_port()
    args = ["live", "plant", "--port", str(port), "--trains", "1", "--spacing-m", "800", "--epoch",
            repr(epoch), "--scale", repr(scale)]  # fmt: skip

    def now() -> float:
        return (time.time() - epoch) * scale

    trains = SafePeers(TRAINS_WIRING_ID, KEY, max_age_s=1.0, peers=lambda p: p == PLANT_ID)
    payload = pack_drives([(0, Drive(1.0, 1.0, 1.0))])[0]
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", 0))
        sock.settimeout(2.0)
        plant, _ = _start(args, "plant on")
        try:
            captured = trains.wrap(payload, PLANT_ID, now())
            sock.sendto(captured, ("127.0.0.1", port))
            sock.recv(4096)  # delivered: the plant answers with the trains' states
        finally:
            plant.kill()
            plant.wait(timeout=30)
        plant, _ = _start(args, "plant on")
        try:
            sock.settimeout(0.2)
            while True:  # what the first plant sent before it died
                try:
                    sock.recv(4096)
                except TimeoutError:
                    break
            sock.sendto(captured, ("127.0.0.1", port))  # the replay
            sock.settimeout(1.5)
            with pytest.raises(TimeoutError):
                sock.recv(4096)  # not delivered: no state comes back
            sock.sendto(trains.wrap(payload, PLANT_ID, now()), ("127.0.0.1", port))
            sock.settimeout(3.0)
            sock.recv(4096)  # a drive sent after its start is delivered
        finally:
            counts = _stop(plant)
    assert counts["refused"] == {"old_session": 1}
    assert counts["delivered"] == 1


def test_a_train_radio_refuses_a_frame_sent_before_its_process_started() -> None:
    """The trains' and the zone controller's radios take ``started_s``: a command sent before it is
    refused (``old_session``), one sent after is delivered."""
    zc = SafePeers(ZC_ADDRESS, KEY, max_age_s=1.0, peers=lambda p: True)
    radio = CbtcEndpoint(own_id=TRAIN_BASE, master_key=KEY, started_s=100.0, peers=lambda p: p == ZC_ADDRESS)
    cmd = MovementCommand(
        train_id=0,
        authority_m=300.0,
        gradient_permille=0.0,
        speed_limit_mps=20.0,
        report_time_s=99.0,
        delay_s=0.0,
    )
    tele = to_telegram(cmd)
    assert tele is not None
    before = zc.wrap(encode(tele), TRAIN_BASE, 99.95)
    assert radio.ingest(before, 100.1, to=str) == []
    assert radio.links.rejected == {"old_session": 1}
    after = zc.wrap(encode(tele), TRAIN_BASE, 100.05)
    assert [o.message for o in radio.ingest(after, 100.1, to=str)] == [cmd]


# ---------------------------------------------------------------------- no assert on received data


def test_a_command_frame_sent_to_the_zone_controller_is_refused_and_counted() -> None:
    """A key holder sends the zone controller (run under ``python -O``) a command frame and a report
    naming another train, both under valid MACs: each is refused and counted, the controller goes
    on serving (it answers the genuine report after them) and stops cleanly."""
    epoch = time.time()
    zc, line = _start(["live", "zc", "--port", "0", "--trains", "1", "--new", "--epoch", repr(epoch),
                       "--scale", "1"], "zone controller on", optimise=True)  # fmt: skip
    counts: dict[str, object] = {}
    try:
        addr = ("127.0.0.1", int(line.split("127.0.0.1:")[1].split()[0]))
        radio = CbtcEndpoint(own_id=TRAIN_BASE, master_key=KEY, peers=lambda p: p == ZC_ADDRESS)
        cmd = MovementCommand(
            train_id=0,
            authority_m=1e4,
            gradient_permille=0.0,
            speed_limit_mps=30.0,
            report_time_s=0.0,
            delay_s=0.0,
        )
        tele = to_telegram(cmd)
        other = to_telegram(_report(1, 1000.0, time.time() - epoch))
        assert tele is not None and other is not None
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
            sock.bind(("127.0.0.1", 0))
            sock.settimeout(3.0)
            sock.sendto(radio.links.wrap(encode(tele), ZC_ADDRESS, time.time() - epoch), addr)
            sock.sendto(radio.links.wrap(encode(other), ZC_ADDRESS, time.time() - epoch), addr)
            time.sleep(0.3)
            radio.handle(_report(0, 1000.0, time.time() - epoch), time.time() - epoch)
            for frame, _ in radio.outgoing:
                sock.sendto(frame, addr)
            answer = sock.recv(4096)  # the controller still serves: a command for train 0
            got = radio.ingest(answer, time.time() - epoch, to=str)
            assert [type(o.message) for o in got] == [MovementCommand]
    finally:
        counts = _stop(zc)
    rejected = counts["radio"]["rejected"]  # type: ignore[index]
    assert rejected == {"unexpected-type": 1, "train-mismatch": 1}, rejected


# ---------------------------------------------------------------------- forged destinations


@settings(max_examples=40, deadline=None)
@given(dst=st.integers(0, 0xFFFF))
def test_a_status_for_no_train_of_this_process_makes_no_link(dst: int) -> None:
    """A psd-status frame's destination names the train it is for; one that is no train of this
    process (however the header is forged) is refused and counted before any link exists for it,
    so a flood of forged destinations makes the process hold nothing."""
    doors = LiveDoors(
        line=default_line(), doors=load_doors(), stations=("127.0.0.1", 9), master_key=KEY, trains=2
    )
    # The platform's own id cannot be the destination of what it sends (its sender refuses the
    # reflection); a frame forged so is another test's (a header naming the receiver itself).
    assume(dst != PLATFORM_BASE)
    platform = SafePeers(PLATFORM_BASE, KEY, max_age_s=1.0, peers=lambda p: True)
    doors.ingest(platform.wrap(b"\x00" * 8, dst, 1.0), 1.0)
    train = dst - TRAIN_DOORS_BASE
    if 0 <= train < 2:
        assert list(doors._links) == [train]
        assert doors.counts()["refused"].get("not_a_train_here", 0) == 0
    else:
        assert doors._links == {}
        assert doors.counts()["refused"] == {"not_a_train_here": 1}


def test_a_telegram_for_no_train_of_this_process_makes_no_link() -> None:
    """As above for the braking telegrams of ground TASC (``LiveTasc``)."""
    from railstop.config.disturbances import load_disturbances
    from railstop.live.tasc import STATION_BASE, TRAIN_TASC_BASE, LiveTasc

    side = LiveTasc(
        line=default_line(), vehicle=default_vehicle(), controller="tasc-pwm", stations=("127.0.0.1", 9),
        master_key=KEY, dist=load_disturbances("nominal"), seed=1, trains=2,
    )  # fmt: skip
    station = SafePeers(STATION_BASE, KEY, max_age_s=1.0, peers=lambda p: True)
    forged = [TRAIN_TASC_BASE + 2, TRAIN_TASC_BASE + 63, TRAIN_TASC_BASE - 1, 0xFFFF, 0]
    for dst in forged:
        side.ingest(station.wrap(b"payload", dst, 1.0), 1.0)
    assert side._rx == {}
    assert side.counts()["telegrams_refused"] == {"not_a_train_here": len(forged)}
    side.ingest(station.wrap(b"payload", TRAIN_TASC_BASE + 1, 1.0), 1.0)
    assert list(side._rx) == [1]


# ---------------------------------------------------------------------- the attack, reduced


def test_a_reduced_attack_crashes_nothing_and_delivers_nothing_it_should_not(tmp_path: Path) -> None:
    """The attack benchmark, reduced: junk, forged ids, the replay of captured frames (before and
    after a kill -9 restart of the zone controller) against the five processes of a two-train line.
    No process crashes, no frame is delivered that should not be, no train moves without authority,
    and every attack datagram is refused or dropped where it is counted."""
    f = load_benchmark("live_attack").run(
        seconds=16.0, trains=2, spacing_m=800.0, flood_rate=0.0, flood_s=0.0, junk_per_target=40,
        restarts=("zone_controller",), workdir=tmp_path, settle_s=3.0, say=lambda *_: None,
    )  # fmt: skip
    t, procs = f["totals"], f["processes"]
    assert t["crashes"] == 0, procs
    assert t["bad_deliveries"] == 0, procs
    assert t["trains_moving_without_authority"] == 0, f["movement"]
    assert t["unaccounted"] == 0, procs
    # The attack reached every process, and the replays the restarted controller and the trains.
    assert all(procs[r]["attack_sent"] > 0 for r in procs)
    assert procs["zone_controller"]["replays_sent"] > 0 and procs["trains"]["replays_sent"] > 0
    assert procs["zone_controller"]["restarts"] == 1
    assert f["movement"]["states"] > 0  # the trains reported to the office throughout


def test_a_state_for_a_train_not_of_this_process_is_refused() -> None:
    """A plant frame (valid MAC) with a state record for a train outside the process's fleet: the
    record is refused and counted and only the process's own train is kept (and answered: the
    serving task answers what ``_take`` keeps; an index past the fleet would end that task)."""
    import math

    from railstop.live.plant import PlantPort, TrainState, pack_states, unpack_states

    port = PlantPort(2, master_key=KEY)
    rows = [
        TrainState(k, 100.0 * k, 0.0, None, math.nan, False, math.nan, math.nan, False, False) for k in (1, 7)
    ]
    kept = port._take(unpack_states(pack_states(rows)[0]))
    assert [s.train for s in kept] == [1]
    assert set(port.states) == {1}
    assert port.wiring.rejected == {"unknown_train": 1}
