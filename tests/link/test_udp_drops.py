"""Datagrams the kernel drops on the receiver (socket receive buffer full) are counted: SO_RXQ_OVFL.

Real sockets on 127.0.0.1, no mocks: the receiver gets a small SO_RCVBUF, a plain sender socket
blasts datagrams at it while the event loop (hence the receiver) does not read, then everything
is read. The kernel's counter must equal what was sent and never arrived.
"""

from __future__ import annotations

import asyncio
import json
import os
import socket
import subprocess
import sys
import time
from collections.abc import Awaitable, Callable
from typing import Any

import pytest

import railstop.link.udp as udp
from railstop.link.safety import PEER_REASONS, SafePeers
from railstop.link.udp import open_endpoint, process_udp_stats

LOOPBACK = "127.0.0.1"
LINUX = sys.platform.startswith("linux")


def run(coro_fn: Callable[[], Awaitable[Any]], timeout_s: float = 20.0) -> Any:
    async def guarded() -> Any:
        return await asyncio.wait_for(coro_fn(), timeout_s)

    return asyncio.run(guarded())


async def drain(ep: udp.UdpEndpoint, quiet_s: float = 0.3) -> list[bytes]:
    """Every frame until none came for ``quiet_s``."""
    got: list[bytes] = []
    while (item := await ep.recv(quiet_s)) is not None:
        got.append(item[0])
    return got


@pytest.mark.skipif(not LINUX, reason="SO_RXQ_OVFL is Linux only")
def test_kernel_drops_on_a_full_receive_buffer_are_counted() -> None:
    blast = 500  # below net.core.netdev_max_backlog (1000): no drop before the socket

    async def body() -> None:
        rx = await open_endpoint((LOOPBACK, 0), queue_frames=100_000, receive_buffer_bytes=4096)
        async with rx:
            assert rx.stats.dropped_by_kernel == 0
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx:
                # No await in this loop: the event loop, hence the receiver, reads nothing meanwhile.
                for i in range(blast):
                    tx.sendto(i.to_bytes(4, "big") + bytes(196), rx.local_address)
                got = await drain(rx)
                # The counter comes with the next datagram queued after the drops: one more.
                tx.sendto(b"last", rx.local_address)
                got += await drain(rx)
            sent = blast + 1
            stats = rx.stats
            assert got[-1] == b"last"
            assert stats.received == len(got) < sent
            # Nothing else dropped: whatever did not arrive, the kernel dropped.
            assert stats.dropped_queue_full == 0 and stats.dropped_oversize == 0 and stats.errors == 0
            assert stats.dropped_by_kernel is not None and stats.dropped_by_kernel > 0
            assert stats.dropped_by_kernel == sent - stats.received
            # What arrived is in order, the first ones (they filled the buffer) among them.
            numbers = [int.from_bytes(g[:4], "big") for g in got[:-1]]
            assert numbers == sorted(numbers) and numbers[0] == 0

    run(body)


@pytest.mark.skipif(not LINUX, reason="SO_RXQ_OVFL is Linux only")
def test_drops_after_the_last_datagram_and_frames_never_taken_are_counted_at_close() -> None:
    """No datagram follows the burst, so no ancillary data carries the kernel's last drops: the
    process's totals read them from the socket table, and closing counts what was never taken
    (still queued, or still in the socket's buffer). Sent = taken + every drop, exactly."""
    blast = 500

    async def body() -> None:
        rx = await open_endpoint((LOOPBACK, 0), queue_frames=40, receive_buffer_bytes=4096)
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx:
            for i in range(blast):  # no await: nothing is read meanwhile, the buffer overflows
                tx.sendto(i.to_bytes(4, "big") + bytes(196), rx.local_address)
        await asyncio.sleep(0.05)  # the loop reads what the buffer held (the queue keeps 40)
        taken = [rx.take() for _ in range(5)]
        assert all(t is not None for t in taken)
        before = rx.stats.dropped_by_kernel
        assert before == 0  # no datagram came after the drops: its ancillary data says none
        totals = process_udp_stats()  # reads the kernel's counter from the socket table
        assert totals["dropped_by_kernel"] is not None and totals["dropped_by_kernel"] > 0
        kernel = rx.stats.dropped_by_kernel
        assert kernel is not None and kernel > 0
        left = rx.queued
        assert left > 0
        rx.close()
        stats = rx.stats
        assert stats.dropped_at_close >= left and rx.queued == 0
        assert stats.dropped_by_kernel is not None
        dropped = stats.dropped_queue_full + stats.dropped_by_kernel + stats.dropped_at_close
        assert blast == len(taken) + dropped

    run(body)


@pytest.mark.skipif(not LINUX, reason="SO_RXQ_OVFL is Linux only")
def test_no_drops_is_zero_and_replies_still_work() -> None:
    async def body() -> None:
        b = await open_endpoint((LOOPBACK, 0))
        a = await open_endpoint((LOOPBACK, 0), b.local_address)
        async with b, a:
            for i in range(50):
                a.send(bytes([i]))
            got = [await b.recv(2.0) for _ in range(50)]
            assert [g[0] for g in got if g] == [bytes([i]) for i in range(50)]
            b.send(b"ack", got[0][1])  # type: ignore[index]
            assert await a.recv(2.0) == (b"ack", b.local_address)
            assert b.stats.dropped_by_kernel == 0 and a.stats.dropped_by_kernel == 0

    run(body)


def test_without_so_rxq_ovfl_the_counter_is_none(monkeypatch: pytest.MonkeyPatch) -> None:
    """Where the option does not exist (not Linux) the endpoint still works and says it cannot count."""
    monkeypatch.setattr(udp, "SO_RXQ_OVFL", None)

    async def body() -> None:
        b = await open_endpoint((LOOPBACK, 0))
        a = await open_endpoint((LOOPBACK, 0), b.local_address)
        async with b, a:
            a.send(b"x")
            assert await b.recv(2.0) == (b"x", a.local_address)
            assert b.stats.dropped_by_kernel is None

    run(body)


def test_receive_command_reports_kernel_drops() -> None:
    """``python -m railstop.link.udp receive`` prints the counter (0 here: nothing was dropped)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind((LOOPBACK, 0))
        port = s.getsockname()[1]
    args = ["receive", "--port", str(port), "--count", "1", "--category", "1", "--epoch", repr(time.time())]
    res = subprocess.run(
        [sys.executable, "-m", "railstop.link.udp", *args, "--wait-s", "0.3"],
        capture_output=True,
        text=True,
        timeout=20,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )
    assert res.returncode == 1, res.stderr  # nothing was sent: incomplete
    got = json.loads(res.stdout.strip().splitlines()[-1])
    assert "dropped_by_kernel" in got
    assert got["dropped_by_kernel"] == (0 if LINUX else None)


def test_a_flooding_source_cannot_push_out_another() -> None:
    """Real sockets: one source floods the endpoint (300 datagrams into a 32-frame queue) while a
    second sends 10 (below its share, 16); the flood loses its own frames, every one of the other's
    is kept (in order) and served in turn, not after the flood's. (With one queue for all, the
    oldest dropped, the flood pushed out all but the last.)"""

    async def body() -> None:
        rx = await open_endpoint((LOOPBACK, 0), queue_frames=32, receive_buffer_bytes=1 << 20)
        async with rx:
            with (
                socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as flood,
                socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as genuine,
            ):
                genuine.bind((LOOPBACK, 0))
                # No await: the kernel buffer holds them until the event loop reads them all at once.
                for i in range(300):
                    flood.sendto(b"F" + i.to_bytes(2, "big"), rx.local_address)
                    if i % 30 == 0:
                        genuine.sendto(b"G" + bytes([i // 30]), rx.local_address)
                got = await drain(rx, 0.3)
                mine = genuine.getsockname()
            stats = rx.stats
        assert stats.received == 310 and stats.dropped_by_kernel in (0, None)
        assert [g for g in got if g[:1] == b"G"] == [b"G" + bytes([k]) for k in range(10)]
        assert stats.dropped_queue_full == 310 - len(got) == 300 - 22  # the flood kept 22 of the 32
        # Served in turn: the genuine frames come among the first (one of them every second frame).
        assert {g[:1] for g in got[:12]} == {b"F", b"G"} and got[-1][:1] == b"F"
        assert mine[1] > 0

    run(body)


def test_process_udp_stats_sum_every_endpoint_open_or_closed() -> None:
    """A process's totals include the endpoints it closed, with the queue's drops."""

    async def body() -> dict[str, int | None]:
        before = process_udp_stats()
        b = await open_endpoint((LOOPBACK, 0), queue_frames=2)
        a = await open_endpoint((LOOPBACK, 0), b.local_address)
        async with b:
            async with a:
                for i in range(5):
                    a.send(bytes([i]))
                while b.stats.received < 5:
                    await asyncio.sleep(0.005)
            mid = process_udp_stats()  # a closed, b open
            assert mid["dropped_queue_full"] == before["dropped_queue_full"] + 3  # type: ignore[operator]
        after = process_udp_stats()
        assert after["sent"] == before["sent"] + 5  # type: ignore[operator]
        assert after["received"] == before["received"] + 5  # type: ignore[operator]
        assert after["endpoints"] == before["endpoints"] + 2  # type: ignore[operator]
        return after

    run(body)


def test_random_and_forged_datagrams_into_a_live_endpoint_are_all_counted() -> None:
    """Random bytes and frames with forged headers over real sockets into an endpoint and SafePeers
    (as a live process reads them): nothing raises, each is counted once, no receiver state is
    kept, and a genuine peer is still heard."""
    import random

    master = bytes(range(40, 72))
    rng = random.Random(5)
    junk = [rng.randbytes(rng.randrange(0, 60)) for _ in range(300)]
    heads = [
        bytes([0x13]) + rng.choice([0x0300, 0x2001, rng.randrange(65536)]).to_bytes(2, "big")
        + rng.choice([0x0300, rng.randrange(65536)]).to_bytes(2, "big") + rng.randbytes(8) + b"\x02"
        + rng.randbytes(10)
        for _ in range(300)
    ]  # fmt: skip

    async def body() -> tuple[SafePeers, int]:
        links = SafePeers(0x0300, master, max_age_s=1.0, peers=lambda p: p == 0x0300 or 0x2000 <= p < 0x3000)
        train = SafePeers(0x2001, master, max_age_s=1.0, peers=lambda p: p == 0x0300)
        rx = await open_endpoint((LOOPBACK, 0), queue_frames=1000, receive_buffer_bytes=1 << 20)
        taken = 0
        async with rx:
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx:
                for data in [*junk, *heads, train.wrap(b"hello", 0x0300, 1.0)]:
                    tx.sendto(data, rx.local_address)
                    await asyncio.sleep(0)
                for data, _ in [(g, None) for g in await drain(rx, 0.3)]:
                    taken += 1
                    links.accept(data, 1.0)
        return links, taken

    links, taken = run(body)
    assert taken == 601  # empty datagrams included: nothing lost on loopback at this pace
    assert links.delivered == 1 and sum(links.rejected.values()) == 600
    assert set(links.rejected) <= set(PEER_REASONS) and "error" not in links.rejected
    assert links.peers_held == 1
