"""UDP transport of link frames: railstop.link.udp (loopback only).

Every wait has a timeout, so a broken transport fails the test instead of hanging it.
"""

from __future__ import annotations

import asyncio
import json
import os
import select
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import Any

import pytest

from railstop.errors import RailstopError
from railstop.link.channel import LinkError
from railstop.link.codec import decode, quantized
from railstop.link.udp import MAX_DATAGRAM_BYTES, UdpEndpoint, demo_payload, demo_telegram, open_endpoint

LOOPBACK = "127.0.0.1"


def run(coro_fn: Callable[[], Awaitable[Any]], timeout_s: float = 10.0) -> Any:
    async def guarded() -> Any:
        return await asyncio.wait_for(coro_fn(), timeout_s)

    return asyncio.run(guarded())


async def wait_received(ep: UdpEndpoint, n: int, timeout_s: float = 5.0) -> None:
    """Until the endpoint's socket has taken n datagrams (queued or dropped)."""
    loop = asyncio.get_running_loop()
    end = loop.time() + timeout_s
    while ep.stats.received + ep.stats.dropped_oversize < n:
        if loop.time() > end:
            raise AssertionError(f"only {ep.stats} after {timeout_s} s")
        await asyncio.sleep(0.005)


def test_round_trip_over_loopback() -> None:
    async def body() -> None:
        b = await open_endpoint((LOOPBACK, 0))
        a = await open_endpoint((LOOPBACK, 0), b.local_address)
        async with b, a:
            frames = [bytes([i]) * (i + 1) for i in range(20)]
            for f in frames:
                a.send(f)
            got = [await b.recv(2.0) for _ in frames]
            assert [g[0] for g in got if g] == frames
            assert {g[1] for g in got if g} == {a.local_address}
            # Reply to the sender's address.
            b.send(b"ack", got[0][1])
            back = await a.recv(2.0)
            assert back == (b"ack", b.local_address)
            assert a.stats.sent == 20 and b.stats.received == 20 and b.stats.dropped_queue_full == 0

    run(body)


def test_queue_is_bounded_and_drops_oldest() -> None:
    async def body() -> None:
        b = await open_endpoint((LOOPBACK, 0), queue_frames=3)
        a = await open_endpoint((LOOPBACK, 0), b.local_address)
        async with b, a:
            for i in range(10):
                a.send(bytes([i]))
            await wait_received(b, 10)
            got = [await b.recv(1.0) for _ in range(3)]
            assert [g[0] for g in got if g] == [bytes([7]), bytes([8]), bytes([9])]
            assert b.stats.dropped_queue_full == 7
            assert await b.recv(0.0) is None

    run(body)


def test_oversize_frames_rejected_and_dropped() -> None:
    async def body() -> None:
        b = await open_endpoint((LOOPBACK, 0), max_frame_bytes=8)
        a = await open_endpoint((LOOPBACK, 0), b.local_address)
        async with b, a:
            with pytest.raises(LinkError, match="exceeds") as info:
                a.send(bytes(MAX_DATAGRAM_BYTES + 1))
            assert isinstance(info.value, RailstopError)
            a.send(bytes(MAX_DATAGRAM_BYTES))  # the largest allowed frame goes
            a.send(bytes(9))  # allowed by a, too long for b
            a.send(bytes(8))
            await wait_received(b, 3)
            assert b.stats.dropped_oversize == 2
            assert await b.recv(1.0) == (bytes(8), a.local_address)
            with pytest.raises(LinkError, match="exceeds"):
                b.send(bytes(9), a.local_address)

    run(body)


def test_timeout_close_and_misuse() -> None:
    async def body() -> None:
        ep = await open_endpoint((LOOPBACK, 0))
        loop = asyncio.get_running_loop()
        t0 = loop.time()
        assert await ep.recv(0.1) is None
        assert 0.09 <= loop.time() - t0 < 2.0
        with pytest.raises(LinkError, match="no address"):
            ep.send(b"x")
        with pytest.raises(LinkError, match="bytes"):
            ep.send("x", ep.local_address)  # type: ignore[arg-type]
        with pytest.raises(LinkError, match="timeout_s"):
            await ep.recv(-1.0)
        # A recv waiting forever returns None when the endpoint closes.
        waiter = asyncio.ensure_future(ep.recv())
        await asyncio.sleep(0.01)
        ep.close()
        assert await asyncio.wait_for(waiter, 2.0) is None
        with pytest.raises(LinkError, match="closed"):
            ep.send(b"x", (LOOPBACK, 9))
        # A port already in use cannot be bound twice.
        async with await open_endpoint((LOOPBACK, 0)) as busy:
            with pytest.raises(LinkError, match="cannot bind"):
                await open_endpoint(busy.local_address)

    run(body)


# --------------------------------------------------------------------------
# Two real processes: python -m railstop.link.udp receive / send

KEY_HEX = "000102030405060708090a0b0c0d0e0f101112131415161718191a1b1c1d1e1f"


# The key files live in one folder that is removed when the test process ends (finalizer of
# TemporaryDirectory): no key is left behind in the machine's temporary folder.
KEY_DIR = tempfile.TemporaryDirectory(prefix="railstop-keys-")


def write_key(text: str) -> str:
    """A key file holding ``text`` (mode 0600, as the tool asks): the key never goes on a command line."""
    fd, path = tempfile.mkstemp(prefix="key-", dir=KEY_DIR.name)
    with os.fdopen(fd, "w") as fh:
        fh.write(text)
    os.chmod(path, 0o600)
    return path


KEY_FILE = write_key(KEY_HEX)
BUDGET_S = 20.0  # the whole two-process test, every wait included


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind((LOOPBACK, 0))
        return int(s.getsockname()[1])


def read_line(stream: Any, deadline: float) -> str:
    """One line from a child's pipe, or fail at the deadline (never block past it)."""
    remaining = deadline - time.monotonic()
    ready, _, _ = select.select([stream], [], [], max(0.0, remaining))
    if not ready:
        raise AssertionError("no line from the child process in time")
    return str(stream.readline())


def udp_cli(*args: str) -> list[str]:
    return [sys.executable, "-m", "railstop.link.udp", *args]


@pytest.mark.parametrize(("category", "corrupt_reason"), [(3, "bad_mac"), (1, "corrupt")])
def test_two_processes_deliver_genuine_and_reject_threats(category: int, corrupt_reason: str) -> None:
    n, replay, corrupt = 20, 3, 3
    deadline = time.monotonic() + BUDGET_S
    port = free_port()
    epoch = time.time()  # shared time origin: stands for the GNSS-synchronised clocks
    common = ["--port", str(port), "--count", str(n), "--category", str(category), "--epoch", repr(epoch)]
    if category == 3:
        common += ["--key-file", KEY_FILE]
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    rx = subprocess.Popen(
        udp_cli("receive", *common, "--wait-s", "15", "--linger-s", "0.3"),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )
    try:
        assert "listening on" in read_line(rx.stderr, deadline)
        tx = subprocess.run(
            udp_cli("send", *common, "--replay", str(replay), "--corrupt", str(corrupt)),
            capture_output=True,
            text=True,
            env=env,
            timeout=max(1.0, deadline - time.monotonic()),
        )
        assert tx.returncode == 0, tx.stderr
        out, err = rx.communicate(timeout=max(1.0, deadline - time.monotonic()))
    finally:
        if rx.poll() is None:
            rx.kill()
            rx.communicate()
    assert rx.returncode == 0, err

    sent = json.loads(tx.stdout.strip().splitlines()[-1])
    assert sent == {
        "sent": n + replay + corrupt,
        "genuine": n,
        "replayed": replay,
        "corrupted": corrupt,
        "send_errors": 0,
    }
    got = json.loads(out.strip().splitlines()[-1])
    assert got["complete"] is True
    assert got["datagrams"] == n + replay + corrupt
    # Nothing dropped on the way: by the kernel (Linux counts it; elsewhere it is unknown) or the queue.
    assert got["dropped_by_kernel"] == (0 if sys.platform.startswith("linux") else None)
    assert got["dropped_queue_full"] == 0
    # The N genuine telegrams, in order, intact down to the codec's CRC-16.
    assert got["delivered"] == n and got["decoded"] == n and got["telegram_errors"] == {}
    assert got["payloads"] == [demo_payload(i).hex() for i in range(n)]
    assert [decode(bytes.fromhex(h)) for h in got["payloads"]] == [
        quantized(demo_telegram(i)) for i in range(n)
    ]
    # Every injected frame rejected, for the right reason; nothing else rejected.
    assert got["rejected"] == {"repeated": replay, corrupt_reason: corrupt}
    counts = got["counts"]
    assert counts["delivered"] == n
    assert counts["repeated"] == replay and counts[corrupt_reason] == corrupt
    assert sum(counts.values()) == n + replay + corrupt


def test_cli_usage_errors() -> None:
    base = ["--port", "9", "--count", "1", "--epoch", "0"]
    # category 3 without a key, category 1 with one: refused before any socket is used
    for extra in (["--category", "3"], ["--category", "1", "--key-file", KEY_FILE]):
        res = subprocess.run(udp_cli("send", *base, *extra), capture_output=True, text=True, timeout=10)
        assert res.returncode == 2 and "error:" in res.stderr
    res = subprocess.run(
        udp_cli("send", *base, "--key-file", write_key("not-hex")), capture_output=True, text=True, timeout=10
    )
    assert res.returncode == 2 and "hexadecimal" in res.stderr
    # A key on the command line is refused whatever else is given, and not echoed.
    res = subprocess.run(
        udp_cli("send", *base, "--key-file", KEY_FILE, "--key-hex", KEY_HEX),
        capture_output=True,
        text=True,
        timeout=10,
    )
    assert res.returncode == 2 and "--key-hex" in res.stderr and KEY_HEX not in res.stderr
    loose = write_key(KEY_HEX)
    os.chmod(loose, 0o644)
    res = subprocess.run(
        udp_cli("send", *base, "--key-file", loose), capture_output=True, text=True, timeout=10
    )
    assert res.returncode == 2 and "chmod 600" in res.stderr


@pytest.mark.parametrize("command", ["send", "receive"])
@pytest.mark.parametrize("port", ["0", "70000", "-1"])
def test_a_port_outside_1_65535_is_one_line(command: str, port: str) -> None:
    """Not a traceback and an exit code 0 with {"sent": 1}: one line naming the option, code 2."""
    args = ["--port", port, "--count", "1", "--epoch", "0", "--key-file", KEY_FILE]
    res = subprocess.run(udp_cli(command, *args), capture_output=True, text=True, timeout=10)
    assert res.returncode == 2
    want = f"error: argument --port: a UDP port is 1..65535 (got '{port}')"
    assert res.stderr.strip().splitlines() == [want]
    assert res.stdout == ""


def test_receiver_without_sender_gives_up_incomplete() -> None:
    res = subprocess.run(
        udp_cli(
            "receive",
            "--port",
            str(free_port()),
            "--count",
            "3",
            "--category",
            "1",
            "--epoch",
            "0",
            "--wait-s",
            "0.3",
        ),
        capture_output=True,
        text=True,
        timeout=10,
    )
    assert res.returncode == 1, res.stderr
    got = json.loads(res.stdout.strip().splitlines()[-1])
    assert got["complete"] is False and got["delivered"] == 0 and got["datagrams"] == 0


@pytest.mark.parametrize(
    ("command", "option", "value", "want"),
    [
        ("send", "--epoch", "nan", "not a number (got 'nan')"),
        ("receive", "--epoch", "inf", "not finite (got 'inf')"),
        ("receive", "--wait-s", "nan", "not a number (got 'nan')"),
        ("receive", "--max-age-s", "0", "must be greater than 0 (got '0')"),
        ("receive", "--linger-s", "-1", "must be at least 0 (got '-1')"),
        ("send", "--interval-s", "-inf", "not finite (got '-inf')"),
        ("receive", "--peer-id", str(2**70), f"a node id is 0..65535 (got '{2**70}')"),
        ("send", "--src-id", "-1", "a node id is 0..65535 (got '-1')"),
        ("send", "--count", "x", "not a whole number (got 'x')"),
    ],
)
def test_a_bad_number_is_one_line_naming_the_option(command: str, option: str, value: str, want: str) -> None:
    """NaN is "not a number", infinity "not finite"; the option is named, never an internal field."""
    args = {"--port": "9", "--count": "1", "--epoch": "0", "--category": "1"}
    if command == "receive":
        args["--wait-s"] = "0.2"
    args[option] = value
    argv = [f"{k}={v}" for k, v in args.items()]  # --x=-inf: a value, not an option
    res = subprocess.run(udp_cli(command, *argv), capture_output=True, text=True, timeout=10)
    assert res.returncode == 2, res
    assert res.stderr.strip().splitlines() == [f"error: argument {option}: {want}"]
    assert res.stdout == ""


def _one_line_exit_2(res: subprocess.CompletedProcess[str], needle: str) -> None:
    assert res.returncode == 2, (res.stdout, res.stderr)
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error:") and needle in lines[0], res.stderr


def test_live_paths_refuse_a_missing_or_built_in_key(tmp_path: Path) -> None:
    """No live path runs on a built-in key: the UDP command refuses a demonstration master key, a
    live process refuses to start without a key, and with a demonstration key given (in a key file
    or the environment) it stops with one line (exit 2) before it opens a socket. ``railstop live
    run`` / ``demo`` generate a key per run and hand it to the processes they start
    (RAILSTOP_OFFICE_KEY)."""
    from railstop.link.safety import demo_master_key

    demo = demo_master_key("CBTC radio").hex()
    env = {k: v for k, v in os.environ.items() if k != "RAILSTOP_OFFICE_KEY"}
    common = ["--port", "9", "--count", "1", "--category", "3", "--epoch", "0"]
    res = subprocess.run(
        udp_cli("send", *common, "--key-file", write_key(demo)),
        capture_output=True,
        text=True,
        timeout=30,
        env=env,
    )
    _one_line_exit_2(res, "demonstration key")
    live = [sys.executable, "-m", "railstop.cli", "live", "zc", "--port", "0"]
    res = subprocess.run(live, capture_output=True, text=True, timeout=60, env=env)
    _one_line_exit_2(res, "key")
    key_file = tmp_path / "demo.key"
    key_file.write_text(demo + "\n")
    key_file.chmod(0o600)
    res = subprocess.run(
        [*live, "--key-file", str(key_file)], capture_output=True, text=True, timeout=60, env=env
    )
    _one_line_exit_2(res, "demonstration key")
    res = subprocess.run(
        live, capture_output=True, text=True, timeout=60, env={**env, "RAILSTOP_OFFICE_KEY": demo}
    )
    _one_line_exit_2(res, "demonstration key")
