"""The live line under attack: junk, forged ids, floods, replays and kill -9 restarts, measured.

    python benchmarks/live_attack.py [--minutes 2] [--trains 3] [--flood-rate 50000]

Starts the live line as ``railstop live run`` does (office, zone controller,
plant, stations, trains: five processes over UDP on loopback, scale 1, a key
generated for the run), with one more process in the middle: a UDP **relay**
(``python benchmarks/live_attack.py relay``) through which every link runs (each
process is given the relay's address for its peers). The relay forwards each
datagram, counts it, keeps the last frames of each link and direction, and on
SIGUSR1 sends every kept frame again (the replay attack, from the wire's own
frames); on SIGUSR2 it prints its counts (one JSON line).

Phase 1 (restarts and replays): each process in turn (zone controller, plant,
stations, trains, office) is killed with SIGKILL and started again with the
options the line needs (the zone controller from its state file), and the
frames captured before its restart are replayed after it. Phase 2 (counted
attacks on the last incarnations): random datagrams of random lengths to
every process's sockets (junk), well-formed safety headers with wrong MACs
naming every plausible source and destination (each receiver's own id, other
parties', out-of-range ids: forged), a flood at one process, a last replay.
Then every process is stopped (SIGTERM) and prints its counts.

Printed, per process and in total:

* **crashes**: a process that exited other than by this benchmark's own kill
  (SIGKILL) or stop (SIGTERM, exit status 0), or wrote a traceback. Target 0.
* **bad deliveries**: frames delivered that should not have been. Each last
  incarnation's delivered frames (its safety layers' counts) are compared with
  the genuine frames the relay forwarded to it since just before it started:
  more delivered than genuinely sent is a forged or replayed frame accepted.
  And every replayed frame must be refused as a replay (``repeated``,
  ``out_of_order``, ``stale``, ``old_session``): fewer such refusals than replays
  sent is a replay accepted. Either excess counts. Target 0.
* **trains moving without authority**, from the trains' reports to the office
  (position, speed, emergency brake, every second) and the plant's true
  positions at the end: a train whose speed rose between two reports while its
  emergency brake was applied at both (the brake must hold it), and two trains
  closer than a train's length (one past the authority that should have kept
  it behind the other). Target 0.
* **every drop counted**: the attack's datagrams sent to each last incarnation
  (junk, forged, flood, replays) against what it reports refused or dropped at
  every layer: the kernel (``SO_RXQ_OVFL``), its receive queue, too long, each
  safety layer's refusals by reason and the application's (codec, unexpected,
  not a train here). Unaccounted = sent - (refused + dropped) must not be
  positive.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import random
import selectors
import signal
import socket
import struct
import subprocess
import sys
import tempfile
import time
from collections import deque
from collections.abc import Iterable
from pathlib import Path
from typing import Any

EXE = [sys.executable, "-m", "railstop.cli"]
KEY_ENV = "RAILSTOP_OFFICE_KEY"
ROLES = ("office", "zone_controller", "plant", "stations", "trains")
#: The links through the relay: name -> (the process that sends first, the process it reaches).
LINKS = {
    "zc": ("trains", "zone_controller"),
    "plant": ("trains", "plant"),
    "stations": ("trains", "stations"),
    "sensors": ("plant", "stations"),
    "office-zc": ("zone_controller", "office"),
    "office-st": ("stations", "office"),
    "office-tr": ("trains", "office"),
}
REPLAY_REASONS = ("repeated", "out_of_order", "stale", "old_session")
# Safety-layer ids of the live line (railstop.link.cbtc_radio, live.plant, live.tasc, live.doors,
# live.office, link.release_link): every party's, a few out of range.
IDS = {
    "zc": 0x0300,
    "zc-release": 0x0301,
    "operator": 0x0310,
    "office": 900,
    "plant": 0x0281,
    "sensors": 0x0280,
    "trains-wiring": 0x4C00,
    "station": 0x0100,
    "platform": 0x0200,
    "train": 0x2000,
    "train-tasc": 0x4000,
    "train-doors": 0x4800,
}
HEADER = struct.Struct(">BHHIIB")
REPLAY_PER_MS = 2  # replayed frames the relay sends per loop turn (about a millisecond)


# ---------------------------------------------------------------------- the relay process


def relay_main(argv: list[str]) -> int:
    """``relay --link NAME:LISTEN_PORT:TARGET_PORT ... [--keep N]``: forward, count, keep, replay."""
    ap = argparse.ArgumentParser(prog="live_attack.py relay")
    ap.add_argument("--link", action="append", required=True)
    ap.add_argument("--keep", type=int, default=400)
    args = ap.parse_args(argv)
    sel = selectors.DefaultSelector()
    listen: dict[str, socket.socket] = {}
    target: dict[str, tuple[str, int]] = {}
    nat: dict[str, dict[tuple[str, int], socket.socket]] = {}
    newest: dict[str, tuple[str, int] | None] = {}
    kept_fwd: dict[str, deque[bytes]] = {}
    kept_back: dict[str, deque[bytes]] = {}
    counts: dict[str, dict[str, int]] = {}
    for spec in args.link:
        name, lp, tp = spec.split(":")
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
        s.bind(("127.0.0.1", int(lp)))
        s.setblocking(False)
        sel.register(s, selectors.EVENT_READ, ("listen", name, None))
        listen[name], target[name], nat[name], newest[name] = s, ("127.0.0.1", int(tp)), {}, None
        kept_fwd[name], kept_back[name] = deque(maxlen=args.keep), deque(maxlen=args.keep)
        counts[name] = {"fwd": 0, "back": 0, "replayed_fwd": 0, "replayed_back": 0}
    flags = {"replay": False, "snapshot": False, "stop": False}
    signal.signal(signal.SIGUSR1, lambda *_: flags.__setitem__("replay", True))
    signal.signal(signal.SIGUSR2, lambda *_: flags.__setitem__("snapshot", True))
    signal.signal(signal.SIGTERM, lambda *_: flags.__setitem__("stop", True))

    def upstream(name: str, client: tuple[str, int]) -> socket.socket:
        u = nat[name].get(client)
        if u is None:
            u = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            u.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
            u.bind(("127.0.0.1", 0))
            u.setblocking(False)
            sel.register(u, selectors.EVENT_READ, ("up", name, client))
            nat[name][client] = u
        return u

    def send(sock: socket.socket, data: bytes, addr: tuple[str, int]) -> None:
        with contextlib.suppress(OSError):  # a process down (being restarted): lost, as on the wire
            sock.sendto(data, addr)

    def snapshot() -> dict[str, Any]:
        return {
            "t": time.time(),
            "counts": {n: dict(c) for n, c in counts.items()},
            "clients": {n: (list(c) if c else None) for n, c in newest.items()},
        }

    # Replays go out paced (REPLAY_PER_MS a millisecond, between the forwarded frames): a burst
    # would only be dropped by the receiver's queue, and a replay dropped is not a replay refused.
    pending: deque[tuple[str, str, bytes]] = deque()
    print(json.dumps({"ready": True}), flush=True)
    while not flags["stop"]:
        for _ in range(min(len(pending), REPLAY_PER_MS)):
            name, way, data = pending.popleft()
            c = newest[name]
            if c is None:
                continue
            if way == "fwd":
                send(upstream(name, c), data, target[name])
            else:
                send(listen[name], data, c)
            counts[name]["replayed_" + way] += 1
        for key, _ in sel.select(timeout=0.001 if pending else 0.05):
            kind, name, client = key.data
            sock = key.fileobj
            assert isinstance(sock, socket.socket)
            for _ in range(64):
                try:
                    data, addr = sock.recvfrom(65535)
                except (BlockingIOError, InterruptedError):
                    break
                except OSError:
                    continue
                if kind == "listen":
                    came = (str(addr[0]), int(addr[1]))
                    newest[name] = came
                    send(upstream(name, came), data, target[name])
                    counts[name]["fwd"] += 1
                    kept_fwd[name].append(data)
                else:
                    send(listen[name], data, client)
                    counts[name]["back"] += 1
                    kept_back[name].append(data)
        if flags["replay"]:
            flags["replay"] = False
            for name in listen:
                pending.extend((name, "fwd", d) for d in kept_fwd[name])
                pending.extend((name, "back", d) for d in kept_back[name])
        if flags["snapshot"]:
            flags["snapshot"] = False
            print(json.dumps(snapshot()), flush=True)
    print(json.dumps(snapshot()), flush=True)
    return 0


# ---------------------------------------------------------------------- the line


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class Line:
    """The five processes and the relay, each started (and started again) with its options."""

    def __init__(self, workdir: Path, *, trains: int, spacing_m: float) -> None:
        self.dir = workdir
        self.trains, self.spacing_m = trains, spacing_m
        self.env = {**os.environ, KEY_ENV: os.urandom(32).hex()}
        self.port = {r: free_port() for r in ("office", "zone_controller", "plant", "stations")}
        self.relay_port = {name: free_port() for name in LINKS}
        self.epoch = time.time()
        self.procs: dict[str, subprocess.Popen[bytes]] = {}
        self.incarnation: dict[str, int] = dict.fromkeys(ROLES, 0)
        self.killed: list[str] = []  # by this benchmark (SIGKILL), not crashes
        self.crashes: dict[str, int] = dict.fromkeys(ROLES, 0)
        self.relay: subprocess.Popen[str] | None = None
        self.relay_end: dict[str, Any] = {}  # the relay's counts after stop_all
        self.counts: dict[str, Any] = {}

    def via(self, link: str) -> str:
        return f"127.0.0.1:{self.relay_port[link]}"

    def args(self, role: str, first: bool) -> list[str]:
        common = ["--epoch", repr(self.epoch), "--scale", "1"]
        n, sp = str(self.trains), str(self.spacing_m)
        if role == "office":
            return ["office", "serve", "--db", str(self.dir / "office.db"), "--port", str(self.port[role])]
        if role == "zone_controller":
            return ["live", "zc", "--port", str(self.port[role]), "--trains", n, "--office",
                    self.via("office-zc"), "--state", str(self.dir / "zc.state"),
                    *(["--new"] if first else []), *common]  # fmt: skip
        if role == "plant":
            return ["live", "plant", "--port", str(self.port[role]), "--trains", n, "--spacing-m", sp,
                    "--stations", self.via("sensors"), *common]  # fmt: skip
        if role == "stations":
            return ["live", "stations", "--port", str(self.port[role]), "--office", self.via("office-st"),
                    *common]  # fmt: skip
        return ["live", "trains", "--zc", self.via("zc"), "--trains", n, "--spacing-m", sp, "--office",
                self.via("office-tr"), "--plant", self.via("plant"), "--stations", self.via("stations"),
                *common]  # fmt: skip

    def start_relay(self) -> None:
        links = [f"{n}:{self.relay_port[n]}:{self.port[LINKS[n][1]]}" for n in LINKS]
        self.relay = subprocess.Popen(
            [sys.executable, __file__, "relay", *[a for x in links for a in ("--link", x)]],
            stdout=subprocess.PIPE,
            text=True,
        )
        assert self.relay.stdout is not None
        self.relay.stdout.readline()  # {"ready": true}

    def relay_snapshot(self) -> dict[str, Any]:
        assert self.relay is not None and self.relay.stdout is not None
        self.relay.send_signal(signal.SIGUSR2)
        return dict(json.loads(self.relay.stdout.readline()))

    def replay(self) -> None:
        assert self.relay is not None
        self.relay.send_signal(signal.SIGUSR1)

    def start(self, role: str, ready: str, timeout_s: float = 120.0) -> None:
        first = self.incarnation[role] == 0
        self.incarnation[role] += 1
        tag = f"{role}.{self.incarnation[role]}"
        out = open(self.dir / f"{tag}.out", "wb")  # noqa: SIM115 (closed with the process)
        err = open(self.dir / f"{tag}.err", "wb")  # noqa: SIM115
        p = subprocess.Popen([*EXE, *self.args(role, first)], env=self.env, stdout=out, stderr=err)
        self.procs[role] = p
        end = time.time() + timeout_s
        while time.time() < end:
            if ready in (self.dir / f"{tag}.err").read_text(errors="replace"):
                return
            if p.poll() is not None:
                break
            time.sleep(0.05)
        raise RuntimeError(f"{tag} did not start: {(self.dir / f'{tag}.err').read_text(errors='replace')}")

    def check_alive(self) -> None:
        """A process that exited while nobody killed it is a crash (started again so the run goes on)."""
        for role, p in self.procs.items():
            if p.poll() is not None:
                self.crashes[role] += 1
                print(f"CRASH: {role} exited with {p.returncode}", flush=True)
                self.start(role, READY[role])

    def kill(self, role: str) -> None:
        p = self.procs[role]
        self.check_alive()
        p.kill()
        p.wait(timeout=30)
        self.killed.append(role)

    def stop_all(self) -> None:
        for role in ("trains", "zone_controller", "plant", "stations", "office"):
            p = self.procs.get(role)
            if p is not None and p.poll() is None:
                p.send_signal(signal.SIGTERM)
                if role != "trains":
                    continue
                try:
                    p.wait(timeout=30)
                except subprocess.TimeoutExpired:
                    p.kill()
        for role, p in self.procs.items():
            try:
                p.wait(timeout=60)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()
            tag = f"{role}.{self.incarnation[role]}"
            text = (self.dir / f"{tag}.out").read_text(errors="replace").strip().splitlines()
            last = text[-1] if text else ""
            self.counts[role] = json.loads(last) if last.startswith("{") else None
            if p.returncode != 0 or self.counts[role] is None:
                self.crashes[role] += 1
        for f in self.dir.glob("*.err"):
            if "Traceback" in f.read_text(errors="replace"):
                self.crashes[f.name.split(".")[0]] += 1
        if self.relay is not None:
            self.relay.send_signal(signal.SIGTERM)
            out, _ = self.relay.communicate(timeout=30)
            self.relay_end = json.loads(out.strip().splitlines()[-1])

    def abort(self) -> None:
        procs: list[subprocess.Popen[Any]] = [*self.procs.values()]
        if self.relay is not None:
            procs.append(self.relay)
        for p in procs:
            if p.poll() is None:
                p.kill()
                p.wait()


READY = {
    "office": "office listening",
    "zone_controller": "zone controller on",
    "plant": "plant on",
    "stations": "stations on",
    "trains": "trains running",
}


# ---------------------------------------------------------------------- the attacks


class Attacker:
    """Datagrams from a socket of its own, counted per target process."""

    def __init__(self, seed: int) -> None:
        self.rng = random.Random(seed)
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.setblocking(False)
        self.sent: dict[str, dict[str, int]] = {r: {"junk": 0, "forged": 0, "flood": 0} for r in ROLES}
        self.send_failed = 0  # datagrams the local socket could not send (not sent: not counted)

    def _send(self, role: str, kind: str, data: bytes, addr: tuple[str, int]) -> None:
        try:
            self.sock.sendto(data, addr)
        except (BlockingIOError, OSError):
            self.send_failed += 1
            return
        self.sent[role][kind] += 1

    def junk(self, targets: Iterable[tuple[str, tuple[str, int]]], n: int) -> None:
        """Random bytes of random lengths (0..1600: some longer than a frame may be)."""
        for role, addr in targets:
            for _ in range(n):
                size = self.rng.choice((0, 1, 4, 5, 13, 14, 21, 22, 40, 100, 255, 300, 1472, 1473, 1600))
                self._send(role, "junk", self.rng.randbytes(size), addr)

    def forged(self, targets: Iterable[tuple[str, tuple[str, int]]], trains: int) -> None:
        """Well-formed category-3 headers with a wrong MAC, for every plausible pair of ids."""
        ids = sorted({v + d for v in IDS.values() for d in (0, 1, trains - 1, trains, 63)} | {0, 0xFFFF})
        now_ms = int(time.time() * 1000) % (1 << 32)
        for role, addr in targets:
            for src in ids:
                for dst in ids:
                    if src == dst:
                        continue
                    payload = self.rng.randbytes(self.rng.choice((0, 8, 12, 40)))
                    head = HEADER.pack(
                        1 << 4 | 3, src, dst, self.rng.randrange(1, 1 << 32), now_ms, len(payload)
                    )
                    self._send(role, "forged", head + payload + self.rng.randbytes(8), addr)

    def flood(
        self, role: str, addr: tuple[str, int], rate: float, seconds: float, src: int, dst: int
    ) -> float:
        """Forged frames (a real party's ids, a wrong MAC: each costs the receiver a MAC) at
        ``rate`` per second for ``seconds``; the rate reached."""
        frame = bytearray(HEADER.pack(1 << 4 | 3, src, dst, 1, 0, 12) + bytes(20))
        start = time.perf_counter()
        sent = 0
        while (elapsed := time.perf_counter() - start) < seconds:
            due = int(elapsed * rate) + 1
            while sent < due:
                frame[5:9] = (sent + 2).to_bytes(4, "big")
                frame[9:13] = (int(time.time() * 1000) % (1 << 32)).to_bytes(4, "big")
                try:
                    self.sock.sendto(frame, addr)
                    self.sent[role]["flood"] += 1
                except (BlockingIOError, OSError):
                    self.send_failed += 1
                sent += 1
        return sent / max(time.perf_counter() - start, 1e-9)


# ---------------------------------------------------------------------- the figures


def _sum(d: object, reasons: Iterable[str] | None = None) -> int:
    if not isinstance(d, dict):
        return 0
    if reasons is None:
        return sum(int(v) for v in d.values() if isinstance(v, int | float))
    return sum(int(d.get(r, 0)) for r in reasons)


def _get(d: Any, *path: str) -> Any:
    for p in path:
        d = d.get(p) if isinstance(d, dict) else None
    return d


def process_figures(role: str, c: dict[str, Any]) -> tuple[int, list[Any], int]:
    """(frames its safety layers delivered, its refusal counts (dicts or totals), dropped below)."""
    ack = _get(c, "office_link", "acknowledged") or 0
    ack_refused = _get(c, "office_link", "ack_rejected") or 0
    if role == "zone_controller":
        delivered = _get(c, "radio", "delivered") + ack
        refused = [_get(c, "radio", "rejected"), c.get("releases_refused"), ack_refused]
    elif role == "plant":
        delivered = c.get("delivered", 0)
        refused = [c.get("refused")]
    elif role == "stations":
        delivered = c.get("delivered", 0) + ack
        refused = [c.get("refused"), _get(c, "platforms", "refused"), ack_refused]
    elif role == "trains":
        delivered = (
            c.get("radio_delivered", 0)
            + (_get(c, "tasc", "telegrams_delivered") or 0)
            + (_get(c, "dwells", "status_frames") or 0)
            + (_get(c, "plant", "frames_received") or 0)
            + ack
        )
        refused = [c.get("radio_rejected"), _get(c, "tasc", "telegrams_refused"),
                   _get(c, "dwells", "refused"), _get(c, "plant", "refused"), ack_refused]  # fmt: skip
    else:  # the office: what it stored or found stored already
        delivered = c.get("stored", 0) + c.get("duplicates", 0)
        refused = [c.get("rejected")]
    udp = c.get("udp") or {}
    dropped = sum(
        int(udp.get(k) or 0)
        for k in ("dropped_by_kernel", "dropped_queue_full", "dropped_oversize", "dropped_at_close")
    )
    return int(delivered), refused, dropped


def _refused_total(refused: list[Any], reasons: Iterable[str] | None = None) -> int:
    total = 0
    for r in refused:
        if isinstance(r, dict):
            total += _sum(r, reasons)
        elif isinstance(r, int) and reasons is None:
            total += r
        elif isinstance(r, int):
            total += r  # a total without reasons (the office link's refused acknowledgements)
    return total


def link_counts(snap_end: dict[str, Any], snap_start: dict[str, Any], role: str) -> tuple[int, int]:
    """(genuine frames the relay forwarded to ``role``, replayed frames it sent to it) between two
    snapshots of the relay."""
    genuine = replays = 0
    for name, (client, target) in LINKS.items():
        a, b = snap_start["counts"][name], snap_end["counts"][name]
        if target == role:
            genuine += b["fwd"] - a["fwd"]
            replays += b["replayed_fwd"] - a["replayed_fwd"]
        if client == role:
            genuine += b["back"] - a["back"]
            replays += b["replayed_back"] - a["replayed_back"]
    return genuine, replays


def movement_checks(db: Path, plant: dict[str, Any] | None, vehicle_length_m: float) -> dict[str, Any]:
    """Trains moving without authority, from the office's train-state reports and the plant's end."""
    from railstop.store import open_store

    with open_store(str(db)) as store:
        states = [r["data"] for r in store.office_reports(kind="train-state")]
    by_train: dict[int, list[dict[str, Any]]] = {}
    for s in states:
        by_train.setdefault(int(s["train"]), []).append(s)
    accel_under_eb = []
    for k, rows in by_train.items():
        rows.sort(key=lambda r: float(r["t_s"]))
        for a, b in zip(rows, rows[1:], strict=False):
            if (
                a["emergency_brake"]
                and b["emergency_brake"]
                and float(b["speed_mps"]) > float(a["speed_mps"]) + 0.05
            ):
                accel_under_eb.append((k, a["t_s"], b["t_s"], a["speed_mps"], b["speed_mps"]))
    too_close = []
    ordered = sorted(states, key=lambda r: float(r["t_s"]))
    for i, a in enumerate(ordered):
        for b in ordered[i + 1 :]:
            if float(b["t_s"]) - float(a["t_s"]) > 0.25:
                break
            if (
                a["train"] != b["train"]
                and abs(float(a["position_m"]) - float(b["position_m"])) < vehicle_length_m
            ):
                too_close.append((a["train"], b["train"], a["t_s"], a["position_m"], b["position_m"]))
    end = sorted(float(t["x_m"]) for t in (plant or {}).get("trains", []))
    overlap_end = sum(1 for x, y in zip(end, end[1:], strict=False) if y - x < vehicle_length_m)
    return {
        "states": len(states),
        "accelerating_under_emergency_brake": accel_under_eb,
        "closer_than_a_train": too_close,
        "plant_end_overlaps": overlap_end,
        "violations": len(accel_under_eb) + len(too_close) + overlap_end,
    }


# ---------------------------------------------------------------------- the run


def run(
    *,
    seconds: float,
    trains: int,
    spacing_m: float,
    flood_rate: float,
    flood_s: float,
    junk_per_target: int,
    restarts: tuple[str, ...] = ("zone_controller", "plant", "stations", "trains", "office"),
    workdir: Path | None = None,
    settle_s: float = 8.0,
    say: Any = print,
) -> dict[str, Any]:
    """The whole attack; returns the figures (also printed by :func:`report`)."""
    from railstop.config import default_vehicle

    tmp = tempfile.TemporaryDirectory(prefix="railstop-attack-") if workdir is None else None
    wd = Path(tmp.name) if tmp is not None else workdir
    assert wd is not None
    line = Line(wd, trains=trains, spacing_m=spacing_m)
    attacker = Attacker(seed=17)
    t0 = time.time()
    try:
        line.start_relay()
        line.start("office", READY["office"])
        line.start("zone_controller", READY["zone_controller"])
        line.start("plant", READY["plant"])
        line.start("stations", READY["stations"])
        snap_start: dict[str, dict[str, Any]] = {r: line.relay_snapshot() for r in ("trains",)}
        line.start("trains", READY["trains"])
        for role in ("office", "zone_controller", "plant", "stations"):
            snap_start[role] = snap_start["trains"]
        say(f"line up in {time.time() - t0:.1f} s (epoch {line.epoch:.3f}); running {settle_s:g} s")
        time.sleep(settle_s)
        budget = max(seconds - (time.time() - t0), 0.0)
        # Phase 1: each process killed (SIGKILL) and started again, then the frames captured
        # before its restart replayed (to it and to everyone).
        per = max(settle_s, (budget * 0.6) / max(len(restarts), 1))
        for role in restarts:
            line.kill(role)
            time.sleep(0.5)
            snap_start[role] = line.relay_snapshot()
            line.start(role, READY[role])
            time.sleep(0.3)
            line.replay()
            say(f"  {role}: killed (SIGKILL), started again, captured frames replayed")
            time.sleep(per)
            line.check_alive()
        # Phase 2: counted attacks on the last incarnations.
        clients = line.relay_snapshot()["clients"]
        trains_socks = [tuple(clients[n]) for n in ("zc", "plant", "office-tr") if clients.get(n)]
        zc_socks = [tuple(clients["office-zc"])] if clients.get("office-zc") else []
        st_socks = [tuple(clients["office-st"])] if clients.get("office-st") else []
        targets: list[tuple[str, tuple[str, int]]] = [
            (r, ("127.0.0.1", line.port[r])) for r in ("office", "zone_controller", "plant", "stations")
        ]
        targets += [("trains", a) for a in trains_socks]
        targets += [("zone_controller", a) for a in zc_socks] + [("stations", a) for a in st_socks]
        attacker.junk(targets, junk_per_target)
        say(f"  junk: {sum(v['junk'] for v in attacker.sent.values())} datagrams")
        time.sleep(1.0)
        attacker.forged(targets, trains)
        say(f"  forged: {sum(v['forged'] for v in attacker.sent.values())} frames with wrong MACs")
        time.sleep(2.0)
        if flood_s > 0.0:
            rate = attacker.flood(
                "zone_controller", ("127.0.0.1", line.port["zone_controller"]), flood_rate, flood_s,
                src=IDS["train"], dst=IDS["zc"],
            )  # fmt: skip
            say(f"  flood: {attacker.sent['zone_controller']['flood']} frames at the zone controller "
                f"({rate:,.0f}/s for {flood_s:g} s)")  # fmt: skip
            time.sleep(1.0)
        line.replay()
        say("  replay of the captured frames")
        rest = max(seconds - (time.time() - t0), 3.0)
        time.sleep(rest)
        line.check_alive()
        line.stop_all()
        # The relay's counts once every process has stopped: the frames a process sends while it
        # stops (its last office reports) are genuine too, and are delivered.
        snap_end = line.relay_end
    except BaseException:
        line.abort()
        raise
    finally:
        attacker.sock.close()
    figures: dict[str, Any] = {"seconds": round(time.time() - t0, 1), "processes": {}}
    totals = {"crashes": 0, "bad_deliveries": 0, "attack_sent": 0, "accounted": 0, "unaccounted": 0}
    for role in ROLES:
        c = line.counts.get(role)
        genuine, replays = link_counts(snap_end, snap_start[role], role)
        row: dict[str, Any] = {"crashes": line.crashes[role], "restarts": line.incarnation[role] - 1}
        if isinstance(c, dict):
            delivered, refused, dropped = process_figures(role, c)
            replay_refused = _refused_total(refused, REPLAY_REASONS)
            bad = max(0, delivered - genuine) + max(0, replays - replay_refused)
            sent = sum(attacker.sent[role].values()) + replays
            accounted = _refused_total(refused) + dropped
            row.update(
                delivered=delivered, genuine_sent=genuine, replays_sent=replays,
                replays_refused=replay_refused,
                bad_deliveries=bad, attack_sent=sent, refused=_refused_total(refused), dropped=dropped,
                unaccounted=max(0, sent - accounted), udp=c.get("udp"),
            )  # fmt: skip
            totals["bad_deliveries"] += bad
            totals["attack_sent"] += sent
            totals["accounted"] += accounted
            totals["unaccounted"] += max(0, sent - accounted)
        totals["crashes"] += line.crashes[role]
        figures["processes"][role] = row
    moves = movement_checks(wd / "office.db", line.counts.get("plant"), default_vehicle().length_m)
    figures["movement"] = moves
    totals["trains_moving_without_authority"] = moves["violations"]
    figures["totals"] = totals
    figures["attack"] = {"sent": attacker.sent, "send_failed": attacker.send_failed}
    figures["raw"] = line.counts
    figures["workdir"] = str(wd)
    if tmp is not None:
        tmp.cleanup()
    return figures


def report(f: dict[str, Any]) -> None:
    print(f"live line under attack, {f['seconds']} s")
    print(f"{'process':16} {'crash':>5} {'rst':>3} {'deliv':>7} {'genuine':>7} {'replays':>7} "
          f"{'rp-ref':>6} {'bad':>3} {'attack':>7} {'refused':>7} {'dropped':>7} {'unacc':>5}")  # fmt: skip
    for role, r in f["processes"].items():
        print(
            f"{role:16} {r['crashes']:>5} {r['restarts']:>3} {r.get('delivered', '-'):>7} "
            f"{r.get('genuine_sent', '-'):>7} {r.get('replays_sent', '-'):>7} "
            f"{r.get('replays_refused', '-'):>6} "
            f"{r.get('bad_deliveries', '-'):>3} {r.get('attack_sent', '-'):>7} {r.get('refused', '-'):>7} "
            f"{r.get('dropped', '-'):>7} {r.get('unaccounted', '-'):>5}"
        )
    t = f["totals"]
    m = f["movement"]
    print(
        f"total: crashes {t['crashes']}, bad deliveries {t['bad_deliveries']}, trains moving without "
        f"authority {t['trains_moving_without_authority']} ({m['states']} train states checked: "
        f"{len(m['accelerating_under_emergency_brake'])} accelerating under emergency brake, "
        f"{len(m['closer_than_a_train'])} closer than a train, "
        f"{m['plant_end_overlaps']} overlapping at the end), attack datagrams {t['attack_sent']}, "
        f"refused or dropped {t['accounted']}, unaccounted {t['unaccounted']}"
    )


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["relay"]:
        return relay_main(argv[1:])
    ap = argparse.ArgumentParser(description="Attack the live line and count what it refuses.")
    ap.add_argument("--minutes", type=float, default=2.0, help="how long the attacked run lasts")
    ap.add_argument("--trains", type=int, default=3)
    ap.add_argument("--spacing-m", type=float, default=800.0)
    ap.add_argument("--flood-rate", type=float, default=50000.0, help="datagrams per second in the flood")
    ap.add_argument("--flood-s", type=float, default=3.0)
    ap.add_argument("--junk", type=int, default=300, help="junk datagrams per target socket")
    ap.add_argument("--json", action="store_true", help="print the figures as JSON too")
    ap.add_argument("--raw", type=Path, default=None, help="write every process's printed counts here")
    args = ap.parse_args(argv)
    figures = run(
        seconds=args.minutes * 60.0, trains=args.trains, spacing_m=args.spacing_m, flood_rate=args.flood_rate,
        flood_s=args.flood_s, junk_per_target=args.junk,
    )  # fmt: skip
    report(figures)
    if args.raw is not None:
        args.raw.write_text(json.dumps(figures["raw"], indent=1))
    if args.json:
        print(json.dumps({k: v for k, v in figures.items() if k != "raw"}))
    t = figures["totals"]
    ok = t["crashes"] == 0 and t["bad_deliveries"] == 0 and t["trains_moving_without_authority"] == 0
    return 0 if ok and t["unaccounted"] == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
