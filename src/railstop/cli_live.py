"""``railstop live run|zc|trains``: the CBTC line on the wall clock, each part a process (issue 17).

``live run`` starts the management office (with its control-room page), the
zone controller and the trains as three processes talking over UDP on
loopback, waits ``--duration-s`` (wall seconds) and stops them; each prints
its counts as one JSON line. ``live zc`` and ``live trains`` are those
processes, startable by hand (a killed one can be started again with the same
options: the run's ``--epoch``, ``--scale`` and key).
"""

from __future__ import annotations

import asyncio
import json
import os
import signal
import subprocess
import sys
import time
from typing import Annotated

import typer

from railstop.cli_common import LineOpt, VehicleOpt, fail
from railstop.cli_office import KEY_ENV, master_key
from railstop.errors import RailstopError

live_app = typer.Typer(
    add_completion=False,
    no_args_is_help=True,
    help="The CBTC line live: office, zone controller and trains as processes over UDP on loopback.",
)

EpochOpt = Annotated[
    float | None, typer.Option(help="The run's time base: seconds since 1970 at its start (default: now).")
]
ScaleOpt = Annotated[float, typer.Option(min=0.1, max=100.0, help="Simulated seconds per wall second.")]
KeyOpt = Annotated[
    str | None, typer.Option("--key-hex", help=f"The links' master key in hex (or {KEY_ENV}).")
]
OfficeOpt = Annotated[str | None, typer.Option(help="The office's UDP address HOST:PORT (none: no reports).")]
TrainsOpt = Annotated[int, typer.Option(min=1, max=60, help="Trains on the line.")]


def _address(text: str, option: str) -> tuple[str, int]:
    host, _, port = text.rpartition(":")
    if not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise RailstopError(f"{option}: HOST:PORT expected (got {text!r})")
    return host, int(port)


def _serve(coro_factory: object) -> None:
    """Run a live process until SIGTERM / SIGINT; print its counts as one JSON line."""

    async def main() -> dict[str, object]:
        stop = asyncio.Event()
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(sig, stop.set)
        return await coro_factory(stop)  # type: ignore[operator]

    try:
        result = asyncio.run(main())
    except (RailstopError, ValueError) as exc:
        fail(str(exc))
    print(json.dumps(result), flush=True)


async def _with_office(office: str | None, own_id: int, key: bytes, run: object) -> object:
    """Run ``run(client)`` with a client of the office (None without --office). The office link
    keeps Unix time (its peers' clocks, whatever the run's time scale)."""
    from railstop.link.udp import EpochClock
    from railstop.live.office import OfficeClient

    if office is None:
        return await run(None)  # type: ignore[operator]
    address = _address(office, "--office")
    async with OfficeClient(own_id=own_id, office=address, master_key=key, clock=EpochClock(0.0)) as client:
        result = await run(client)  # type: ignore[operator]
        drained = await client.drain(timeout_s=5.0)
        if isinstance(result, dict):
            result["office_link"] = {**client.outbox.counts, "pending": client.pending, "drained": drained}
        return result


@live_app.command("zc")
def zc_cmd(
    port: Annotated[int, typer.Option(min=0, max=65535, help="UDP port of the zone controller.")] = 7710,
    trains: TrainsOpt = 4,
    epoch: EpochOpt = None,
    scale: ScaleOpt = 1.0,
    key_hex: KeyOpt = None,
    office: OfficeOpt = None,
    line: LineOpt = None,
    vehicle: VehicleOpt = None,
) -> None:
    """The SPEC §4 zone controller as a live process."""
    from railstop.config import load_line, load_vehicle
    from railstop.live.cbtc import run_zone_controller
    from railstop.live.clock import TimeBase

    try:
        key = master_key(key_hex)
        ln, veh = load_line(line), load_vehicle(vehicle)
    except RailstopError as exc:
        fail(str(exc))
    base = TimeBase(time.time() if epoch is None else epoch, scale)

    def ready(addr: tuple[str, int]) -> None:
        print(f"zone controller on {addr[0]}:{addr[1]} (pid {os.getpid()})", file=sys.stderr, flush=True)

    async def run(stop: asyncio.Event) -> object:
        async def zone_controller(client: object) -> object:
            return await run_zone_controller(
                line=ln,
                vehicle=veh,
                trains=trains,
                local=("127.0.0.1", port),
                base=base,
                master_key=key,
                stop=stop,
                office=client,  # type: ignore[arg-type]
                on_ready=ready,
            )

        return await _with_office(office, 800, key, zone_controller)

    _serve(run)


@live_app.command("trains")
def trains_cmd(
    zc: Annotated[str, typer.Option(help="The zone controller's UDP address HOST:PORT.")] = "127.0.0.1:7710",
    trains: TrainsOpt = 4,
    spacing_m: Annotated[
        float, typer.Option(min=150.0, max=5000.0, help="Between trains at the start.")
    ] = 600.0,
    epoch: EpochOpt = None,
    scale: ScaleOpt = 1.0,
    key_hex: KeyOpt = None,
    office: OfficeOpt = None,
    outage_train: Annotated[
        int | None,
        typer.Option(help="SIGUSR1 kills this train's radio, the next one restores it (fault injection)."),
    ] = None,
    line: LineOpt = None,
    vehicle: VehicleOpt = None,
) -> None:
    """Every train's onboard CBTC unit and the plant that moves the trains, as one live process."""
    from railstop.config import load_line, load_vehicle
    from railstop.live.cbtc import run_trains
    from railstop.live.clock import TimeBase

    try:
        key = master_key(key_hex)
        ln, veh = load_line(line), load_vehicle(vehicle)
        zc_addr = _address(zc, "--zc")
    except RailstopError as exc:
        fail(str(exc))
    base = TimeBase(time.time() if epoch is None else epoch, scale)
    print(f"trains running (pid {os.getpid()})", file=sys.stderr, flush=True)

    dead: set[int] = set()

    def toggle() -> None:
        assert outage_train is not None
        dead.symmetric_difference_update({outage_train})
        state = "dead" if outage_train in dead else "restored"
        print(f"radio of train {outage_train} {state}", file=sys.stderr, flush=True)

    async def run(stop: asyncio.Event) -> object:
        if outage_train is not None:
            asyncio.get_running_loop().add_signal_handler(signal.SIGUSR1, toggle)

        async def fleet(client: object) -> object:
            return await run_trains(
                line=ln,
                vehicle=veh,
                trains=trains,
                spacing_m=spacing_m,
                zc=zc_addr,
                base=base,
                master_key=key,
                stop=stop,
                office=client,  # type: ignore[arg-type]
                outage=dead,
            )

        return await _with_office(office, 801, key, fleet)

    _serve(run)


@live_app.command("run")
def run_cmd(
    trains: TrainsOpt = 4,
    duration_s: Annotated[float, typer.Option(min=1.0, max=86400.0, help="Wall seconds to run.")] = 120.0,
    scale: ScaleOpt = 1.0,
    db: Annotated[
        str, typer.Option(help="The office's database (SQLite file or PostgreSQL URL).")
    ] = "railstop.db",
    http_port: Annotated[int, typer.Option(min=0, max=65535, help="The control-room page's port.")] = 8080,
    spacing_m: Annotated[
        float, typer.Option(min=150.0, max=5000.0, help="Between trains at the start.")
    ] = 600.0,
) -> None:
    """Office (with its page), zone controller and trains as three processes for --duration-s."""
    key = os.urandom(32).hex()
    epoch = time.time()
    env = {**os.environ, KEY_ENV: key}
    exe = [sys.executable, "-m", "railstop.cli"]
    common = ["--epoch", repr(epoch), "--scale", repr(scale)]
    procs: list[subprocess.Popen[str]] = []

    def start(args: list[str]) -> tuple[subprocess.Popen[str], str]:
        proc = subprocess.Popen(
            [*exe, *args], env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
        )
        procs.append(proc)
        assert proc.stderr is not None
        return proc, proc.stderr.readline().strip()

    try:
        office, line1 = start(["office", "serve", "--db", db, "--port", "0", "--http-port", str(http_port)])
        assert office.stderr is not None
        line2 = office.stderr.readline().strip()
        page = next((x for x in (line1, line2) if x.startswith("control-room page")), "")
        listening = next((x for x in (line1, line2) if x.startswith("office listening")), "")
        if not page or not listening:
            raise RailstopError(f"the office did not start: {line1} {line2} {office.stderr.read()}")
        office_addr = listening.split(" on ")[1].split()[0]
        zc, zc_line = start(
            ["live", "zc", "--port", "0", "--trains", str(trains), "--office", office_addr, *common]
        )
        if not zc_line.startswith("zone controller on"):
            raise RailstopError(f"the zone controller did not start: {zc_line}")
        zc_addr = zc_line.split(" on ")[1].split()[0]
        tr, _ = start(["live", "trains", "--zc", zc_addr, "--trains", str(trains), "--spacing-m",
                             str(spacing_m), "--office", office_addr, *common])  # fmt: skip
        print(f"{page}; office {office_addr}, zone controller {zc_addr} (pid {zc.pid}), trains pid {tr.pid}",
              flush=True)  # fmt: skip
        time.sleep(duration_s)
    except RailstopError as exc:
        for p in procs:
            p.kill()
        fail(str(exc))
    finally:
        results: dict[str, object] = {}
        # The trains first, the office last: it stores what the others report as they stop.
        for role, p in reversed(list(zip(("office", "zone_controller", "trains"), procs, strict=False))):
            p.send_signal(signal.SIGTERM)
            out, _ = p.communicate(timeout=30)
            text = out.strip().splitlines()[-1] if out.strip() else ""
            results[role] = json.loads(text) if text.startswith("{") else text
    print(json.dumps(results))
