"""The management office link and service (SPEC §1 claims 7, 20; issue 17 item 2).

The link ends are pure (``link.office_link``): tested with times as numbers.
The service is tested end to end: ``railstop office serve`` as a real process
on a loopback UDP port, a real client sending reports, the office killed with
SIGKILL in the middle and started again, and the database (a real SQLite file
and a real PostgreSQL server) holding every report exactly once.
"""

from __future__ import annotations

import asyncio
import os
import signal
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st

from railstop.link.office_link import (
    OfficeInbox,
    OfficeLinkError,
    OfficeOutbox,
)
from railstop.link.safety import link_key
from railstop.store import open_store
from zygote import run_cli

KEY = bytes(range(32))
OFFICE = 900


def ends(sender: int = 7, *, session: int = 11) -> tuple[OfficeOutbox, OfficeInbox]:
    out = OfficeOutbox(own_id=sender, office_id=OFFICE, master_key=KEY, session=session)
    inbox = OfficeInbox(own_id=OFFICE, master_key=KEY, senders=(sender,), session=99)
    return out, inbox


# ------------------------------------------------------------------ the pure link


def test_a_report_goes_through_and_its_acknowledgement_clears_it() -> None:
    out, inbox = ends()
    seq, frame = out.submit("stop-result", {"station": "Riverside", "error_m": 0.012}, 10.0)
    report, ack, reason = inbox.on_frame(frame, 10.01)
    assert reason is None and report is not None and ack is not None
    assert (report.sender_id, report.session, report.seq, report.kind) == (7, 11, seq, "stop-result")
    assert report.data == {"station": "Riverside", "error_m": 0.012}
    assert out.pending and out.on_frame(ack, 10.02) == seq and not out.pending


def test_an_unacknowledged_report_is_sent_again_as_a_new_frame_and_accepted_again() -> None:
    out, inbox = ends()
    _, first = out.submit("tasc-command", {"v": 1}, 0.0)
    assert out.due(0.5) == []  # not yet
    (again,) = out.due(1.0)  # resend_s
    assert again != first  # a new safety frame: not a replay
    r1, _, _ = inbox.on_frame(first, 1.0)
    r2, ack2, reason = inbox.on_frame(again, 1.0)
    # The office takes both (the store keeps one) and acknowledges both.
    assert r1 is not None and r2 is not None and (r1.session, r1.seq) == (r2.session, r2.seq)
    assert reason is None and ack2 is not None
    out.on_frame(ack2, 1.1)
    assert not out.pending and out.counts["resent"] == 1


def test_resending_is_bounded_to_a_window_of_the_oldest_reports() -> None:
    """1,000 reports gathered while the office was down: each resend sends the oldest 64 due, not
    all 1,000; as the office acknowledges them, the next oldest follow; nothing is skipped."""
    out, inbox = ends()
    for i in range(1000):
        out.submit("train-state", {"i": i}, 0.0)
    window = out.times.resend_window
    stored: list[int] = []
    t = 1.0
    while out.pending:
        frames = out.due(t)
        assert 0 < len(frames) <= window
        for frame in frames:
            report, ack, _ = inbox.on_frame(frame, t)
            assert report is not None and ack is not None
            stored.append(report.data["i"])
            out.on_frame(ack, t)
        t += 0.1
    assert stored == list(range(1000))  # the oldest first, each once


def test_a_replayed_frame_is_rejected() -> None:
    out, inbox = ends()
    _, frame = out.submit("dwell-event", {"s": "PSC"}, 0.0)
    assert inbox.on_frame(frame, 0.0)[0] is not None
    assert inbox.on_frame(frame, 0.1) == (None, None, "repeated")


def test_a_tampered_or_foreign_frame_is_rejected_with_its_reason() -> None:
    out, inbox = ends()
    _, frame = out.submit("zone-event", {"train": 3}, 0.0)
    bad = bytearray(frame)
    bad[len(bad) // 2] ^= 0x01
    assert inbox.on_frame(bytes(bad), 0.0)[2] == "bad_mac"
    stranger = OfficeOutbox(own_id=8, office_id=OFFICE, master_key=KEY, session=1)
    assert inbox.on_frame(stranger.submit("zone-event", {}, 0.0)[1], 0.0)[2] == "unknown_sender"
    wrong_key = OfficeOutbox(own_id=7, office_id=OFFICE, master_key=bytes(32), session=1)
    assert inbox.on_frame(wrong_key.submit("zone-event", {}, 0.0)[1], 0.0)[2] == "bad_mac"
    assert inbox.counts["bad_mac"] == 2 and inbox.counts["accepted"] == 0


def test_a_forged_acknowledgement_does_not_clear_a_report() -> None:
    out, inbox = ends()
    seq, frame = out.submit("stop-result", {}, 0.0)
    _, ack, _ = inbox.on_frame(frame, 0.0)
    assert ack is not None
    forged = bytearray(ack)
    forged[-1] ^= 0xFF
    assert out.on_frame(bytes(forged), 0.0) is None and seq in out.pending
    # An acknowledgement of another session (a former run of this sender) clears nothing either.
    other, _ = ends(session=12)
    _, frame2 = other.submit("stop-result", {}, 0.0)
    inbox2 = OfficeInbox(own_id=OFFICE, master_key=KEY, senders=(7,), session=98)
    _, ack2, _ = inbox2.on_frame(frame2, 0.0)
    assert ack2 is not None and out.on_frame(ack2, 0.0) is None and seq in out.pending


def test_a_restarted_sender_is_followed_and_an_old_session_replay_is_stale() -> None:
    out, inbox = ends(session=1)
    for i in range(3):
        inbox.on_frame(out.submit("train-state", {"i": i}, float(i))[1], float(i))
    old_frame = out.submit("train-state", {"i": 3}, 3.0)[1]
    inbox.on_frame(old_frame, 3.0)
    # The sender restarts: its safety sequence numbers start at 1 again, a new session.
    restarted = OfficeOutbox(own_id=7, office_id=OFFICE, master_key=KEY, session=2)
    report, ack, reason = inbox.on_frame(restarted.submit("train-state", {"i": 0}, 4.0)[1], 4.0)
    assert reason is None and report is not None and report.session == 2 and ack is not None
    # Someone replays the old session's frame later: refused (stale), the new session stays.
    assert inbox.on_frame(old_frame, 20.0)[2] == "stale"
    assert inbox.on_frame(restarted.submit("train-state", {"i": 1}, 20.0)[1], 20.0)[0] is not None


def test_a_fresh_frame_of_the_old_session_does_not_take_the_link_back() -> None:
    """Alternating frames of a sender's old and new sessions (both still fresh): the old one,
    sent before the new session's frames, is refused every time; the new session is kept."""
    out, inbox = ends(session=1)
    for i in range(3):
        inbox.on_frame(out.submit("train-state", {"i": i}, i / 10)[1], i / 10)
    old_frame = out.submit("train-state", {"i": 3}, 0.3)[1]  # sent, not yet delivered
    restarted = OfficeOutbox(own_id=7, office_id=OFFICE, master_key=KEY, session=2)
    for i in range(6):  # the new session's numbers pass the old frame's
        assert inbox.on_frame(restarted.submit("train-state", {"i": i}, 0.4)[1], 0.4)[2] is None
    for k in range(3):
        now = 0.5 + k / 10
        report, _, reason = inbox.on_frame(old_frame, now)
        assert report is None and reason in ("old_session", "repeated", "out_of_order")
        new = inbox.on_frame(restarted.submit("train-state", {"i": k + 6}, now)[1], now)[0]
        assert new is not None and new.session == 2


def test_a_restarted_office_is_followed_by_the_senders() -> None:
    out, inbox = ends()
    for t in (0.0, 0.1):
        _, ack, _ = inbox.on_frame(out.submit("stop-result", {}, t)[1], t)
        assert ack is not None and out.on_frame(ack, t) is not None
    seq, frame = out.submit("stop-result", {}, 0.2)
    restarted = OfficeInbox(own_id=OFFICE, master_key=KEY, senders=(7,), session=100)
    _, ack, _ = restarted.on_frame(frame, 0.2)  # its acknowledgements start at 1 again
    assert ack is not None and out.on_frame(ack, 0.3) == seq and not out.pending


def test_reports_the_link_cannot_carry_are_refused_whole() -> None:
    out, _ = ends()
    with pytest.raises(OfficeLinkError, match="one of"):
        out.submit("gossip", {}, 0.0)
    with pytest.raises(OfficeLinkError, match="at most 255"):
        out.submit("stop-result", {"x": os.urandom(200).hex()}, 0.0)  # does not deflate below 255
    with pytest.raises(OfficeLinkError, match="not plain JSON"):
        out.submit("stop-result", {"x": float("nan")}, 0.0)
    assert not out.pending and out.next_seq == 1


def test_a_tasc_command_with_its_inputs_fits_deflated_and_a_bomb_is_refused() -> None:
    """A station's command record (its inputs, the command, the telegram on the air) is about 280
    bytes of JSON: deflated it fits the 255-byte frame. A frame whose payload would inflate beyond
    4 KiB is refused as malformed, not inflated."""
    import json
    import zlib

    from railstop.config import default_line, default_vehicle
    from railstop.link.safety import SafeSender
    from railstop.live.tasc import StationTasc, wired_stop

    line, vehicle = default_line(), default_vehicle()
    _, wayside = wired_stop(StationTasc.create(0, line.stations[0], vehicle, "tasc-pwm"), vehicle)
    out, inbox = ends()
    for rec in wayside.records:
        rec = {**rec, "t": rec["t"] + 259_200.0, "tr": 59}  # three days into a run, train 59
        envelope = {"e": 2**32 - 1, "q": 1, "k": "tasc-command", "t": 1.8e9 + 0.123, "d": rec}
        assert len(json.dumps(envelope, separators=(",", ":"))) > 255  # too long as plain JSON
        _, frame = out.submit("tasc-command", rec, 1.8e9)
        report, _, reason = inbox.on_frame(frame, 1.8e9)
        assert reason is None and report is not None and report.data == rec
    packer = zlib.compressobj(9, zlib.DEFLATED, -15)
    bomb = packer.compress(b'{"e":1,"k":"stop-result","d":{"x":"' + b"y" * 10_000 + b'"}}') + packer.flush()
    assert len(bomb) < 255
    forged = SafeSender(7, OFFICE, key=link_key(KEY, 7, OFFICE), category=3).wrap(bomb, 5.0)
    _, fresh = ends()
    assert fresh.on_frame(forged, 5.0) == (None, None, "malformed")


def test_direction_keys_differ() -> None:
    assert link_key(KEY, 7, OFFICE) != link_key(KEY, OFFICE, 7)


def test_an_acknowledgement_made_when_sent_is_fresh_however_long_the_report_was_held() -> None:
    """The office holds a report while its database is away and acknowledges it once stored, maybe
    many seconds later. An acknowledgement made on arrival would be refused as stale by then (the
    report stays pending: safe, but it never clears); one made when it is sent is taken."""
    out, inbox = ends()
    seq, frame = out.submit("stop-result", {"i": 1}, 0.0)
    report, reason = inbox.accept(frame, 0.0)
    assert report is not None and reason is None
    made_on_arrival = inbox.ack(report, 0.0)
    held_s = out.times.max_age_s + 5.0
    assert out.on_frame(made_on_arrival, held_s) is None and seq in out.pending
    assert out.on_frame(inbox.ack(report, held_s), held_s) == seq and not out.pending


@given(
    field=st.sampled_from(["e", "q"]),
    value=st.one_of(
        st.integers(min_value=2**63, max_value=2**80),
        st.integers(max_value=-1),
        st.booleans(),
        st.floats(allow_nan=False, allow_infinity=False),
        st.text(max_size=5),
    ),
)
def test_numbers_a_database_cannot_keep_are_refused_as_malformed(field: str, value: object) -> None:
    """A sender (with the key) whose session or sequence number does not fit the database's 64-bit
    columns (or is no integer): the office refuses the report at once, it is never queued for
    storing (where it would fail the database) and never acknowledged."""
    import json
    import zlib

    from railstop.link.safety import SafeSender

    obj = {"e": 5, "q": 1, "k": "stop-result", "t": 1.0, "d": {}}
    obj[field] = value
    packer = zlib.compressobj(9, zlib.DEFLATED, -15)
    payload = packer.compress(json.dumps(obj).encode()) + packer.flush()
    frame = SafeSender(7, OFFICE, key=link_key(KEY, 7, OFFICE), category=3).wrap(payload, 1.0)
    _, inbox = ends()
    assert inbox.on_frame(frame, 1.0) == (None, None, "malformed")
    assert inbox.counts["accepted"] == 0


# ------------------------------------------------------------------ the store


@pytest.fixture(params=["sqlite", "postgresql"])
def db(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[str]:
    if request.param == "sqlite":
        yield str(tmp_path / "office.db")
        return
    yield request.getfixturevalue("empty_postgres")


def test_the_store_keeps_a_report_once(db: str) -> None:
    with open_store(db) as store:
        kw: dict[str, Any] = {"sender_id": 7, "session": 5, "seq": 1, "kind": "stop-result", "sent_s": 1.5}
        first = store.save_office_report(**kw, data={"error_m": 0.01})
        assert first is not None and first["data"] == {"error_m": 0.01}
        assert store.save_office_report(**kw, data={"error_m": 0.01}) is None
        assert store.save_office_report(**{**kw, "seq": 2}, data={}) is not None
        assert store.save_office_report(**{**kw, "session": 6}, data={}) is not None
        rows = store.office_reports()
        assert [(r["session"], r["seq"]) for r in rows] == [(5, 1), (5, 2), (6, 1)]
        assert rows[0]["data"] == {"error_m": 0.01} and store.office_report_count() == 3
        assert [r["seq"] for r in store.office_reports(after_id=rows[0]["id"])] == [2, 1]
        # The last n, in the order received (what a page opened late is sent first).
        last_two = store.office_reports(limit=2, latest=True)
        assert [(r["session"], r["seq"]) for r in last_two] == [(5, 2), (6, 1)]


# ------------------------------------------------------------------ end to end


def _start_office(db: str, port: int = 0) -> tuple[subprocess.Popen[str], int]:
    proc = subprocess.Popen(
        [sys.executable, "-m", "railstop.cli", "office", "serve", "--db", db, "--port", str(port),
         "--senders", "1-20"],
        env={**os.environ, "RAILSTOP_OFFICE_KEY": KEY.hex()},
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    assert proc.stderr is not None
    line = proc.stderr.readline()
    assert "office listening on 127.0.0.1:" in line, line + proc.stderr.read()
    return proc, int(line.split("127.0.0.1:")[1].split()[0])


def test_killing_the_office_mid_run_loses_no_report(db: str) -> None:
    """200 reports at 100 per second; SIGKILL of the office after the first 60 are acknowledged,
    a new office on the same port 1 s later: every report stored exactly once."""
    from railstop.link.office_link import LinkTimes
    from railstop.link.udp import EpochClock
    from railstop.live.office import OfficeClient

    proc, port = _start_office(db)
    n = 200

    async def client() -> tuple[bool, int, dict[str, int]]:
        nonlocal proc
        clock = EpochClock(0.0)
        times = LinkTimes(resend_s=0.3)
        async with OfficeClient(
            own_id=7, office=("127.0.0.1", port), master_key=KEY, clock=clock, times=times
        ) as office:
            killed = False
            for i in range(n):
                office.report("stop-result", {"i": i, "station": "Riverside", "error_m": 0.001 * i})
                await asyncio.sleep(0.01)
                if not killed and office.outbox.counts["acknowledged"] >= 60:
                    os.kill(proc.pid, signal.SIGKILL)
                    proc.wait(timeout=10)
                    killed = True
                    kill_at = i
            assert killed
            await asyncio.sleep(1.0)
            proc, again = _start_office(db, port)
            assert again == port
            drained = await office.drain(timeout_s=30.0)
            return drained, kill_at, dict(office.outbox.counts)

    try:
        drained, kill_at, counts = asyncio.run(client())
    finally:
        proc.send_signal(signal.SIGTERM)
        out, _ = proc.communicate(timeout=20)
    assert drained, counts
    assert counts["resent"] > 0 and kill_at < n - 1  # the kill did fall in the middle
    with open_store(db) as store:
        rows = store.office_reports()
    assert sorted(r["data"]["i"] for r in rows) == list(range(n))
    assert len({(r["session"], r["seq"]) for r in rows}) == n == len(rows)
    assert proc.returncode == 0 and '"stored"' in out


def _private_key_file(where: Path, text: str = KEY.hex() + "\n", mode: int = 0o600) -> Path:
    path = where / "office.key"
    path.write_text(text)
    path.chmod(mode)
    return path


def _serve(tmp_path: Path, *args: str, env: dict[str, str] | None = None) -> subprocess.CompletedProcess[str]:
    """``railstop office serve`` that is expected to refuse its options (it stops at once)."""
    base = {k: v for k, v in os.environ.items() if k != "RAILSTOP_OFFICE_KEY"}
    # Forked from a warm zygote (tests/zygote.py; stdin /dev/null): it refuses before it serves.
    return run_cli(
        "office", "serve", "--db", str(tmp_path / "o.db"), "--port", "0", *args,
        timeout=60, env={**base, **(env or {})},
    )  # fmt: skip


def _refused(p: subprocess.CompletedProcess[str], *needles: str) -> str:
    """The one error line of a refused start (exit code 2, nothing served)."""
    lines = p.stderr.strip().splitlines()
    assert p.returncode == 2 and len(lines) == 1 and lines[0].startswith("error:"), p.stderr
    assert "Traceback" not in p.stderr and "listening" not in p.stderr + p.stdout
    for needle in needles:
        assert needle in lines[0], (needle, lines[0])
    return lines[0]


def test_office_serve_refuses_bad_options_in_one_line(tmp_path: Path) -> None:
    key = _private_key_file(tmp_path)
    _refused(_serve(tmp_path, "--key-file", str(key), "--senders", "9-x"), "--senders")
    _refused(_serve(tmp_path), "--key-file", "RAILSTOP_OFFICE_KEY")  # no key at all
    for value in ("abc", "00" * 8):
        _refused(_serve(tmp_path, env={"RAILSTOP_OFFICE_KEY": value}), "RAILSTOP_OFFICE_KEY")


def test_a_key_on_the_command_line_is_refused_whatever_else_is_given(tmp_path: Path) -> None:
    """``--key-hex`` (a key every user of the machine could read in the process list) stops the
    office and a live process in one line naming what to use instead, never echoing the key; a
    valid key file or environment key beside it does not let it through."""
    key = _private_key_file(tmp_path)
    for extra, env in (
        ([], None),
        (["--key-file", str(key)], None),
        ([], {"RAILSTOP_OFFICE_KEY": KEY.hex()}),
    ):
        line = _refused(
            _serve(tmp_path, "--key-hex", KEY.hex(), *extra, env=env),
            "--key-hex", "command line", "--key-file", "RAILSTOP_OFFICE_KEY",
        )  # fmt: skip
        assert KEY.hex() not in line
    live = run_cli("live", "zc", "--port", "0", "--new", "--key-hex", KEY.hex(), timeout=60)
    line = _refused(live, "--key-hex", "--key-file")
    assert KEY.hex() not in line and "zone controller on" not in live.stderr


def test_a_key_file_others_may_read_or_that_holds_no_key_is_refused(tmp_path: Path) -> None:
    """The process does not start on a key file that group or others may read or write, that is
    missing, not a regular file, not hex or under 16 bytes: one line naming --key-file, the file and
    the reason; the key itself is never echoed."""
    cases = [
        (KEY.hex(), 0o644, "chmod 600"),
        (KEY.hex(), 0o640, "chmod 600"),
        (KEY.hex(), 0o602, "chmod 600"),
        ("not a key\n", 0o600, "hexadecimal"),
        ("00112233", 0o600, "16 bytes"),
        ("", 0o600, "empty"),
    ]
    for text, mode, why in cases:
        key = _private_key_file(tmp_path, text, mode)
        line = _refused(_serve(tmp_path, "--key-file", str(key)), "--key-file", str(key), why)
        assert KEY.hex() not in line
    _refused(
        _serve(tmp_path, "--key-file", str(tmp_path / "nosuch.key")), "--key-file", "nosuch.key", "no such"
    )
    _refused(_serve(tmp_path, "--key-file", str(tmp_path)), "--key-file", "not a regular file")


@given(mode=st.integers(0, 0o777), pad=st.sampled_from(["", " ", "\n", "\t\n  "]))
def test_only_a_key_file_closed_to_group_and_others_is_read(
    tmp_path_factory: Any, mode: int, pad: str
) -> None:
    """Property over every permission mode: a key file is read exactly when group and others have no
    permission on it (0600 or stricter), and then whitespace around the hex is ignored."""
    from railstop.cli.office import read_key_file
    from railstop.errors import RailstopError

    path = _private_key_file(tmp_path_factory.mktemp("k"), pad + KEY.hex() + pad, mode)
    try:
        if mode & 0o077:
            with pytest.raises(RailstopError, match="chmod 600"):
                read_key_file(path)
        elif os.geteuid() == 0 or mode & 0o400:  # root reads whatever the owner's bits
            assert read_key_file(path) == KEY
    finally:
        path.chmod(0o600)


def test_new_key_writes_a_private_random_key_that_the_office_reads_and_never_overwrites(
    tmp_path: Path,
) -> None:
    from railstop.cli.office import read_key_file

    def new_key(path: Path) -> subprocess.CompletedProcess[str]:
        return run_cli("office", "new-key", "--out", str(path), timeout=60)

    a, b = tmp_path / "a.key", tmp_path / "b.key"
    made = new_key(a)
    assert made.returncode == 0, made.stderr
    assert a.stat().st_mode & 0o777 == 0o600
    key = read_key_file(a)
    assert len(key) == 32 and key.hex() not in made.stdout + made.stderr  # never printed
    assert new_key(b).returncode == 0 and read_key_file(b) != key  # fresh each time
    again = new_key(a)
    _refused(again, "--out", str(a), "exists")
    assert read_key_file(a) == key  # a key in use is never overwritten
    # The office starts on it (and serves until stopped).
    proc = subprocess.Popen(
        [sys.executable, "-m", "railstop.cli", "office", "serve", "--db", str(tmp_path / "o.db"),
         "--port", "0", "--key-file", str(a)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, stdin=subprocess.DEVNULL,
        env={k: v for k, v in os.environ.items() if k != "RAILSTOP_OFFICE_KEY"},
    )  # fmt: skip
    assert proc.stderr is not None
    try:
        assert "office listening on 127.0.0.1:" in proc.stderr.readline()
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.communicate(timeout=30)


def test_office_reports_lists_what_is_stored_and_sums_up_the_stops(tmp_path: Path) -> None:
    """``railstop office reports``: the latest reports of a kind (table, or JSON lines with
    --json), and per station and controller the stops among them."""
    import json

    db = tmp_path / "office.db"

    def stop(station: str, error: float, eb: str | None = None) -> dict[str, object]:
        within = abs(error) <= 0.35
        return {
            "station": station,
            "controller": "tasc-pwm",
            "error_m": error,
            "within": within,
            "emergency_brake": eb,
        }

    stops = [stop("Museum", -0.02), stop("Museum", -3.5, "telegram-timeout"), stop("Harbour", 0.027)]
    with open_store(str(db)) as store:
        for seq, data in enumerate(stops, start=1):
            store.save_office_report(
                sender_id=801, session=5, seq=seq, kind="stop-result", sent_s=1.0, data=data
            )
        command = {"st": "Museum", "a_cmd": 0.4}
        store.save_office_report(
            sender_id=802, session=6, seq=1, kind="tasc-command", sent_s=1.0, data=command
        )
    cli = [sys.executable, "-m", "railstop.cli", "office", "reports", "--db", str(db)]
    wide = {**os.environ, "COLUMNS": "200"}

    def run(*args: str) -> str:
        p = subprocess.run([*cli, *args], capture_output=True, text=True, timeout=60, env=wide)
        assert p.returncode == 0, p.stderr
        return p.stdout

    assert [json.loads(line)["data"] for line in run("--kind", "stop-result", "--json").splitlines()] == stops
    out = run("--last", "2")
    assert "2 of 4 reports" in out and "tasc-command" in out
    assert (
        "Harbour (tasc-pwm): 1 stop(s), 1 within tolerance, |error| max 0.027 m, 0 emergency brake(s)" in out
    )
    out = run("--kind", "stop-result")
    assert (
        "Museum (tasc-pwm): 2 stop(s), 1 within tolerance, |error| max 3.500 m, 1 emergency brake(s)" in out
    )


def test_office_reports_sums_up_the_dwells() -> None:
    """The dwell summary of ``railstop office reports`` (SPEC §5): per station, start enables,
    faults, corrections and the longest dwell to start enable."""
    from railstop.cli.office import dwell_summary_lines

    def dwell(station: str, outcome: str, dwell_s: float | None, corrections: int = 0) -> dict[str, object]:
        return {"station": station, "outcome": outcome, "dwell_s": dwell_s, "corrections": corrections}

    lines = dwell_summary_lines(
        [dwell("Museum", "start-enable", 32.8), dwell("Museum", "start-enable", 37.2, 1),
         dwell("Museum", "fault", None, 2), dwell("Harbour", "fault", None)]
    )  # fmt: skip
    assert lines == [
        "Harbour (doors): 1 dwell(s), 0 start enable, 1 fault(s), 0 correction(s)",
        "Museum (doors): 3 dwell(s), 2 start enable, 1 fault(s), 3 correction(s), longest 37.2 s",
    ]


def test_a_restarted_office_takes_no_report_sent_before_it_started() -> None:
    """A report the previous office took, replayed to a restarted office while still fresh, is
    refused (old_session); what the sender sends after the restart is taken."""
    out, _ = ends(session=1)
    _, frame = out.submit("train-state", {"i": 0}, 1.0)
    restarted = OfficeInbox(own_id=OFFICE, master_key=KEY, senders=(7,), session=100, started_s=2.0)
    report, ack, reason = restarted.on_frame(frame, 2.5)  # 1.5 s old: fresh, but sent before the start
    assert report is None and ack is None and reason == "old_session"
    assert restarted.on_frame(out.submit("train-state", {"i": 1}, 3.0)[1], 3.0)[0] is not None
    # Without the floor the same replay would be taken again.
    unfloored = OfficeInbox(own_id=OFFICE, master_key=KEY, senders=(7,), session=101)
    assert unfloored.on_frame(frame, 2.5)[0] is not None
