"""``railstop live run|zc|trains``: the CBTC line on the wall clock, each part a process (issue 17).

``live run`` starts the management office (with its control-room page), the
zone controller and the trains as three processes talking over UDP on
loopback, waits ``--duration-s`` (wall seconds) and stops them; each prints
its counts as one JSON line. ``live zc`` and ``live trains`` are those
processes, startable by hand (a killed one can be started again with the same
options: the run's ``--epoch``, ``--scale`` and key; a zone controller with its
``--state`` file and without ``--new``).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Annotated, Any

import typer

from railstop.cli.common import LineOpt, VehicleOpt, address_option, command_group, fail, with_option_groups
from railstop.cli.doors import DoorsOpt
from railstop.cli.office import KEY_ENV, KeyFileOpt, KeyHexOpt, master_key
from railstop.errors import RailstopError

if TYPE_CHECKING:
    import asyncio

    from railstop.config.schema import Line, Vehicle
    from railstop.live.clock import TimeBase

live_app = command_group(
    "The CBTC line live: office, zone controller and trains as processes over UDP on loopback."
)

EpochOpt = Annotated[
    float | None, typer.Option(help="The run's time base: seconds since 1970 at its start (default: now).")
]
ScaleOpt = Annotated[float, typer.Option(min=0.1, max=100.0, help="Simulated seconds per wall second.")]
OfficeOpt = Annotated[str | None, typer.Option(help="The office's UDP address HOST:PORT (none: no reports).")]
TrainsOpt = Annotated[int, typer.Option(min=1, max=60, help="Trains on the line.")]
SpacingOpt = Annotated[float, typer.Option(min=150.0, max=5000.0, help="Between trains at the start.")]
SeedOpt = Annotated[int, typer.Option(help="Seed of the trains' disturbance draws (one per stop).")]
OutageOpt = Annotated[
    list[str] | None,
    typer.Option(
        "--outage",
        help="TRAIN:START_S:DURATION_S: that train's radio dead from START_S simulated seconds after the "
        "trains' process starts, for DURATION_S (repeatable).",
    ),
]
DisturbancesOpt = Annotated[
    str, typer.Option(help="Disturbance set of the trains' draws (a name or a TOML file).")
]


@dataclass(frozen=True)
class ProcessOptions:
    """The options every live process of a run shares (an option group): the run's time base, the
    links' key and the line's data."""

    epoch: EpochOpt = None
    scale: ScaleOpt = 1.0
    key_file: KeyFileOpt = None
    key_hex: KeyHexOpt = None
    line: LineOpt = None
    vehicle: VehicleOpt = None

    def setup(self) -> tuple[bytes, Line, Vehicle, TimeBase]:
        """What every live process loads first: the key (--key-file or RAILSTOP_OFFICE_KEY;
        --key-hex is refused), the line and vehicle data, the time base (the run's epoch, or
        now). Raises RailstopError with the one-line message."""
        from railstop.config import load_line, load_vehicle
        from railstop.live.clock import TimeBase

        key = master_key(self.key_file, self.key_hex)
        ln, veh = load_line(self.line), load_vehicle(self.vehicle)
        return key, ln, veh, TimeBase(time.time() if self.epoch is None else self.epoch, self.scale)


def _outage(text: str, trains: int) -> tuple[int, float, float]:
    try:
        train_s, start_s, duration_s = text.split(":")
        train, start, duration = int(train_s), float(start_s), float(duration_s)
    except ValueError:
        raise RailstopError(f"--outage: TRAIN:START_S:DURATION_S expected (got {text!r})") from None
    if not 0 <= train < trains or start < 0.0 or duration <= 0.0:
        raise RailstopError(f"--outage: a train 0..{trains - 1}, a start >= 0, a duration > 0 (got {text!r})")
    return train, start, duration


def _serve(coro_factory: object) -> None:
    """Run a live process until SIGTERM / SIGINT; print its counts as one JSON line."""
    import asyncio  # lazy: CLI start-up (the event loop only for the live processes)

    from railstop.live.clock import GcWatch

    async def main() -> dict[str, object]:
        stop = asyncio.Event()
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(sig, stop.set)
        return await coro_factory(stop)  # type: ignore[operator]

    started = time.monotonic()
    try:
        with GcWatch() as watch:
            result = asyncio.run(main())
    except (RailstopError, ValueError) as exc:
        fail(str(exc))
    if isinstance(result, dict):
        result["gc"] = watch.counts()  # its pauses, beside its clock's late steps
        from railstop.link.udp import process_udp_stats  # lazy: CLI start-up

        result["udp"] = process_udp_stats()  # every datagram dropped (kernel, queue, too long), counted
        # What the process cost: its CPU seconds (user + system) over its wall seconds.
        result["cpu_s"] = round(time.process_time(), 2)
        result["wall_s"] = round(time.monotonic() - started, 2)
    print(json.dumps(result), flush=True)


async def _with_office(office: str | None, own_id: int, key: bytes, run: object) -> object:
    """Run ``run(client)`` with a client of the office (None without --office). The office link
    keeps Unix time (its peers' clocks, whatever the run's time scale)."""
    from railstop.link.udp import EpochClock
    from railstop.live.office import OfficeClient

    if office is None:
        return await run(None)  # type: ignore[operator]
    address = address_option(office, "--office")
    async with OfficeClient(own_id=own_id, office=address, master_key=key, clock=EpochClock(0.0)) as client:
        result = await run(client)  # type: ignore[operator]
        drained = await client.drain(timeout_s=5.0)
        if isinstance(result, dict):
            result["office_link"] = {**client.outbox.counts, "pending": client.pending, "drained": drained}
        return result


def _serve_listener(label: str, office: str | None, own_id: int, key: bytes, start: Any) -> None:
    """Serve a live process that listens on a UDP port (zone controller, stations): it says where
    on stderr once bound (``<label> on HOST:PORT``), reports to the office as ``own_id``, and prints
    its counts when stopped. ``start(stop, office_client, on_ready)`` is its coroutine."""

    def ready(addr: tuple[str, int]) -> None:
        print(f"{label} on {addr[0]}:{addr[1]} (pid {os.getpid()})", file=sys.stderr, flush=True)

    async def run(stop: asyncio.Event) -> object:
        return await _with_office(office, own_id, key, lambda client: start(stop, client, ready))

    _serve(run)


ZcStateOpt = Annotated[
    str | None,
    typer.Option(
        "--state",
        help="The zone controller's durable state file: written on every change of a train's status, "
        "zone or authority, read when it starts again.",
    ),
]


@live_app.command("zc")
@with_option_groups
def zc_cmd(
    *,
    port: Annotated[int, typer.Option(min=0, max=65535, help="UDP port of the zone controller.")] = 7710,
    trains: TrainsOpt = 4,
    process: ProcessOptions,
    office: OfficeOpt = None,
    state: ZcStateOpt = None,
    new: Annotated[
        bool,
        typer.Option(
            "--new",
            help="The operation's start: no train known yet (without it, a restart: the state is read "
            "from --state, and without a usable one every train is held until an operator releases it).",
        ),
    ] = False,
) -> None:
    """The SPEC §4 zone controller as a live process."""
    from pathlib import Path

    from railstop.live.cbtc import run_zone_controller

    try:
        key, ln, veh, base = process.setup()
    except RailstopError as exc:
        fail(str(exc))

    _serve_listener(
        "zone controller", office, 800, key,
        lambda stop, client, ready: run_zone_controller(
            line=ln, vehicle=veh, trains=trains, local=("127.0.0.1", port), base=base, master_key=key,
            stop=stop, office=client, on_ready=ready, state=None if state is None else Path(state), new=new,
            note=lambda text: print(text, file=sys.stderr, flush=True),
        ),
    )  # fmt: skip


TascControllerOpt = Annotated[
    str, typer.Option("--controller", help="The trains' onboard TASC configuration (SPEC §1).")
]


DoorModeOpt = Annotated[
    str,
    typer.Option(
        "--door-mode",
        help="Who works the train doors at the platforms: auto (the ATC) or manual (the driver).",
    ),
]


def _check_door_mode(door_mode: str) -> None:
    if door_mode not in ("auto", "manual"):
        raise RailstopError(f"--door-mode: auto or manual (got {door_mode!r})")


PsdJamOpt = Annotated[
    list[str] | None,
    typer.Option(
        "--psd-jam",
        help="Fault injection: STATION:UNIT, that PSD unit (1 = front) fails to close on its next closing.",
    ),
]


def _psd_jams(texts: list[str], line: Line, doors_per_side: int) -> tuple[tuple[int, int], ...]:
    """--psd-jam STATION:UNIT (a station's name or number from 0, a unit from 1) as (station, unit
    from 0); RailstopError naming the bad value."""
    names = {st.name: i for i, st in enumerate(line.stations)}
    out = []
    for text in texts:
        station, _, unit = text.rpartition(":")
        i = names.get(station, int(station) if station.isdigit() else -1)
        if not 0 <= i < len(line.stations) or not unit.isdigit() or not 1 <= int(unit) <= doors_per_side:
            raise RailstopError(
                f"--psd-jam: STATION:UNIT with a station of the line ({', '.join(names)}) and a unit "
                f"1..{doors_per_side} (got {text!r})"
            )
        out.append((i, int(unit) - 1))
    return tuple(out)


def _tasc_controller(controller: str) -> str:
    from railstop.onboard.tasc_receiver import CONFIG_CODES

    if controller not in CONFIG_CODES:
        raise RailstopError(f"--controller: one of {', '.join(CONFIG_CODES)} (got {controller!r})")
    return controller


@live_app.command("stations")
@with_option_groups
def stations_cmd(
    *,
    port: Annotated[int, typer.Option(min=0, max=65535, help="UDP port of the stations.")] = 7720,
    controller: TascControllerOpt = "tasc-pwm",
    process: ProcessOptions,
    office: OfficeOpt = None,
    doors: DoorsOpt = None,
    psd_jam: PsdJamOpt = None,
) -> None:
    """Every station's wayside units as a live process: the TASC unit (SPEC §1: sensor readings in,
    braking telegrams out, every command to the office) and the platform's WPCS (SPEC §5: the door
    link with the train standing there, the WCC's commands)."""
    from railstop.config.doors import load_doors
    from railstop.live.tasc import run_stations

    try:
        key, ln, veh, base = process.setup()
        ctrl = _tasc_controller(controller)
        door_data = load_doors(doors)
        for st in ln.stations:  # one PSD tolerance per station: a doors file that differs is refused
            door_data.at_station(st, "the line file")
        jams = _psd_jams(psd_jam or [], ln, door_data.doors_per_side)
    except RailstopError as exc:
        fail(str(exc))

    _serve_listener(
        "stations", office, 802, key,
        lambda stop, client, ready: run_stations(
            line=ln, vehicle=veh, controller=ctrl, local=("127.0.0.1", port), base=base, master_key=key,
            stop=stop, office=client, on_ready=ready, doors=door_data, jams=jams,
        ),
    )  # fmt: skip


@live_app.command("plant")
@with_option_groups
def plant_cmd(
    *,
    port: Annotated[int, typer.Option(min=0, max=65535, help="UDP port of the plant.")] = 7730,
    trains: TrainsOpt = 4,
    spacing_m: SpacingOpt = 600.0,
    process: ProcessOptions,
    stations: Annotated[
        str | None,
        typer.Option(
            help="The stations' UDP address HOST:PORT: the trackside readings go there and the trains "
            "stop by ground TASC (none: point-mass stops)."
        ),
    ] = None,
    controller: TascControllerOpt = "tasc-pwm",
    seed: SeedOpt = 1,
    disturbances: DisturbancesOpt = "standard",
) -> None:
    """The plant as a live process: every train's motion (under its drives from the trains
    process; under ground TASC the stop model's brakes and motion, in lock step with the onboard
    unit), the trains' own sensors and the trackside sensors (the stations' detectors and radar,
    the platforms' stop sensors)."""
    from railstop.config.disturbances import load_disturbances
    from railstop.live.plant import Plant, TascPlantData, run_plant

    try:
        key, ln, veh, base = process.setup()
        stations_at = None if stations is None else address_option(stations, "--stations")
        data = None
        if stations_at is not None:
            data = TascPlantData(_tasc_controller(controller), load_disturbances(disturbances), seed)
        plant = Plant(line=ln, vehicle=veh, trains=trains, spacing_m=spacing_m, master_key=key, tasc=data)
    except (RailstopError, ValueError) as exc:
        fail(str(exc))
    if data is not None:
        from railstop.live.tasc import warm_up

        warm_up()  # the compiled steps loaded before the clock starts

    _serve_listener(
        "plant", None, 802, key,
        lambda stop, _client, ready: run_plant(
            plant=plant, local=("127.0.0.1", port), stations=stations_at, base=base, master_key=key,
            stop=stop, on_ready=ready,
        ),
    )  # fmt: skip


@live_app.command("trains")
@with_option_groups
def trains_cmd(
    *,
    zc: Annotated[str, typer.Option(help="The zone controller's UDP address HOST:PORT.")] = "127.0.0.1:7710",
    trains: TrainsOpt = 4,
    spacing_m: SpacingOpt = 600.0,
    process: ProcessOptions,
    office: OfficeOpt = None,
    outage_train: Annotated[
        int | None,
        typer.Option(help="SIGUSR1 kills this train's radio, the next one restores it (fault injection)."),
    ] = None,
    outage: OutageOpt = None,
    stations: Annotated[
        str | None,
        typer.Option(
            help="The stations' UDP address HOST:PORT: stop by ground TASC (none: point-mass stops)."
        ),
    ] = None,
    controller: TascControllerOpt = "tasc-pwm",
    seed: SeedOpt = 1,
    disturbances: DisturbancesOpt = "standard",
    tasc_loss: Annotated[
        float,
        typer.Option(min=0.0, max=1.0, help="Fault injection: the share of braking telegram frames lost."),
    ] = 0.0,
    plant: Annotated[
        str | None,
        typer.Option(help="The plant process's UDP address HOST:PORT (none: the plant runs in this one)."),
    ] = None,
    doors: DoorsOpt = None,
    door_mode: DoorModeOpt = "auto",
    obstruct: Annotated[
        list[str] | None,
        typer.Option(
            help="Fault injection: TRAIN:DOOR, that train's door (1 = front) on the platform side meets "
            "an obstacle at its next dwell's closing."
        ),
    ] = None,
) -> None:
    """Every train's onboard units (CBTC; with --stations ground TASC and the dwell over the door
    link with the platforms' WPCS) as one live process; the plant that moves the trains is the
    process at --plant, or runs in this one."""
    from railstop.config.disturbances import load_disturbances
    from railstop.config.doors import load_doors
    from railstop.live.cbtc import run_trains
    from railstop.live.doors import LiveDoors
    from railstop.live.tasc import LiveTasc

    try:
        key, ln, veh, base = process.setup()
        zc_addr = address_option(zc, "--zc")
        plant_addr = None if plant is None else address_option(plant, "--plant")
        windows = [_outage(o, trains) for o in outage or []]
        _check_door_mode(door_mode)
        tasc = door_link = None
        if stations is not None:
            door_link = LiveDoors(
                line=ln,
                doors=load_doors(doors),
                stations=address_option(stations, "--stations"),
                master_key=key,
                manual=door_mode == "manual",
                trains=trains,
                started_s=base.now_s(),  # statuses sent before this process started are refused
                seed=seed,
            )
            for text in obstruct or []:
                train_s, _, door_s = text.partition(":")
                n = door_link.doors.doors_per_side
                if not (
                    train_s.isdigit() and door_s.isdigit() and int(train_s) < trains and 1 <= int(door_s) <= n
                ):
                    why = f"TRAIN:DOOR with a train 0..{trains - 1} and a door 1..{n}"
                    raise RailstopError(f"--obstruct: {why} (got {text!r})")
                door_link.obstructions[int(train_s)] = int(door_s) - 1
            tasc = LiveTasc(
                line=ln,
                vehicle=veh,
                controller=_tasc_controller(controller),
                stations=address_option(stations, "--stations"),
                master_key=key,
                dist=load_disturbances(disturbances),
                seed=seed,
                loss=tasc_loss,
                trains=trains,
                started_s=base.now_s(),  # telegrams sent before this process started are refused
            )
    except RailstopError as exc:
        fail(str(exc))
    print(f"trains running (pid {os.getpid()})", file=sys.stderr, flush=True)

    dead: set[int] = set()

    def set_radio(train: int, dead_now: bool) -> None:
        (dead.add if dead_now else dead.discard)(train)
        print(f"radio of train {train} {'dead' if dead_now else 'restored'}", file=sys.stderr, flush=True)

    def toggle() -> None:
        assert outage_train is not None  # the handler is set only with --outage-train
        set_radio(outage_train, outage_train not in dead)

    async def run(stop: asyncio.Event) -> object:
        import asyncio

        loop = asyncio.get_running_loop()
        if outage_train is not None:
            loop.add_signal_handler(signal.SIGUSR1, toggle)
        # The windows count from this process's start (simulated seconds), not from the run's epoch:
        # on a loaded machine the processes take seconds to start, and a window timed from the
        # epoch could be over before the trains report at all (then no train is lost).
        t0 = base.now_s()
        for train, start_s, duration_s in windows:
            loop.call_later(max(base.wall_until(t0 + start_s), 0.0), set_radio, train, True)
            loop.call_later(max(base.wall_until(t0 + start_s + duration_s), 0.0), set_radio, train, False)

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
                tasc=tasc,
                doors=door_link,
                plant=plant_addr,
            )

        return await _with_office(office, 801, key, fleet)

    _serve(run)


def _free_udp_port() -> int:
    import socket

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def _run_line(
    *,
    trains: int,
    duration_s: float,
    scale: float,
    db: str,
    http_port: int,
    spacing_m: float,
    operators: str | None,
    outages: list[str],
    controller: str | None = "tasc-pwm",
    tasc_loss: float = 0.0,
    psd_jams: list[str] | None = None,
    door_mode: str = "auto",
    zc_state: str | None = None,
    failed: dict[str, int | None] | None = None,
) -> dict[str, object]:
    """``failed`` gets the processes that ended before the stop or with a non-zero exit code (their
    exit codes). Office (with its page), zone controller, stations (with ``controller``; None: no ground
    TASC, point-mass stops) and trains as processes for ``duration_s`` wall seconds; their counts,
    one object per process. ``tasc_loss``: the braking telegrams' injected loss. ``zc_state``: the
    zone controller's durable state file (the run is a new operation; a zone controller started
    again by hand with ``--state`` reads it); default: beside the database, or in the temporary
    folder for a database URL."""
    import threading

    key = os.urandom(32).hex()
    env = {**os.environ, KEY_ENV: key}
    exe = [sys.executable, "-m", "railstop.cli"]
    procs: list[subprocess.Popen[str]] = []
    zc_port = _free_udp_port()

    def launch(args: list[str]) -> subprocess.Popen[str]:
        # The run's key reaches its processes through the environment only (readable by this user
        # alone), never on a command line (readable by every user, ps / /proc/PID/cmdline).
        if any(key in a for a in args) or any(a.startswith("--key") for a in args):
            raise RailstopError("a live process would get the links' key on its command line: not started")
        proc = subprocess.Popen(
            [*exe, *args], env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
        )
        procs.append(proc)
        return proc

    def start(
        args: list[str], lines: int = 1, proc: subprocess.Popen[str] | None = None
    ) -> tuple[subprocess.Popen[str], list[str]]:
        """Start a process (or take one launched already) and read its first stderr lines."""
        proc = launch(args) if proc is None else proc
        assert proc.stderr is not None
        first = [proc.stderr.readline().strip() for _ in range(lines)]
        # The rest of its stderr is passed on (and never fills a pipe that nobody reads).
        err = proc.stderr
        threading.Thread(target=lambda: [print(x, end="", file=sys.stderr) for x in err], daemon=True).start()
        return proc, first

    results: dict[str, object] = {}
    failed = {} if failed is None else failed
    try:
        st_port = _free_udp_port()
        office_args = ["office", "serve", "--db", db, "--port", "0", "--http-port", str(http_port)]
        if operators is not None:
            office_args += ["--zc", f"127.0.0.1:{zc_port}", "--operators", operators]
            if controller is not None:
                office_args += ["--stations", f"127.0.0.1:{st_port}"]  # the page's WCC commands
        _, lines = start(office_args, lines=2)
        page = next((x for x in lines if x.startswith("control-room page")), "")
        listening = next((x for x in lines if x.startswith("office listening")), "")
        if not page or not listening:
            raise RailstopError(f"the office did not start: {' '.join(lines)}")
        office_addr = listening.split(" on ")[1].split()[0]
        # The run's time base starts now: the office (which keeps Unix time) is up.
        common = ["--epoch", repr(time.time()), "--scale", repr(scale)]
        if zc_state is None:
            import tempfile

            url = "://" in db
            zc_state = f"{tempfile.gettempdir()}/railstop-zc-{zc_port}.state" if url else f"{db}.zc-state"
        zc, (zc_line,) = start(
            ["live", "zc", "--port", str(zc_port), "--trains", str(trains), "--office", office_addr,
             "--state", zc_state, "--new", *common]
        )  # fmt: skip
        if not zc_line.startswith("zone controller on"):
            raise RailstopError(f"the zone controller did not start: {zc_line}")
        outage_args = [a for o in outages for a in ("--outage", o)]
        plant_port = _free_udp_port()
        plant_args = ["live", "plant", "--port", str(plant_port), "--trains", str(trains), "--spacing-m",
                      str(spacing_m), *common]  # fmt: skip
        if controller is not None:
            plant_args += ["--stations", f"127.0.0.1:{st_port}", "--controller", controller]
        plant_proc = launch(plant_args)
        tasc_args: list[str] = []
        if controller is not None:
            # The stations and the trains load their compiled steps at the same time.
            stations_proc = launch(
                ["live", "stations", "--port", str(st_port), "--controller", controller, "--office",
                 office_addr, *[a for j in psd_jams or [] for a in ("--psd-jam", j)], *common]
            )  # fmt: skip
            tasc_args = ["--stations", f"127.0.0.1:{st_port}", "--controller", controller]
            tasc_args += ["--tasc-loss", repr(tasc_loss), "--door-mode", door_mode]
        _, (plant_line,) = start([], proc=plant_proc)
        if not plant_line.startswith("plant on"):
            raise RailstopError(f"the plant did not start: {plant_line}")
        tr = launch(
            ["live", "trains", "--zc", f"127.0.0.1:{zc_port}", "--trains", str(trains), "--spacing-m",
             str(spacing_m), "--office", office_addr, "--plant", f"127.0.0.1:{plant_port}", *outage_args,
             *tasc_args, *common]
        )  # fmt: skip
        if controller is not None:
            _, (st_line,) = start([], proc=stations_proc)
            if not st_line.startswith("stations on"):
                raise RailstopError(f"the stations did not start: {st_line}")
        start([], proc=tr)
        print(
            f"{page} (open it in a browser); office {office_addr}, zone controller 127.0.0.1:{zc_port} "
            f"(pid {zc.pid}), plant 127.0.0.1:{plant_port} (pid {plant_proc.pid}), "
            f"{'stations (pid ' + str(stations_proc.pid) + '), ' if controller else ''}trains "
            f"(pid {tr.pid}); running {duration_s:g} s",
            flush=True,
        )
        time.sleep(duration_s)
    except RailstopError as exc:
        for p in procs:
            p.kill()
        fail(str(exc))
    finally:
        # The trains first, the office last: it stores what the others report as they stop.
        # The line's processes stop together (one alone would see its peers fall silent: lost
        # trains, missed commands), then the office, which stores what they report as they stop.
        roles = ("office", "zone_controller", "plant", *(("stations",) if controller else ()), "trains")
        by_role = dict(zip(roles, procs, strict=False))
        # A process that ended before the stop (killed, crashed) ends the run as a failure.
        early = {role: p.returncode for role, p in by_role.items() if p.poll() is not None}
        for role in ("trains", "zone_controller", "plant", "stations"):
            if role in by_role and by_role[role].poll() is None:
                by_role[role].send_signal(signal.SIGTERM)
        for role in ("trains", "zone_controller", "plant", "stations", "office"):
            if role not in by_role:
                continue
            p = by_role[role]
            if role == "office" and p.poll() is None:
                p.send_signal(signal.SIGTERM)
            out, _ = p.communicate(timeout=30)
            text = out.strip().splitlines()[-1] if out.strip() else ""
            results[role] = json.loads(text) if text.startswith("{") else text
            if role in early or p.returncode != 0:
                failed[role] = p.returncode
    return results


RunZcStateOpt = Annotated[
    str | None,
    typer.Option(
        "--zc-state",
        help="The zone controller's durable state file (default: the database's path + .zc-state); "
        "a zone controller started again by hand reads it (railstop live zc --state).",
    ),
]
OperatorsOpt = Annotated[
    str | None, typer.Option(help="Operators file (railstop office add-operator): the page's zone release.")
]


@live_app.command("run")
def run_cmd(
    trains: TrainsOpt = 4,
    duration_s: Annotated[float, typer.Option(min=1.0, max=86400.0, help="Wall seconds to run.")] = 120.0,
    scale: ScaleOpt = 1.0,
    db: Annotated[
        str, typer.Option(help="The office's database (SQLite file or PostgreSQL URL).")
    ] = "railstop.db",
    http_port: Annotated[int, typer.Option(min=0, max=65535, help="The control-room page's port.")] = 8080,
    spacing_m: SpacingOpt = 600.0,
    operators: OperatorsOpt = None,
    outage: OutageOpt = None,
    controller: TascControllerOpt = "tasc-pwm",
    tasc: Annotated[
        bool, typer.Option("--tasc/--no-tasc", help="Stop by ground TASC (a stations process).")
    ] = True,
    tasc_loss: Annotated[
        float,
        typer.Option(min=0.0, max=1.0, help="Fault injection: the share of braking telegram frames lost."),
    ] = 0.0,
    psd_jam: PsdJamOpt = None,
    door_mode: DoorModeOpt = "auto",
    zc_state: RunZcStateOpt = None,
) -> None:
    """Office (with its page), zone controller, stations and trains as processes for --duration-s."""
    try:
        ctrl = _tasc_controller(controller) if tasc else None
        _check_door_mode(door_mode)
        if psd_jam:
            from railstop.config import load_line
            from railstop.config.doors import load_doors

            _psd_jams(psd_jam, load_line(None), load_doors(None).doors_per_side)  # refused before any start
    except RailstopError as exc:
        fail(str(exc))
    failed: dict[str, int | None] = {}
    results = _run_line(
        trains=trains,
        duration_s=duration_s,
        scale=scale,
        db=db,
        http_port=http_port,
        spacing_m=spacing_m,
        operators=operators,
        outages=list(outage or []),
        controller=ctrl,
        tasc_loss=tasc_loss,
        psd_jams=list(psd_jam or []),
        door_mode=door_mode,
        zc_state=zc_state,
        failed=failed,
    )
    print(json.dumps(results))
    if failed:  # the run's record is printed above; the run itself failed
        fail(_failed_text(failed))


def _failed_text(failed: dict[str, int | None]) -> str:
    """One line: the processes that ended early or failed, with their exit codes."""
    parts = [f"{role.replace('_', ' ')} (exit code {code})" for role, code in failed.items()]
    return f"the live run failed: {', '.join(parts)} ended before the stop or with an error"


@live_app.command("demo")
def demo_cmd(
    http_port: Annotated[int, typer.Option(min=0, max=65535, help="The control-room page's port.")] = 8080,
    db: Annotated[str, typer.Option(help="The office's database.")] = "railstop-live.db",
    operators: OperatorsOpt = None,
    zc_state: RunZcStateOpt = None,
) -> None:
    """Two minutes of six trains with a radio outage of train 2 from 30 s to 50 s: its protection
    zone, its re-detection; prints where to open the page, then what happened."""
    failed: dict[str, int | None] = {}
    results = _run_line(
        trains=6,
        duration_s=120.0,
        scale=1.0,
        db=db,
        http_port=http_port,
        spacing_m=600.0,
        operators=operators,
        outages=["2:30:20"],
        zc_state=zc_state,
        failed=failed,
    )
    if failed:
        fail(_failed_text(failed))
    zc = results.get("zone_controller")
    fleet = results.get("trains")
    office = results.get("office")
    if not (isinstance(zc, dict) and isinstance(fleet, dict) and isinstance(office, dict)):
        fail(f"a process did not finish cleanly: {json.dumps(results)}")
    print(
        f"zone controller: {zc['reports']} reports, {zc['commands']} commands, {zc['lost_trains']} train(s) "
        f"lost, {zc['auto_releases']} re-detected inside their zone (released), {zc['flagged']} outside "
        f"(flagged), {zc['manual_releases']} manual release(s); trains: emergency brakes "
        f"{fleet['emergency_brakes'] or 'none'}; office: {office['stored']} reports stored in {db}"
    )
    t = fleet.get("tasc")
    if isinstance(t, dict):
        print(
            f"station stops by ground TASC (tasc-pwm): {t['stops']}, {t['within_tolerance']} within the "
            f"stations' tolerance, |error| p99 {t['abs_error_p99_m']} m, max {t['abs_error_max_m']} m; "
            f"emergency brakes {t['emergency_brakes'] or 'none'}"
        )
    d = fleet.get("dwells")
    if isinstance(d, dict):
        print(
            f"dwells over the door link (SPEC §5): {d['dwells']} ended {d['outcomes'] or '-'}, "
            f"{d['corrections']} correction(s), the longest {d['dwell_s_max']} s from standstill to "
            f"start enable"
        )
