"""Asyncio UDP transport for link frames between processes (DESIGN: link/, live drivers).

:func:`open_endpoint` gives a :class:`UdpEndpoint` that sends and receives
frames (bytes) as UDP datagrams: the same frames :class:`~railstop.link.channel.SimChannel`
carries in simulation, here over real sockets. It is a driver at the edge
(DESIGN "one idea"): it opens a socket; the units it feeds (the safety layer,
the TASC units) stay pure.

* One frame = one datagram. Frames longer than ``max_frame_bytes`` (default
  1472 = Ethernet MTU 1500 − IPv4 20 − UDP 8, so no IP fragmentation) are
  refused on send with :class:`~railstop.link.channel.LinkError`; longer
  datagrams received are dropped and counted.
* The receive queue is bounded (``queue_frames`` in all) and fair between the
  source addresses: each source has its own first-in first-out queue and
  :meth:`UdpEndpoint.take` / :meth:`UdpEndpoint.recv` serve the sources in
  turn, one frame each. When the queue is full the *oldest* frame of a source
  holding at least its share (the arriving one if it does, else the longest)
  is dropped and counted (a late TASC telegram is worth less than the newest
  one): a source flooding the endpoint loses its own frames, one that sends
  fewer than its share loses none, and it is served in turn however many
  frames the flood queued (DESIGN rule 9).
* Datagrams the kernel drops before the endpoint sees them (socket receive
  buffer full) are counted too, on Linux: the socket has ``SO_RXQ_OVFL`` set and
  is read with ``recvmsg``, whose ancillary data carries the kernel's drop
  counter of the socket (``EndpointStats.dropped_by_kernel``). The counter
  arrives with each datagram, as it stood when that datagram was queued, so
  drops after the last datagram received show only with the next one; when
  the process reads its totals and when the endpoint closes, the counter is
  read from the kernel's socket table (``/proc/self/net/udp``) too, so drops
  after the last datagram are counted as well. Where
  the option does not exist (not Linux) or the event loop cannot watch a socket
  (Windows' proactor), the endpoint uses asyncio's own datagram transport and
  the counter is None: unknown, not zero.
* Every drop is counted: by the kernel, by the queue, too long, a socket
  error, and the frames still waiting (in the queue or the socket's buffer)
  when the endpoint closes (:class:`EndpointStats`); :func:`process_udp_stats` sums them over
  every endpoint the process opened, for its printed counts.

Two processes (``python -m railstop.link.udp``)
-----------------------------------------------
``send --port P --count N ...`` encodes N TASC telegrams
(:func:`demo_telegram`, ``railstop.link.codec``), wraps each with
``railstop.link.safety.SafeSender`` and sends them; ``--replay K`` and
``--corrupt K`` also inject K verbatim re-sends of earlier frames and K
copies with one bit flipped (EN 50159 threats: repetition, corruption), so a
test sees the receiver reject them over real sockets.
``receive --port P --count N ...`` binds P (it says ``listening on host:port``
on stderr once bound), accepts frames with ``SafeReceiver`` until N were
delivered (or ``--wait-s`` ran out), lingers ``--linger-s`` for stragglers,
decodes the delivered payloads and prints one JSON line:
``{"counts": receiver.counts, "delivered": ..., "rejected": {reason: n}, ...}``;
with the endpoint's counts (``datagrams``, ``dropped_queue_full``,
``dropped_oversize``, ``dropped_by_kernel``: null where it cannot be known);
exit status 0 when N were delivered, 1 when not, 2 on a usage error.
Category 3 (``--category 3``, open transmission: radio) needs ``--key-file``,
a file holding the master key (mode 0600); each direction uses
``safety.link_key(master, src, dst)``.
Categories 1 and 2 use a CRC-32 and no key.

Time: the safety layer stamps and checks times in seconds. Sender and
receiver are different processes, so both count seconds since a shared epoch
given on the command line (``--epoch``, a ``time.time()`` value): this stands
for the GNSS-synchronised clocks of the wayside and the train (SPEC §2). Each
process reads the wall clock once at start to place its ``time.monotonic()``
on that epoch and then only uses the monotonic clock, at this edge only.
"""

from __future__ import annotations

import argparse
import asyncio
import collections
import json
import math
import os
import socket
import struct
import sys
import time
import weakref
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, NoReturn

from railstop.errors import RailstopError, TelegramError
from railstop.link.channel import LinkError
from railstop.link.codec import TascRequiredDecel, decode, encode
from railstop.link.keys import read_key_file
from railstop.link.safety import Delivered, SafeReceiver, SafeSender, check_master_key, link_key

Address = tuple[str, int]

#: Largest frame sent by default: Ethernet MTU 1500 − IPv4 header 20 − UDP header 8.
MAX_DATAGRAM_BYTES = 1472
DEFAULT_QUEUE_FRAMES = 256

#: Socket option asking the kernel for its drop counter with each datagram (Linux: 40, absent from
#: Python's ``socket`` module); None where there is no such option.
SO_RXQ_OVFL: int | None = getattr(socket, "SO_RXQ_OVFL", 40 if sys.platform.startswith("linux") else None)
_DROPS = struct.Struct("=I")  # the counter: a native uint32 (wraps at 2^32)
_READS_PER_WAKE = 256  # datagrams read per readiness callback: a batch (a flood cannot starve the loop)


@dataclass(frozen=True, slots=True, kw_only=True)
class EndpointStats:
    """Counts of a :class:`UdpEndpoint`: frames sent and received, and why any were dropped."""

    sent: int
    received: int
    dropped_queue_full: int  # oldest frames dropped because the queue was full
    dropped_oversize: int  # received datagrams longer than max_frame_bytes
    dropped_by_kernel: int | None  # dropped by the kernel (receive buffer full); None = cannot know
    errors: int  # errors the socket reported (e.g. ICMP port unreachable)
    dropped_at_close: int = 0  # frames never taken: queued or in the socket's buffer at close
    sources_max: int = 0  # the most source addresses with frames queued at once

    def summary(self) -> dict[str, int | None]:
        """The counts as a dict (for a process's printed counts)."""
        return asdict(self)


class _Protocol(asyncio.DatagramProtocol):
    def __init__(self, endpoint: UdpEndpoint) -> None:
        self._endpoint = endpoint

    def datagram_received(self, data: bytes, addr: Any) -> None:
        self._endpoint._on_datagram(data, (str(addr[0]), int(addr[1])))

    def error_received(self, exc: Exception) -> None:
        self._endpoint._errors += 1

    def kernel_drops(self, count: int) -> None:
        """The kernel's drop counter of the socket, as it came with the latest datagram (a uint32:
        the drops since the last one are the difference modulo 2^32)."""
        self._endpoint._kernel_counter(count)

    def connection_lost(self, exc: Exception | None) -> None:
        self._endpoint._wake.set()  # a waiting recv() returns


class _RecvmsgTransport(asyncio.DatagramTransport):
    """A datagram transport that reads with ``recvmsg`` to get the ``SO_RXQ_OVFL`` drop counter.

    asyncio's own transport reads with ``recvfrom``, which drops ancillary data. Needs an event
    loop that can watch a socket (``add_reader``). Sends go out at once; a send the socket
    cannot take now (EAGAIN) waits in a buffer until it can, as with asyncio's transport.
    """

    def __init__(
        self, loop: asyncio.AbstractEventLoop, sock: socket.socket, protocol: _Protocol, max_size: int
    ) -> None:
        super().__init__(extra={"socket": sock, "sockname": sock.getsockname()})
        self._loop = loop
        self._sock = sock
        self._fd = sock.fileno()
        self._protocol = protocol
        self._max_size = max_size
        self._ancillary = socket.CMSG_SPACE(_DROPS.size)
        self._pending: collections.deque[tuple[bytes, Any]] = collections.deque()
        self._closing = False
        loop.add_reader(self._fd, self._read_ready)  # NotImplementedError: the caller falls back

    def _read_ready(self) -> None:
        for _ in range(_READS_PER_WAKE):
            try:
                data, ancdata, _flags, addr = self._sock.recvmsg(self._max_size, self._ancillary)
            except (BlockingIOError, InterruptedError):
                return
            except OSError as exc:  # e.g. ICMP port unreachable of an earlier send
                self._protocol.error_received(exc)
                continue
            try:
                for level, kind, payload in ancdata:
                    if level == socket.SOL_SOCKET and kind == SO_RXQ_OVFL and len(payload) >= _DROPS.size:
                        self._protocol.kernel_drops(_DROPS.unpack_from(payload)[0])
                self._protocol.datagram_received(data, addr)
            except Exception as exc:  # DESIGN rule 9: a datagram never stops the reader; counted
                self._protocol.error_received(exc)
            if self._closing:
                return

    def sendto(self, data: bytes | bytearray | memoryview, addr: Any = None) -> None:
        if self._closing:
            raise LinkError("endpoint is closed")
        if not self._pending:
            try:
                self._sock.sendto(data, addr)
                return
            except (BlockingIOError, InterruptedError):
                self._loop.add_writer(self._fd, self._write_ready)
            except OSError as exc:
                self._protocol.error_received(exc)
                return
        self._pending.append((bytes(data), addr))

    def _write_ready(self) -> None:
        while self._pending:
            data, addr = self._pending[0]
            try:
                self._sock.sendto(data, addr)
            except (BlockingIOError, InterruptedError):
                return
            except OSError as exc:
                self._protocol.error_received(exc)
            self._pending.popleft()
        self._loop.remove_writer(self._fd)
        if self._closing:
            self._finish()

    def is_closing(self) -> bool:
        return self._closing

    def close(self) -> None:
        """Stop reading; close the socket once the sends waiting in the buffer are out."""
        if self._closing:
            return
        self._closing = True
        self._loop.remove_reader(self._fd)
        if not self._pending:
            self._finish()

    def abort(self) -> None:
        self._closing = True
        self._pending.clear()
        self._loop.remove_reader(self._fd)
        self._loop.remove_writer(self._fd)
        self._finish()

    def _finish(self) -> None:
        if self._sock.fileno() < 0:
            return
        self._loop.call_soon(self._protocol.connection_lost, None)
        self._sock.close()


def _socket_table_drops(sock: socket.socket) -> int | None:
    """The kernel's drop counter of ``sock`` read from its socket table (Linux: the last column of
    ``/proc/self/net/udp`` or ``udp6``, the same counter ``SO_RXQ_OVFL`` carries); None where it
    cannot be read."""
    try:
        inode = str(os.fstat(sock.fileno()).st_ino)
    except OSError:
        return None
    for table in ("/proc/self/net/udp", "/proc/self/net/udp6"):
        try:
            with open(table, encoding="ascii", errors="replace") as fh:
                next(fh, None)  # the header
                for row in fh:
                    cols = row.split()
                    if len(cols) >= 13 and cols[9] == inode:
                        return int(cols[-1]) if cols[-1].isdigit() else None
        except OSError:
            continue
    return None


def _enable_drop_counter(sock: socket.socket) -> bool:
    """Ask the kernel for its drop counter with each datagram; False where it cannot."""
    if SO_RXQ_OVFL is None:
        return False
    try:
        sock.setsockopt(socket.SOL_SOCKET, SO_RXQ_OVFL, 1)
    except OSError:
        return False
    return True


class UdpEndpoint:
    """A UDP socket carrying frames; made by :func:`open_endpoint`."""

    def __init__(self, *, remote: Address | None, queue_frames: int, max_frame_bytes: int) -> None:
        self._transport: asyncio.DatagramTransport | None = None
        self._remote = remote
        # One FIFO per source address with frames queued; _turn: those sources in serving order.
        self._queues: dict[Address, collections.deque[bytes]] = {}
        self._turn: collections.deque[Address] = collections.deque()
        self._queued = 0
        self._queue_frames = queue_frames
        self._max_frame_bytes = max_frame_bytes
        self._wake = asyncio.Event()
        self._sent = 0
        self._received = 0
        self._dropped_full = 0
        self._dropped_oversize = 0
        self._dropped_kernel: int | None = None  # None until open_endpoint enables the counter
        self._kernel_seen = 0  # the kernel's counter as it came last (uint32)
        self._dropped_at_close = 0
        self._errors = 0
        self._sources_max = 0
        self._counted = False  # added to the process's totals (at close)
        _OPEN.add(self)

    # -- socket callbacks ------------------------------------------------

    def _on_datagram(self, data: bytes, addr: Address) -> None:
        if len(data) > self._max_frame_bytes:
            self._dropped_oversize += 1
            return
        q = self._queues.get(addr)
        if q is None:
            q = self._queues[addr] = collections.deque()
            self._turn.append(addr)
            self._sources_max = max(self._sources_max, len(self._queues))
        q.append(data)
        self._queued += 1
        self._received += 1
        if self._queued > self._queue_frames:
            # Full: the oldest frame of a source holding at least its share goes. The arriving
            # source if it does (a flood pays for itself, at O(1)); else the longest queue. A
            # source below its share never loses a frame (module docstring).
            if len(q) * len(self._queues) >= self._queued:
                victim = addr
            else:
                victim = max(self._queues, key=lambda a: len(self._queues[a]))
            vq = self._queues[victim]
            vq.popleft()
            self._queued -= 1
            self._dropped_full += 1
            if not vq:
                del self._queues[victim]
                self._turn.remove(victim)
        self._wake.set()

    def _pop(self) -> tuple[bytes, Address]:
        """The next frame in turn: the oldest of the next source, which then goes to the back."""
        addr = self._turn.popleft()
        q = self._queues[addr]
        data = q.popleft()
        self._queued -= 1
        if q:
            self._turn.append(addr)
        else:
            del self._queues[addr]
        return data, addr

    # -- public ----------------------------------------------------------

    @property
    def local_address(self) -> Address:
        """The bound (host, port); port is the real one when 0 was asked for."""
        if self._transport is None:
            raise LinkError("endpoint is not open")
        host, port = self._transport.get_extra_info("sockname")[:2]
        return str(host), int(port)

    @property
    def closed(self) -> bool:
        return self._transport is None or self._transport.is_closing()

    @property
    def stats(self) -> EndpointStats:
        return EndpointStats(
            sent=self._sent,
            received=self._received,
            dropped_queue_full=self._dropped_full,
            dropped_oversize=self._dropped_oversize,
            dropped_by_kernel=self._dropped_kernel,
            errors=self._errors,
            dropped_at_close=self._dropped_at_close,
            sources_max=self._sources_max,
        )

    def _socket(self) -> socket.socket | None:
        sock = None if self._transport is None else self._transport.get_extra_info("socket")
        return sock if isinstance(sock, socket.socket) and sock.fileno() >= 0 else None

    def _read_kernel_drops(self) -> None:
        """Bring ``dropped_by_kernel`` up to the kernel's counter now (drops after the last datagram
        received show in no datagram's ancillary data)."""
        sock = self._socket()
        if self._dropped_kernel is None or sock is None:
            return
        count = _socket_table_drops(sock)
        if count is not None:
            self._kernel_counter(count)

    def _kernel_counter(self, count: int) -> None:
        """The kernel's drop counter as it stands now (a uint32, from a datagram's ancillary data or
        the socket table): the drops since it was last seen are the difference modulo 2^32."""
        self._dropped_kernel = (self._dropped_kernel or 0) + (count - self._kernel_seen) % (1 << 32)
        self._kernel_seen = count % (1 << 32)

    def send(self, frame: bytes, addr: Address | None = None) -> None:
        """Send one frame as one datagram to ``addr`` (default: the endpoint's remote)."""
        if not isinstance(frame, bytes | bytearray | memoryview):
            raise LinkError(f"frame must be bytes (got {type(frame).__name__})")
        frame = bytes(frame)
        if len(frame) > self._max_frame_bytes:
            raise LinkError(f"frame of {len(frame)} bytes exceeds max_frame_bytes = {self._max_frame_bytes}")
        target = addr if addr is not None else self._remote
        if target is None:
            raise LinkError("no address: give addr or open the endpoint with a remote")
        if self._transport is None or self._transport.is_closing():
            raise LinkError("endpoint is closed")
        self._transport.sendto(frame, target)
        self._sent += 1

    async def recv(self, timeout_s: float | None = None) -> tuple[bytes, Address] | None:
        """The next queued frame and its sender (as :meth:`take`); None after ``timeout_s`` (None =
        wait) or once closed."""
        if timeout_s is not None and not (timeout_s >= 0.0 and math.isfinite(timeout_s)):
            raise LinkError(f"timeout_s must be a non-negative number (got {timeout_s!r})")
        loop = asyncio.get_running_loop()
        deadline = None if timeout_s is None else loop.time() + timeout_s
        while not self._queued:
            if self.closed:
                return None
            self._wake.clear()
            remaining = None if deadline is None else deadline - loop.time()
            if remaining is not None and remaining <= 0.0:
                return None
            try:
                await asyncio.wait_for(self._wake.wait(), remaining)
            except TimeoutError:
                return None
        return self._pop()

    def take(self) -> tuple[bytes, Address] | None:
        """The next queued frame and its sender (the sources in turn, each source's oldest first),
        or None at once when none is queued."""
        return self._pop() if self._queued else None

    @property
    def queued(self) -> int:
        """Frames waiting in the queue."""
        return self._queued

    def close(self) -> None:
        """Close the socket. The frames never taken (queued, or still in the socket's buffer) are
        counted as dropped at close, and the kernel's drop counter is read one last time."""
        if self._transport is not None and not self._transport.is_closing():
            sock = self._socket()
            if sock is not None:
                while True:  # what the kernel still holds for us: read and counted, never delivered
                    try:
                        sock.recv(1)
                    except OSError:  # EAGAIN: empty (the socket is non-blocking), or any error
                        break
                    self._dropped_at_close += 1
            self._read_kernel_drops()
            self._dropped_at_close += self._queued
            self._queues.clear()
            self._turn.clear()
            self._queued = 0
            self._transport.close()
        _count_closed(self)

    async def __aenter__(self) -> UdpEndpoint:
        return self

    async def __aexit__(self, *exc: object) -> None:
        self.close()


# Every endpoint of this process, for its totals: those open, and the sum of those closed.
_OPEN: weakref.WeakSet[UdpEndpoint] = weakref.WeakSet()
_CLOSED: dict[str, int] = {}
_CLOSED_UNKNOWN_KERNEL = [0]  # closed endpoints whose kernel drops could not be known


def _count_closed(ep: UdpEndpoint) -> None:
    if ep._counted:
        return
    ep._counted = True
    _OPEN.discard(ep)
    _add(_CLOSED, ep.stats)
    if ep.stats.dropped_by_kernel is None:
        _CLOSED_UNKNOWN_KERNEL[0] += 1


def _add(into: dict[str, int], stats: EndpointStats) -> None:
    for name, value in stats.summary().items():
        if name == "sources_max":
            into[name] = max(into.get(name, 0), int(value or 0))
        elif value is not None:
            into[name] = into.get(name, 0) + int(value)
    into["endpoints"] = into.get("endpoints", 0) + 1


def process_udp_stats() -> dict[str, int | None]:
    """Every UDP endpoint this process opened, summed (open and closed): datagrams sent and
    received, every drop by where it happened (the kernel, the queue, too long), socket errors.
    ``dropped_by_kernel`` is None if any endpoint could not know it (not Linux)."""
    out: dict[str, int] = dict(_CLOSED)
    unknown = _CLOSED_UNKNOWN_KERNEL[0]
    for ep in list(_OPEN):
        ep._read_kernel_drops()
        _add(out, ep.stats)
        unknown += ep.stats.dropped_by_kernel is None
    result: dict[str, int | None] = {
        "endpoints": out.get("endpoints", 0),
        "sent": out.get("sent", 0),
        "received": out.get("received", 0),
        "dropped_by_kernel": None if unknown else out.get("dropped_by_kernel", 0),
        "dropped_queue_full": out.get("dropped_queue_full", 0),
        "dropped_oversize": out.get("dropped_oversize", 0),
        "dropped_at_close": out.get("dropped_at_close", 0),
        "errors": out.get("errors", 0),
    }
    return result


def local_for(remote: Address) -> Address:
    """Where to bind to reach ``remote``: loopback for a peer on loopback, any address otherwise;
    any free port."""
    return ("127.0.0.1" if remote[0] in ("127.0.0.1", "localhost") else "0.0.0.0", 0)


async def open_endpoint(
    local: Address,
    remote: Address | None = None,
    *,
    queue_frames: int = DEFAULT_QUEUE_FRAMES,
    max_frame_bytes: int = MAX_DATAGRAM_BYTES,
    receive_buffer_bytes: int | None = None,
) -> UdpEndpoint:
    """Bind a UDP endpoint at ``local`` (port 0 = any free port); ``remote`` = default destination.

    ``receive_buffer_bytes`` sets the socket's SO_RCVBUF (the kernel may round it; None = the
    system default). ``stats.dropped_by_kernel`` counts what the kernel dropped when that buffer
    was full: 0 from the start on Linux, None where it cannot be known (see the module docstring).
    """
    if queue_frames < 1:
        raise LinkError(f"queue_frames must be >= 1 (got {queue_frames!r})")
    if not 1 <= max_frame_bytes <= 65507:  # largest UDP payload over IPv4
        raise LinkError(f"max_frame_bytes must be 1..65507 (got {max_frame_bytes!r})")
    if receive_buffer_bytes is not None and receive_buffer_bytes < 1:
        raise LinkError(f"receive_buffer_bytes must be >= 1 (got {receive_buffer_bytes!r})")
    endpoint = UdpEndpoint(remote=remote, queue_frames=queue_frames, max_frame_bytes=max_frame_bytes)
    loop = asyncio.get_running_loop()
    sock = await _bound_socket(loop, local)
    protocol = _Protocol(endpoint)
    try:
        if receive_buffer_bytes is not None:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, receive_buffer_bytes)
        transport: asyncio.DatagramTransport | None = None
        if _enable_drop_counter(sock):
            try:
                # One byte more than a frame may have: a longer datagram shows as too long.
                transport = _RecvmsgTransport(loop, sock, protocol, max_frame_bytes + 1)
                endpoint._dropped_kernel = 0
            except NotImplementedError:  # an event loop that cannot watch a socket
                transport = None
        if transport is None:
            transport, _ = await loop.create_datagram_endpoint(lambda: protocol, sock=sock)
    except OSError as exc:
        sock.close()
        raise LinkError(f"cannot set up UDP {local[0]}:{local[1]}: {exc.strerror or exc}") from None
    endpoint._transport = transport
    return endpoint


async def _bound_socket(loop: asyncio.AbstractEventLoop, local: Address) -> socket.socket:
    """A non-blocking UDP socket bound to ``local`` (the first of its addresses that binds)."""
    host, port = local
    try:
        infos = await loop.getaddrinfo(host, port, type=socket.SOCK_DGRAM, proto=socket.IPPROTO_UDP)
    except OSError as exc:
        raise LinkError(f"cannot bind UDP {host}:{port}: {exc.strerror or exc}") from None
    problem: OSError | None = None
    for family, kind, proto, _, address in infos:
        sock = socket.socket(family, kind, proto)
        try:
            sock.setblocking(False)
            sock.bind(address)
        except OSError as exc:
            sock.close()
            problem = exc
            continue
        return sock
    detail = "no address" if problem is None else problem.strerror or str(problem)
    raise LinkError(f"cannot bind UDP {host}:{port}: {detail}")


# --------------------------------------------------------------------------
# Two-process demo / test driver: python -m railstop.link.udp send|receive


class EpochClock:
    """Seconds since a shared epoch (stands for GNSS time, SPEC §2), ticking on time.monotonic()."""

    def __init__(self, epoch: float) -> None:
        # The only wall-clock read: place the monotonic clock on the shared epoch.
        self._offset_s = time.time() - time.monotonic() - epoch

    def now_s(self) -> float:
        return time.monotonic() + self._offset_s


def demo_telegram(i: int) -> TascRequiredDecel:
    """Telegram i of the demo: a TASC required deceleration (SPEC §1 claim 3 form 6), varying with i."""
    return TascRequiredDecel(train_id=101, detector=i % 5, required_mps2=(500 + i % 9000) / 1000)


def demo_payload(i: int) -> bytes:
    """The codec bytes of :func:`demo_telegram` ``i`` (type, payload, CRC-16: SPEC §5)."""
    return encode(demo_telegram(i))


def _spread(k: int, n: int) -> list[int]:
    """k injection points among genuine frames 0..n-2 (never after the last genuine frame)."""
    if k <= 0 or n < 2:
        return []
    if k == 1:
        return [(n - 2) // 2]
    return [round(j * (n - 2) / (k - 1)) for j in range(k)]


def _direction_key(args: argparse.Namespace, src_id: int, dst_id: int) -> bytes | None:
    """Category 3: the key of this direction, derived from the shared master key (read from
    ``--key-file``); 1, 2: none (CRC-32). ``--key-hex`` is refused whatever its value."""
    if args.key_hex is not None:
        raise LinkError(
            "--key-hex: a key is never given on the command line (every user sees it in the process "
            "list): use --key-file FILE (mode 0600; railstop office new-key --out FILE writes one)"
        )
    if args.category != 3:
        if args.key_file is not None:
            raise LinkError(f"category {args.category} uses a CRC-32, not a key: leave out --key-file")
        return None
    if args.key_file is None:
        raise LinkError("category 3 needs --key-file (the shared master key)")
    return link_key(check_master_key(read_key_file(args.key_file)), src_id, dst_id)


async def run_sender(args: argparse.Namespace) -> dict[str, Any]:
    clock = EpochClock(args.epoch)
    key = _direction_key(args, args.src_id, args.dst_id)
    sender = SafeSender(args.src_id, args.dst_id, key=key, category=args.category)
    replay_after = collections.Counter(_spread(args.replay, args.count))
    corrupt_after = collections.Counter(_spread(args.corrupt, args.count))
    sent: list[bytes] = []
    injected = {"replayed": 0, "corrupted": 0}
    async with await open_endpoint((args.host, 0), (args.host, args.port)) as ep:
        i = 0
        nxt = sender.wrap(demo_payload(0), clock.now_s()) if args.count else b""
        while i < args.count:
            frame = nxt
            ep.send(frame)
            sent.append(frame)
            await asyncio.sleep(args.interval_s)
            if i + 1 < args.count:
                nxt = sender.wrap(demo_payload(i + 1), clock.now_s())
            # Repetition threat: an earlier frame again, verbatim.
            for _ in range(replay_after[i]):
                ep.send(sent[max(i - 1, 0)])
                injected["replayed"] += 1
                await asyncio.sleep(args.interval_s)
            # Corruption threat: a copy of the next genuine frame with one bit flipped, sent first.
            for _ in range(corrupt_after[i]):
                bad = bytearray(nxt)
                bad[len(bad) // 2] ^= 0x10
                ep.send(bytes(bad))
                injected["corrupted"] += 1
                await asyncio.sleep(args.interval_s)
            i += 1
        await asyncio.sleep(args.interval_s)  # let the socket report a refused last datagram
        stats = ep.stats
    return {"sent": stats.sent, "genuine": len(sent), **injected, "send_errors": stats.errors}


async def run_receiver(args: argparse.Namespace) -> dict[str, Any]:
    clock = EpochClock(args.epoch)
    receiver = SafeReceiver(
        args.own_id,
        args.peer_id,
        key=_direction_key(args, args.peer_id, args.own_id),
        category=args.category,
        max_age_s=args.max_age_s,
        timeout_s=args.timeout_s,
        start_s=clock.now_s(),
        # Frames sent before this process started are refused (an earlier receiver may have
        # delivered them: the safety layer's restart rule).
        not_before_s=clock.now_s(),
    )
    delivered = 0
    decoded = 0
    telegram_errors: collections.Counter[str] = collections.Counter()
    rejected: collections.Counter[str] = collections.Counter()
    payloads: list[str] = []
    loop = asyncio.get_running_loop()
    async with await open_endpoint((args.host, args.port)) as ep:
        host, port = ep.local_address
        print(f"listening on {host}:{port}", file=sys.stderr, flush=True)
        deadline = loop.time() + args.wait_s
        linger_until: float | None = None
        while True:
            end = deadline if linger_until is None else min(deadline, linger_until)
            got = await ep.recv(max(0.0, end - loop.time()))
            if got is None:
                break
            try:
                result = receiver.accept(got[0], clock.now_s())
            except Exception:  # DESIGN rule 9: no frame stops the receiver; counted
                rejected["error"] += 1
                continue
            if isinstance(result, Delivered):
                delivered += 1
                payloads.append(result.payload.hex())
                try:
                    decode(result.payload)  # the codec's own checks (CRC-16) behind the safety layer
                    decoded += 1
                except TelegramError as exc:
                    telegram_errors[exc.reason] += 1
                except Exception:  # DESIGN rule 9: counted, survived
                    telegram_errors["error"] += 1
                if delivered >= args.count and linger_until is None:
                    linger_until = loop.time() + args.linger_s
            else:
                rejected[str(result.reason)] += 1
        stats = ep.stats
    return {
        "counts": dict(receiver.counts),
        "delivered": delivered,
        "decoded": decoded,
        "telegram_errors": dict(telegram_errors),
        "rejected": dict(rejected),
        "complete": delivered >= args.count,
        "datagrams": stats.received,
        "dropped_queue_full": stats.dropped_queue_full,
        "dropped_oversize": stats.dropped_oversize,
        "dropped_by_kernel": stats.dropped_by_kernel,
        "socket_errors": stats.errors,
        "payloads": payloads,
    }


def _finite(text: str) -> float:
    """A finite number; NaN is "not a number" and infinity "not finite" (never too big or small)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number (got {text!r})") from None
    if math.isnan(value):
        raise argparse.ArgumentTypeError(f"not a number (got {text!r})")
    if math.isinf(value):
        raise argparse.ArgumentTypeError(f"not finite (got {text!r})")
    return value


def _positive(text: str) -> float:
    value = _finite(text)
    if not value > 0.0:
        raise argparse.ArgumentTypeError(f"must be greater than 0 (got {text!r})")
    return value


def _non_negative(text: str) -> float:
    value = _finite(text)
    if value < 0.0:
        raise argparse.ArgumentTypeError(f"must be at least 0 (got {text!r})")
    return value


def _node_id(text: str) -> int:
    """A safety-layer node id: a uint16 in the frame header."""
    value = _whole(text)
    if not 0 <= value <= 0xFFFF:
        raise argparse.ArgumentTypeError(f"a node id is 0..65535 (got {text!r})")
    return value


def _whole(text: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a whole number (got {text!r})") from None


def _port(text: str) -> int:
    value = _whole(text)
    if not 1 <= value <= 65535:
        raise argparse.ArgumentTypeError(f"a UDP port is 1..65535 (got {text!r})")
    return value


class _Parser(argparse.ArgumentParser):
    """argparse with railstop's error form: one line ``error: ...``, exit code 2."""

    def error(self, message: str) -> NoReturn:
        print(f"error: {message}", file=sys.stderr)
        raise SystemExit(2)


def _non_negative_int(text: str) -> int:
    value = _whole(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be >= 0 (got {text!r})")
    return value


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="python -m railstop.link.udp",
        description="Send or receive safety-layer telegrams over UDP between two processes.",
    )
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)
    common = _Parser(add_help=False)
    common.add_argument("--host", default="127.0.0.1", help="address (default: loopback)")
    common.add_argument("--port", type=_port, required=True, help="the receiver's UDP port (1..65535)")
    common.add_argument("--count", type=_non_negative_int, required=True, help="genuine telegrams")
    common.add_argument(
        "--category", type=int, choices=(1, 2, 3), default=3, help="EN 50159 category of the transmission"
    )
    common.add_argument(
        "--key-file",
        dest="key_file",
        type=Path,
        default=None,
        help="file holding the shared master key in hexadecimal, mode 0600 (category 3; each direction "
        "uses a key derived from it)",
    )
    # Declared only to refuse it in one line: a key on a command line is every user's to read.
    common.add_argument("--key-hex", dest="key_hex", default=None, help=argparse.SUPPRESS)
    common.add_argument(
        "--epoch",
        type=_finite,
        required=True,
        help="shared time origin, a time.time() value (stands for GNSS-synchronised clocks)",
    )

    snd = sub.add_parser("send", parents=[common], help="wrap and send telegrams")
    snd.add_argument("--src-id", type=_node_id, default=1, help="this sender's id (0..65535)")
    snd.add_argument("--dst-id", type=_node_id, default=2, help="the receiver's id (0..65535)")
    snd.add_argument("--interval-s", type=_non_negative, default=0.005, help="pause between datagrams")
    snd.add_argument("--replay", type=_non_negative_int, default=0, help="inject K re-sent old frames")
    snd.add_argument(
        "--corrupt", type=_non_negative_int, default=0, help="inject K frames with a bit flipped"
    )

    rcv = sub.add_parser("receive", parents=[common], help="accept telegrams, print JSON counts")
    rcv.add_argument("--own-id", type=_node_id, default=2, help="this receiver's id (0..65535)")
    rcv.add_argument("--peer-id", type=_node_id, default=1, help="the sender's id (0..65535)")
    rcv.add_argument("--max-age-s", type=_positive, default=1.0, help="oldest acceptable telegram")
    rcv.add_argument("--timeout-s", type=_positive, default=2.0, help="safety-layer supervision timeout")
    rcv.add_argument("--wait-s", type=_positive, default=10.0, help="give up after this long")
    rcv.add_argument("--linger-s", type=_non_negative, default=0.2, help="keep listening after the last one")
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        if args.command == "send":
            out = asyncio.run(run_sender(args))
            ok = out["send_errors"] == 0  # e.g. the receiver's port refused (ICMP unreachable)
        else:
            out = asyncio.run(run_receiver(args))
            ok = bool(out["complete"])
    except RailstopError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(json.dumps(out, sort_keys=True), flush=True)
    return 0 if ok else 1


__all__ = [
    "MAX_DATAGRAM_BYTES",
    "EndpointStats",
    "EpochClock",
    "UdpEndpoint",
    "build_parser",
    "demo_payload",
    "demo_telegram",
    "main",
    "open_endpoint",
    "process_udp_stats",
]


if __name__ == "__main__":
    sys.exit(main())
