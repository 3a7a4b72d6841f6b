"""Fuzz the codec's ``decode``, the safety layer's ``SafeReceiver.accept`` and ``SafePeers.accept``,
and a live UDP endpoint.

    python benchmarks/fuzz_telegrams.py [--inputs 1000000] [--peers 200000] [--udp 20000] [--seed S]

``--peers N``: N inputs to ``SafePeers.accept`` of a zone controller (its
live predicate: itself and 4096 train ids): random bytes, frames with forged
headers (any source, its own id among them, any destination, sequence number,
timestamp and length, a MAC made without the key), bit flips and replays of
genuine frames, and genuine frames. Failures: any exception, a delivery that
is not a genuine new frame, receiver state for anyone but the genuine peer,
counters that do not add up. ``--udp N``: N datagrams (random and forged, a
genuine frame every 100th) over loopback into a UDP endpoint read as a live
process reads it (``take`` then ``SafePeers.accept``); it prints the
endpoint's and the safety layer's counters.

Feeds ``--inputs`` inputs to ``decode`` and as many to ``accept`` (half to a
category 1 receiver, half to a category 3 one): random lengths and bytes,
random bytes behind a valid type byte, frames with a valid CRC around random
field values, and mutations of valid telegrams / safety frames (bit flips,
truncations, extensions, byte swaps, type changes, header changes), plus
replays, delays, forgeries and the genuine frames themselves. It counts every
outcome by reason. Anything else is a failure, printed with its traceback,
and the exit code is 1:

- an exception other than ``TelegramError`` from ``decode``, or any
  exception from ``accept``;
- a decoded telegram that does not re-encode to the same bytes, or a
  genuine telegram that does not decode;
- a delivered safety frame whose payload or sequence number is not a
  genuine one, or whose sequence number does not increase.

Inputs come from ``numpy.random.default_rng(seed)``, drawn in batches.
"""

from __future__ import annotations

import argparse
import asyncio
import collections
import socket
import struct
import sys
import time
import traceback
from collections.abc import Callable

import numpy as np

from railstop.errors import TelegramError
from railstop.link.codec import LAYOUTS, Layout, crc16, decode, encode
from railstop.link.safety import Delivered, SafePeers, SafeReceiver, SafeSender, link_key
from railstop.link.udp import open_endpoint

PEERS_KEY = b"fuzz master key of 32 bytes, v2."
ZC, TRAIN = 0x0300, 0x2001  # the zone controller and a train radio, as in the live CBTC line

BATCH = 20_000
MAX_AGE_S = 0.5
DECODE_KINDS = (
    "random",
    "random behind a type",
    "random fields, valid CRC",
    "bit flips",
    "truncation",
    "extension",
    "byte swap",
    "type change",
    "genuine",
)
ACCEPT_KINDS = (
    "genuine",
    "replay",
    "bit flips",
    "truncation",
    "extension",
    "byte swap",
    "random",
    "forgery",
    "delayed",
    "header change",
)


class Failures:
    def __init__(self) -> None:
        self.count = 0
        self.shown = 0

    def record(self, what: str, data: bytes, exc: BaseException | None = None) -> None:
        self.count += 1
        if self.shown < 10:
            self.shown += 1
            print(f"UNEXPECTED {what}: input {data.hex()}", file=sys.stderr)
            if exc is not None:
                traceback.print_exception(exc, file=sys.stderr)


def _raw_frame(layout: Layout, rng: np.random.Generator, *, in_range: bool) -> bytes:
    """A frame with a correct CRC built straight from wire integers (not through encode)."""
    raws = []
    for f in layout.fields:
        bits = f.size * 8
        lo, hi = (-(1 << (bits - 1)), (1 << (bits - 1)) - 1) if f.code.islower() else (0, (1 << bits) - 1)
        if in_range:
            if f.kind == "enum" and f.choices:
                raws.append(int(rng.choice(list(f.choices))))
                continue
            lo, hi = f.raw_min, f.raw_max
            if f.absent is not None and rng.random() < 0.2:
                raws.append(f.absent)
                continue
        raws.append(int(rng.integers(lo, hi, endpoint=True)))
    body = bytes((layout.code,)) + layout.packer.pack(*raws)
    return body + crc16(body).to_bytes(2, "big")


def fuzz_decode(n: int, rng: np.random.Generator, failures: Failures) -> collections.Counter[str]:
    layouts = list(LAYOUTS.values())
    codes = np.array([lay.code for lay in layouts])
    pool = [_raw_frame(layouts[i % len(layouts)], rng, in_range=True) for i in range(4096)]
    for frame in pool:  # the genuine pool must decode and re-encode
        try:
            if encode(decode(frame)) != frame:
                failures.record("pool frame does not re-encode", frame)
        except Exception as exc:
            failures.record("pool frame does not decode", frame, exc)
    outcomes: collections.Counter[str] = collections.Counter()
    kinds_seen: collections.Counter[str] = collections.Counter()
    done = 0
    while done < n:
        b = min(BATCH, n - done)
        kind = rng.integers(0, len(DECODE_KINDS), b)
        length = rng.integers(0, 41, b)
        pick = rng.integers(0, len(pool), b)
        pos = rng.integers(0, 1 << 30, (b, 3))
        nflip = rng.integers(1, 4, b)
        type_pick = rng.integers(0, len(codes), b)
        noise = rng.bytes(b * 48)
        fresh = [_raw_frame(layouts[int(t)], rng, in_range=False) for t in type_pick[kind == 2]]
        k_fresh = 0
        for i in range(b):
            k = int(kind[i])
            base = pool[int(pick[i])]
            chunk = noise[i * 48 : i * 48 + 48]
            if k == 0:
                data = chunk[: int(length[i])]
            elif k == 1:
                lay = layouts[int(type_pick[i])]
                size = max(0, lay.frame_size - 1 + int(length[i]) % 5 - 2)
                data = bytes((lay.code,)) + chunk[:size]
            elif k == 2:
                data = fresh[k_fresh]
                k_fresh += 1
            elif k == 3:
                buf = bytearray(base)
                for j in range(int(nflip[i])):
                    p = int(pos[i, j]) % (8 * len(buf))
                    buf[p // 8] ^= 1 << (p % 8)
                data = bytes(buf)
            elif k == 4:
                data = base[: int(pos[i, 0]) % len(base)]
            elif k == 5:
                data = base + chunk[: 1 + int(length[i]) % 8]
            elif k == 6:
                buf = bytearray(base)
                a, c = int(pos[i, 0]) % len(buf), int(pos[i, 1]) % len(buf)
                buf[a], buf[c] = buf[c], buf[a]
                data = bytes(buf)
            elif k == 7:
                data = bytes((int(codes[int(type_pick[i])]),)) + base[1:]
            else:
                data = base
            kinds_seen[DECODE_KINDS[k]] += 1
            try:
                msg = decode(data)
            except TelegramError as exc:
                outcomes[exc.reason] += 1
                continue
            except Exception as exc:
                failures.record("decode raised", data, exc)
                continue
            outcomes["decoded"] += 1
            try:
                if encode(msg) != data:
                    failures.record("decoded telegram re-encodes differently", data)
            except Exception as exc:
                failures.record("decoded telegram does not encode", data, exc)
        done += b
    outcomes["_kinds"] = len(kinds_seen)
    return outcomes


def fuzz_accept(
    n: int, category: int, rng: np.random.Generator, failures: Failures
) -> collections.Counter[str]:
    key = link_key(b"fuzz master key of 32 bytes....", 1, 2) if category == 3 else None
    sender = SafeSender(1, 2, key=key, category=category)
    receiver = SafeReceiver(2, 1, key=key, category=category, max_age_s=MAX_AGE_S, timeout_s=1.0)
    if category == 3:
        forger = SafeSender(1, 2, key=link_key(b"another master key, 32 bytes...", 1, 2), category=3)
    else:
        forger = SafeSender(3, 2, category=category)  # a station that is not the peer
    genuine: dict[int, bytes] = {}
    recent: collections.deque[bytes] = collections.deque(maxlen=128)
    last_delivered = 0
    now_ms = 0
    payloads = [_raw_frame(lay, rng, in_range=True) for lay in LAYOUTS.values()]
    outcomes: collections.Counter[str] = collections.Counter()

    def send(t_ms: int) -> bytes:
        payload = payloads[len(genuine) % len(payloads)]
        genuine[sender.next_seq] = payload
        frame = sender.wrap(payload, t_ms / 1000)
        recent.append(frame)
        return frame

    send(0)
    done = 0
    while done < n:
        b = min(BATCH, n - done)
        kind = rng.integers(0, len(ACCEPT_KINDS), b)
        step = rng.integers(0, 21, b)
        pick = rng.integers(0, 1 << 30, b)
        pos = rng.integers(0, 1 << 30, (b, 3))
        nflip = rng.integers(1, 4, b)
        length = rng.integers(0, 61, b)
        delay = rng.integers(0, 2 * round(MAX_AGE_S * 1000), b)
        noise = rng.bytes(b * 64)
        for i in range(b):
            now_ms += int(step[i])
            k = int(kind[i])
            base = recent[int(pick[i]) % len(recent)]
            chunk = noise[i * 64 : i * 64 + 64]
            if k == 0:
                data = send(now_ms)
            elif k == 1:
                data = base
            elif k == 2:
                buf = bytearray(base)
                for j in range(int(nflip[i])):
                    p = int(pos[i, j]) % (8 * len(buf))
                    buf[p // 8] ^= 1 << (p % 8)
                data = bytes(buf)
            elif k == 3:
                data = base[: int(pos[i, 0]) % len(base)]
            elif k == 4:
                data = base + chunk[: 1 + int(length[i]) % 16]
            elif k == 5:
                buf = bytearray(base)
                a, c = int(pos[i, 0]) % len(buf), int(pos[i, 1]) % len(buf)
                buf[a], buf[c] = buf[c], buf[a]
                data = bytes(buf)
            elif k == 6:
                data = chunk[: int(length[i])]
            elif k == 7:
                forger.next_seq = sender.next_seq
                data = forger.wrap(chunk[:8], now_ms / 1000)
            elif k == 8:
                data = send(now_ms - int(delay[i]))
            else:
                buf = bytearray(base)
                buf[int(pos[i, 0]) % 14] ^= 1 << int(pos[i, 1]) % 8
                data = bytes(buf)
            try:
                got = receiver.accept(data, now_ms / 1000)
            except Exception as exc:
                failures.record(f"accept (category {category}) raised", data, exc)
                continue
            if isinstance(got, Delivered):
                outcomes["delivered"] += 1
                if genuine.get(got.seq) != got.payload or got.seq <= last_delivered:
                    failures.record(
                        f"category {category} delivered a frame that is not genuine or not new", data
                    )
                last_delivered = got.seq
            else:
                outcomes[got.reason] += 1
        done += b
    if sum(receiver.counts.values()) != n or receiver.counts["delivered"] != outcomes["delivered"]:
        failures.record(f"category {category} counters do not add up", b"")
    outcomes["_deletions"] = receiver.deletions
    return outcomes


def _zc_peers() -> SafePeers:
    return SafePeers(ZC, PEERS_KEY, max_age_s=MAX_AGE_S, peers=lambda p: p == ZC or 0x2000 <= p < 0x3000)


def _hostile(rng: np.random.Generator, k: int, recent: collections.deque[bytes]) -> bytes:
    """One hostile input of kind ``k`` (0 random bytes, 1 forged header, 2 bit flips, 3 replay)."""
    if k == 0:
        return rng.bytes(int(rng.integers(0, 61)))
    if k == 1:
        src = int(rng.choice([ZC, TRAIN, int(rng.integers(0x2000, 0x3000)), int(rng.integers(0, 1 << 16))]))
        dst = int(rng.choice([ZC, int(rng.integers(0, 1 << 16))]))
        n = int(rng.integers(0, 20))
        length = n if rng.random() < 0.8 else int(rng.integers(0, 256))
        head = struct.pack(
            ">BHHIIB", int(rng.choice([0x13, int(rng.integers(0, 256))])), src, dst,
            int(rng.integers(0, 1 << 32)), int(rng.integers(0, 1 << 32)), length,
        )  # fmt: skip
        return head + rng.bytes(n) + rng.bytes(8)
    base = recent[int(rng.integers(0, len(recent)))]
    if k == 2:
        buf = bytearray(base)
        for _ in range(int(rng.integers(1, 4))):
            p = int(rng.integers(0, 8 * len(buf)))
            buf[p // 8] ^= 1 << (p % 8)
        return bytes(buf)
    return base


def fuzz_peers(n: int, rng: np.random.Generator, failures: Failures) -> collections.Counter[str]:
    links = _zc_peers()
    train = SafePeers(TRAIN, PEERS_KEY, max_age_s=MAX_AGE_S, peers=lambda p: p == ZC)
    recent: collections.deque[bytes] = collections.deque(maxlen=64)
    genuine: set[bytes] = set()
    last_seq = 0
    now_ms = 0
    outcomes: collections.Counter[str] = collections.Counter()
    for i in range(n):
        now_ms += int(rng.integers(0, 10))
        k = int(rng.integers(0, 5))
        if k == 4 or not recent:
            data = train.wrap(i.to_bytes(4, "big"), ZC, now_ms / 1000)
            genuine.add(data[14:18])
            recent.append(data)
        else:
            data = _hostile(rng, k, recent)
        try:
            got = links.accept(data, now_ms / 1000)
        except Exception as exc:
            failures.record("SafePeers.accept raised", data, exc)
            continue
        if got is None:
            continue
        outcomes["delivered"] += 1
        if got[0] != TRAIN or got[1].payload not in genuine or got[1].seq <= last_seq:
            failures.record("SafePeers delivered a frame that is not genuine or not new", data)
        last_seq = got[1].seq
    outcomes.update(links.rejected)
    if sum(outcomes.values()) != n or links.delivered != outcomes["delivered"]:
        failures.record("SafePeers counters do not add up", b"")
    if links.peers_held > 1:
        failures.record(f"SafePeers holds {links.peers_held} receivers (1 genuine peer)", b"")
    outcomes["_held"] = links.peers_held
    return outcomes


async def _fuzz_udp(n: int, rng: np.random.Generator, failures: Failures) -> dict[str, object]:
    links = _zc_peers()
    train = SafePeers(TRAIN, PEERS_KEY, max_age_s=5.0, peers=lambda p: p == ZC)
    recent: collections.deque[bytes] = collections.deque([train.wrap(b"first", ZC, 0.0)], maxlen=64)
    genuine_sent = 0
    loop = asyncio.get_running_loop()
    t0 = loop.time()
    async with await open_endpoint(("127.0.0.1", 0), queue_frames=4096) as ep:

        def drain() -> None:
            while (got := ep.take()) is not None:
                try:
                    links.accept(got[0], loop.time() - t0)
                except Exception as exc:
                    failures.record("SafePeers.accept (UDP) raised", got[0], exc)

        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx:
            for i in range(n):
                if i % 100 == 0:
                    data = train.wrap(i.to_bytes(4, "big"), ZC, loop.time() - t0)
                    recent.append(data)
                    genuine_sent += 1
                else:
                    data = _hostile(rng, int(rng.integers(0, 4)), recent)
                tx.sendto(data, ep.local_address)
                if i % 50 == 49:
                    await asyncio.sleep(0)  # the endpoint reads; a live process's pace, not a flood
                    drain()
            await asyncio.sleep(0.2)
            drain()
        stats = ep.stats
    return {"genuine_sent": genuine_sent, "stats": stats, "links": links}


def _table(title: str, outcomes: collections.Counter[str], n: int, seconds: float) -> None:
    print(f"\n{title}: {n:,} inputs in {seconds:.1f} s = {n / seconds:,.0f} inputs/s")
    for reason, count in sorted(outcomes.items(), key=lambda kv: -kv[1]):
        if not reason.startswith("_"):
            print(f"  {reason:<18} {count:>10,}  {100 * count / n:6.2f} %")


def _timed(fn: Callable[[], collections.Counter[str]]) -> tuple[collections.Counter[str], float]:
    t0 = time.perf_counter()
    out = fn()
    return out, time.perf_counter() - t0


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "--inputs", type=int, default=1_000_000, help="inputs to decode, and as many to accept"
    )
    parser.add_argument("--peers", type=int, default=200_000, help="inputs to SafePeers.accept")
    parser.add_argument("--udp", type=int, default=20_000, help="datagrams into a live UDP endpoint")
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args()
    if args.inputs < 2 or args.peers < 0 or args.udp < 0:
        parser.error("--inputs: at least 2; --peers, --udp: at least 0")
    rng = np.random.default_rng(args.seed)
    failures = Failures()
    print(f"fuzz_telegrams: seed {args.seed}, {args.inputs:,} inputs to decode and {args.inputs:,} to accept")
    dec, dec_s = _timed(lambda: fuzz_decode(args.inputs, rng, failures))
    _table("decode", dec, args.inputs, dec_s)
    half = args.inputs // 2
    c1, c1_s = _timed(lambda: fuzz_accept(half, 1, rng, failures))
    _table("SafeReceiver.accept, category 1 (CRC-32)", c1, half, c1_s)
    print(f"  (deletions counted: {c1['_deletions']:,})")
    c3, c3_s = _timed(lambda: fuzz_accept(args.inputs - half, 3, rng, failures))
    _table("SafeReceiver.accept, category 3 (HMAC-SHA256/8)", c3, args.inputs - half, c3_s)
    print(f"  (deletions counted: {c3['_deletions']:,})")
    total = 2 * args.inputs
    seconds = dec_s + c1_s + c3_s
    if args.peers:
        pe, pe_s = _timed(lambda: fuzz_peers(args.peers, rng, failures))
        _table("SafePeers.accept (zone controller, 4096 possible peers)", pe, args.peers, pe_s)
        print(f"  (receivers held: {pe['_held']})")
        total, seconds = total + args.peers, seconds + pe_s
    if args.udp:
        t0 = time.perf_counter()
        out = asyncio.run(_fuzz_udp(args.udp, rng, failures))
        udp_s = time.perf_counter() - t0
        st, links = out["stats"], out["links"]
        assert isinstance(links, SafePeers)
        print(f"\nUDP endpoint + SafePeers: {args.udp:,} datagrams over loopback in {udp_s:.1f} s")
        print(f"  endpoint: {st}")
        held = links.peers_held
        print(f"  genuine sent {out['genuine_sent']}, delivered {links.delivered}, receivers held {held}")
        print(f"  refused: {dict(sorted(links.rejected.items()))}")
        total, seconds = total + args.udp, seconds + udp_s
    print(f"\ntotal {total:,} inputs in {seconds:.1f} s; unexpected: {failures.count}")
    if failures.count:
        sys.exit(1)


if __name__ == "__main__":
    main()
