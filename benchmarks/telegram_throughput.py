"""Telegram throughput: codec encode+decode and safety-layer wrap+accept per second; a flood.

    python benchmarks/telegram_throughput.py [--count 100000]
    python benchmarks/telegram_throughput.py --flood-s 3 [--step-s 0.05]

The payload is a realistic TASC telegram (SPEC §1 form 6, required
deceleration: an 8-byte codec frame). Every figure is measured here on one
core; nothing is asserted (DESIGN: speed targets live in benchmarks, never
as timed tests).

``--flood-s S``: a receiver like a live process (a UDP endpoint on loopback,
``SafePeers``, the queue drained every ``--step-s``) hears a genuine peer
sending one category-3 frame every 10 ms (a process of its own) while a
second process floods it for S seconds with frames whose header names the
genuine peer (so they pass every check before the MAC and cost an HMAC each).
It prints how many genuine frames got through and every drop, with where it
was counted: the kernel (``SO_RXQ_OVFL``), the endpoint's queue, the safety
layer's refusals.
"""

from __future__ import annotations

import argparse
import asyncio
import os
import socket
import subprocess
import sys
import time

from railstop.link.codec import CbtcReport, TascRequiredDecel, decode, encode
from railstop.link.safety import Delivered, SafePeers, SafeReceiver, SafeSender, frame_size, link_key
from railstop.link.udp import EpochClock, open_endpoint

FLOOD_KEY = bytes(range(7, 39))  # the benchmark's own master key (not a built-in one)
GENUINE_ID, RECEIVER_ID = 0x2001, 0x0300  # a train radio and the zone controller, as in live CBTC


def _rate(count: int, seconds: float) -> str:
    return f"{count / seconds:>12,.0f} /s  ({seconds / count * 1e6:6.2f} µs each)"


def bench_codec(count: int) -> None:
    msgs = [
        TascRequiredDecel(train_id=101, detector=i % 5, required_mps2=(i % 1000) / 1000) for i in range(count)
    ]
    t0 = time.perf_counter()
    frames = [encode(m) for m in msgs]
    t1 = time.perf_counter()
    back = [decode(f) for f in frames]
    t2 = time.perf_counter()
    if back != msgs:
        raise SystemExit("round trip failed")
    print(f"codec tasc-required-decel ({len(frames[0])} B frame)")
    print(f"  encode          {_rate(count, t1 - t0)}")
    print(f"  decode          {_rate(count, t2 - t1)}")
    print(f"  encode+decode   {_rate(count, t2 - t0)}")
    report = CbtcReport(train_id=7, position_m=1200.5, speed_mps=16.667, direction="L", time_s=3600.25)
    t0 = time.perf_counter()
    for _ in range(count):
        decode(encode(report))
    t1 = time.perf_counter()
    print(f"codec cbtc-report ({len(encode(report))} B frame)")
    print(f"  encode+decode   {_rate(count, t1 - t0)}")


def bench_safety(count: int, category: int) -> None:
    payload = encode(TascRequiredDecel(train_id=101, detector=2, required_mps2=0.7))
    key = link_key(bytes(range(32)), 1, 2) if category == 3 else None
    sender = SafeSender(1, 2, key=key, category=category)
    receiver = SafeReceiver(2, 1, key=key, category=category, max_age_s=0.5, timeout_s=1.0)
    times = [i * 0.01 for i in range(count)]  # one frame per 10 ms of link time
    t0 = time.perf_counter()
    frames = [sender.wrap(payload, t) for t in times]
    t1 = time.perf_counter()
    results = [receiver.accept(f, t) for f, t in zip(frames, times, strict=True)]
    t2 = time.perf_counter()
    if not all(isinstance(r, Delivered) for r in results):
        raise SystemExit("a genuine frame was rejected")
    code = "HMAC-SHA256/8" if category == 3 else "CRC-32"
    print(f"safety category {category} ({code}), {frame_size(len(payload), category)} B frame")
    print(f"  wrap            {_rate(count, t1 - t0)}")
    print(f"  accept          {_rate(count, t2 - t1)}")
    print(f"  wrap+accept     {_rate(count, t2 - t0)}")


def _genuine(port: int, epoch: float, duration_s: float) -> None:
    """The genuine peer: one frame every 10 ms (its sequence number in the payload)."""
    clock = EpochClock(epoch)
    links = SafePeers(GENUINE_ID, FLOOD_KEY, max_age_s=1.0, peers=lambda p: p == RECEIVER_ID)
    sent = 0
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        end = time.monotonic() + duration_s
        nxt = time.monotonic()
        while time.monotonic() < end:
            sock.sendto(links.wrap(sent.to_bytes(4, "big"), RECEIVER_ID, clock.now_s()), ("127.0.0.1", port))
            sent += 1
            nxt += 0.01
            time.sleep(max(0.0, nxt - time.monotonic()))
    print(sent, flush=True)


def _flooder(port: int, duration_s: float) -> None:
    """The flood: frames naming the genuine peer as source, random MACs, as fast as one core sends."""
    rng = os.urandom
    head = bytes([0x13]) + GENUINE_ID.to_bytes(2, "big") + RECEIVER_ID.to_bytes(2, "big")
    frames = [head + rng(8) + b"\x04" + rng(4) + rng(8) for _ in range(4096)]
    sent = 0
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.setblocking(False)
        end = time.monotonic() + duration_s
        while time.monotonic() < end:
            for f in frames[:256]:
                try:
                    sock.sendto(f, ("127.0.0.1", port))
                    sent += 1
                except BlockingIOError:
                    pass
            frames.append(frames.pop(0))
    print(sent, flush=True)


async def _flood_receiver(duration_s: float, step_s: float) -> None:
    epoch = time.time()
    clock = EpochClock(epoch)
    links = SafePeers(RECEIVER_ID, FLOOD_KEY, max_age_s=1.0, peers=lambda p: p == GENUINE_ID)
    delivered: set[int] = set()
    steps = taken = 0
    async with await open_endpoint(("127.0.0.1", 0)) as ep:
        port = ep.local_address[1]
        me = [sys.executable, __file__, "--role"]
        common = ["--port", str(port), "--epoch", repr(epoch), "--flood-s", str(duration_s)]
        genuine = subprocess.Popen([*me, "genuine", *common], stdout=subprocess.PIPE, text=True)
        flood = subprocess.Popen([*me, "flood", *common], stdout=subprocess.PIPE, text=True)
        loop = asyncio.get_running_loop()
        end = loop.time() + duration_s + 1.0
        while loop.time() < end:
            await asyncio.sleep(step_s)
            steps += 1
            while (got := ep.take()) is not None:
                taken += 1
                ok = links.accept(got[0], clock.now_s())
                if ok is not None:
                    delivered.add(int.from_bytes(ok[1].payload, "big"))
        genuine_sent = int((genuine.communicate()[0] or "0").split()[-1])
        flood_sent = int((flood.communicate()[0] or "0").split()[-1])
        await asyncio.sleep(0.2)
        while (got := ep.take()) is not None:
            taken += 1
            ok = links.accept(got[0], clock.now_s())
            if ok is not None:
                delivered.add(int.from_bytes(ok[1].payload, "big"))
        stats = ep.stats
    print(f"flood: {duration_s:g} s on loopback, the receiver drains its queue every {step_s * 1000:g} ms")
    print(f"  genuine frames sent (10 ms period)   {genuine_sent:>10,}")
    print(
        f"  genuine frames delivered             {len(delivered):>10,}  "
        f"({100 * len(delivered) / max(1, genuine_sent):.1f} %)"
    )
    print(f"  flood datagrams sent                 {flood_sent:>10,}")
    print(f"  datagrams into the endpoint's queue  {stats.received:>10,}")
    print(f"  frames taken and checked (HMAC)      {taken:>10,}  in {steps} drains")
    print(f"  dropped by the kernel (SO_RXQ_OVFL)  {stats.dropped_by_kernel!s:>10}")
    print(f"  dropped by the endpoint's queue      {stats.dropped_queue_full:>10,}")
    print(f"  refused by the safety layer          {dict(sorted(links.rejected.items()))}")


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--count", type=int, default=100_000, help="telegrams per measurement")
    parser.add_argument("--flood-s", type=float, default=None, help="run the flood measurement instead")
    parser.add_argument("--step-s", type=float, default=0.05, help="flood: the receiver's drain period")
    parser.add_argument("--role", choices=("genuine", "flood"), help=argparse.SUPPRESS)
    parser.add_argument("--port", type=int, help=argparse.SUPPRESS)
    parser.add_argument("--epoch", type=float, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.role == "genuine":
        _genuine(args.port, args.epoch, args.flood_s)
        return
    if args.role == "flood":
        _flooder(args.port, args.flood_s)
        return
    if args.flood_s is not None:
        asyncio.run(_flood_receiver(args.flood_s, args.step_s))
        return
    print(f"{args.count:,} telegrams per measurement")
    bench_codec(args.count)
    for category in (1, 3):
        bench_safety(args.count, category)
    # Full path of one TASC telegram: encode, wrap (cat 3), accept, decode.
    key = link_key(bytes(range(32)), 1, 2)
    sender = SafeSender(1, 2, key=key, category=3)
    receiver = SafeReceiver(2, 1, key=key, category=3, max_age_s=0.5, timeout_s=1.0)
    msg = TascRequiredDecel(train_id=101, detector=2, required_mps2=0.7)
    t0 = time.perf_counter()
    for i in range(args.count):
        got = receiver.accept(sender.wrap(encode(msg), i * 0.01), i * 0.01)
        if not isinstance(got, Delivered) or decode(got.payload) != msg:
            raise SystemExit("end-to-end failed")
    t1 = time.perf_counter()
    print("end to end (encode, wrap cat 3, accept, decode)")
    print(f"  telegrams       {_rate(args.count, t1 - t0)}")


if __name__ == "__main__":
    main()
