"""Telegram throughput: codec encode+decode and safety-layer wrap+accept per second.

    python benchmarks/telegram_throughput.py [--count 100000]

The payload is a realistic TASC telegram (SPEC §1 form 6, required
deceleration: an 8-byte codec frame). Every figure is measured here on one
core; nothing is asserted (DESIGN: speed targets live in benchmarks, never
as timed tests).
"""

from __future__ import annotations

import argparse
import time

from railstop.link.codec import CbtcReport, TascRequiredDecel, decode, encode
from railstop.link.safety import Delivered, SafeReceiver, SafeSender, frame_size, link_key


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


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--count", type=int, default=100_000, help="telegrams per measurement")
    args = parser.parse_args()
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
