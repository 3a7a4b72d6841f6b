"""``railstop office serve``: the management office (SPEC §1 claims 7, 20) as a service."""

from __future__ import annotations

import json
import os
import signal
import socket
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

from railstop.cli.common import LineOpt, address_option, command_group, fail
from railstop.errors import RailstopError

if TYPE_CHECKING:
    import asyncio

office_app = command_group(
    "The management office: receives the wayside's reports and keeps them in a database."
)

KEY_ENV = "RAILSTOP_OFFICE_KEY"
# A key file is one line of hex; anything longer is not one (and is not read into memory whole).
# The refusal of --key-hex (EN 50159 category 3: the links' master key is a credential). A command
# line is readable by every user of the machine (ps, /proc/PID/cmdline) and stays in shell
# histories, so the option is declared only to say this; the value is never echoed.
KEY_HEX_REFUSED = (
    "--key-hex: a key is never given on the command line (every user sees it in the process list, "
    f"and it stays in the shell history): use --key-file FILE (mode 0600; railstop office new-key "
    f"--out FILE writes one) or set {KEY_ENV}"
)

KeyFileOpt = Annotated[
    Path | None,
    typer.Option(
        "--key-file",
        help=f"File holding the links' master key in hex, mode 0600 (railstop office new-key writes "
        f"one); or set {KEY_ENV}.",
    ),
]
# Hidden: declared only to refuse it with KEY_HEX_REFUSED (not an unknown-option error).
KeyHexOpt = Annotated[str | None, typer.Option("--key-hex", hidden=True)]


def _key_from_hex(text: str, where: str) -> bytes:
    from railstop.link.keys import key_from_hex  # lazy: CLI start-up (railstop.link loads the codec)

    return key_from_hex(text, where)


def read_key_file(path: Path) -> bytes:
    """The master key in a key file (``railstop.link.keys.read_key_file``: 0600, hex, 16 bytes)."""
    from railstop.link.keys import read_key_file as read  # lazy: CLI start-up

    return read(path)


def master_key(key_file: Path | None, key_hex: str | None = None) -> bytes:
    """The links' master key (EN 50159 category 3): from ``--key-file`` or else the environment's
    RAILSTOP_OFFICE_KEY (hex, >= 16 bytes). ``key_hex`` (``--key-hex``) is refused whatever its
    value: a key on a command line is readable by every user of the machine. No key, or a bad one:
    a RailstopError (the process does not start)."""
    if key_hex is not None:
        raise RailstopError(KEY_HEX_REFUSED)
    if key_file is not None:
        return read_key_file(key_file)
    text = os.environ.get(KEY_ENV)
    if not text:
        raise RailstopError(
            f"--key-file: the links' master key is needed: give --key-file FILE (mode 0600) or set {KEY_ENV}"
        )
    return _key_from_hex(text, KEY_ENV)


def sender_ids(spec: str) -> tuple[int, ...]:
    """``"1-40"`` or ``"1,2,7"`` (safety-layer ids 0..65535) as a tuple."""
    ids: list[int] = []
    try:
        for part in spec.split(","):
            lo, _, hi = part.strip().partition("-")
            a, b = int(lo), int(hi or lo)
            if not 0 <= a <= b <= 0xFFFF:
                raise ValueError
            ids.extend(range(a, b + 1))
    except ValueError:
        raise RailstopError(
            f"--senders: ids or ranges of ids 0..65535, e.g. 1-40 or 1,2,7 (got {spec!r})"
        ) from None
    return tuple(sorted(set(ids)))


@office_app.command("serve")
def serve_cmd(
    db: Annotated[
        str, typer.Option(help="SQLite file, or a PostgreSQL URL (postgresql://user@host:port/db).")
    ] = "railstop.db",
    host: Annotated[str, typer.Option(help="Address to listen on.")] = "127.0.0.1",
    port: Annotated[int, typer.Option(min=0, max=65535, help="UDP port (0: any free one).")] = 7700,
    key_file: KeyFileOpt = None,
    key_hex: KeyHexOpt = None,
    senders: Annotated[str, typer.Option(help="The wayside units' ids it accepts.")] = "1-899",
    http_port: Annotated[
        int | None,
        typer.Option("--http-port", min=0, max=65535, help="Also serve the control-room page (0: any port)."),
    ] = None,
    zc: Annotated[
        str | None, typer.Option(help="The zone controller's UDP address HOST:PORT, for manual releases.")
    ] = None,
    stations: Annotated[
        str | None,
        typer.Option(help="The stations' UDP address HOST:PORT, for the WCC's commands to the WPCS."),
    ] = None,
    operators: Annotated[
        Path | None,
        typer.Option(
            help="Operators file (railstop office add-operator, mode 0600): who may log in to the page "
            "and send its commands."
        ),
    ] = None,
    allowed_hosts: Annotated[
        str | None,
        typer.Option(
            "--allowed-hosts",
            help="Host names (or HOST:PORT) the page answers to, comma-separated (default: the address "
            "it listens on).",
        ),
    ] = None,
    tls_cert: Annotated[
        Path | None, typer.Option("--tls-cert", help="Serve the page over TLS with this certificate (PEM).")
    ] = None,
    tls_key: Annotated[Path | None, typer.Option("--tls-key", help="The certificate's key (PEM).")] = None,
    http_timeout_s: Annotated[
        float,
        typer.Option(
            "--http-timeout-s",
            min=0.5,
            max=300.0,
            help="A request's headers, and its body, must arrive within this.",
        ),
    ] = 10.0,
    line: LineOpt = None,
) -> None:
    """Receive, store and acknowledge the wayside's reports until stopped (SIGTERM, Ctrl-C); with
    --http-port, serve the control-room page too, behind a login (--operators; without it a one-time
    credential for viewing is printed once); with --zc: its zone release; with --stations: its WCC
    commands."""
    from railstop.config import load_line
    from railstop.link.udp import EpochClock
    from railstop.live.office import serve_office

    try:
        key = master_key(key_file, key_hex)
        ids = sender_ids(senders)
        ln = load_line(line)
        if operators is None and (zc is not None or stations is not None):
            raise RailstopError("--zc / --stations: the operator commands need --operators")
        ops = None
        zc_addr = None if zc is None else address_option(zc, "--zc")
        st_addr = None if stations is None else address_option(stations, "--stations")
        if operators is not None:
            from railstop.live.operators import load_operators

            ops = load_operators(operators)
        page_opts: dict[str, Any] = (
            {} if http_port is None else _page_options(host, allowed_hosts, tls_cert, tls_key, http_timeout_s)
        )
    except RailstopError as exc:
        fail(str(exc))
    # Without an operators file the page still needs a login: a random one for viewing only, for this
    # run only, printed once to the terminal (never on a command line, never stored).
    viewer = None if ops is not None or http_port is None else _one_time_viewer()
    station_list = [{"name": st.name, "chainage_m": st.stop_point_m} for st in ln.stations]
    length = ln.line.length_m or max(st.stop_point_m for st in ln.stations) + 500.0
    line_data = {"name": ln.line.name, "length_m": length, "stations": station_list}

    import asyncio  # lazy: CLI start-up (the event loop only for the serving processes)

    async def main() -> dict[str, object]:
        stop = asyncio.Event()
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(sig, stop.set)

        def ready(addr: tuple[str, int]) -> None:
            print(f"office listening on {addr[0]}:{addr[1]} (database {db})", file=sys.stderr, flush=True)
            if viewer is not None:
                print(
                    f"control-room login: {VIEWER} / {viewer[0]} (viewing only, this run only)",
                    file=sys.stderr,
                    flush=True,
                )

        page = (
            None
            if http_port is None
            else await _start_page(
                host,
                http_port,
                ln.line.name,
                line_data,
                key,
                dict(ops or {}) if viewer is None else {VIEWER: viewer[1]},
                zc_addr,
                st_addr,
                page_opts,
            )
        )
        try:
            stats = await serve_office(
                db=db,
                local=(host, port),
                master_key=key,
                senders=ids,
                clock=EpochClock(0.0),
                stop=stop,
                on_ready=ready,
                on_report=None if page is None else page.broadcast.publish,
                on_store=None if page is None else page.stores.append,
            )
        finally:
            if page is not None:
                await page.close()
        return stats.as_dict()  # with the database's retries, outages and time away

    started = time.monotonic()
    try:
        result = asyncio.run(main())
    except RailstopError as exc:
        fail(str(exc))
    from railstop.link.udp import process_udp_stats  # lazy: CLI start-up

    result["udp"] = process_udp_stats()  # every datagram dropped (kernel, queue, too long), counted
    result["cpu_s"] = round(time.process_time(), 2)
    result["wall_s"] = round(time.monotonic() - started, 2)
    print(json.dumps(result))


class _Page:
    """The control-room page running beside the office (uvicorn in the office's event loop)."""

    def __init__(self, server: Any, task: asyncio.Task[None], broadcast: Any, stores: list[Any]) -> None:
        self.server, self.task, self.broadcast, self.stores = server, task, broadcast, stores

    async def close(self) -> None:
        self.server.should_exit = True
        await self.task


VIEWER = "viewer"  # the one-time login's name (only when the office has no operators file)
STOP_CHART_MAX = 20_000  # the stop results the page's chart gets at most (the latest ones)
CREDENTIAL_ENV = "RAILSTOP_OPERATOR_CREDENTIAL"


def _one_time_viewer() -> tuple[str, Any]:
    """A random credential (128 bits) and its operator entry, which may view but never command."""
    import secrets

    from railstop.live.operators import Operator, hash_credential
    from railstop.live.page import VIEW_ONLY_ID

    secret = secrets.token_urlsafe(16)
    # 128 random bits need no slow hash against guessing; a few iterations keep the login quick.
    return secret, Operator(id=VIEW_ONLY_ID, pbkdf2_sha256=hash_credential(secret, iterations=10_000))


def _page_options(
    host: str, allowed_hosts: str | None, tls_cert: Path | None, tls_key: Path | None, timeout_s: float
) -> dict[str, Any]:
    """The page's options, checked (a RailstopError naming the option)."""
    from railstop.live.page import AllowedHosts, PageLimits

    if (tls_cert is None) != (tls_key is None):
        raise RailstopError("--tls-cert / --tls-key: give both or neither")
    for opt, path in (("--tls-cert", tls_cert), ("--tls-key", tls_key)):
        if path is not None and not path.is_file():
            raise RailstopError(f"{opt}: {path}: no such file")
    names = [] if allowed_hosts is None else [n for n in allowed_hosts.split(",") if n.strip()]
    if allowed_hosts is not None and not names:
        raise RailstopError(f"--allowed-hosts: a host name or HOST:PORT expected (got {allowed_hosts!r})")
    if not names and host in ("0.0.0.0", "::", ""):
        raise RailstopError("--allowed-hosts: the page listens on every address: name its host names")
    return {
        "hosts": AllowedHosts(names),
        "limits": PageLimits(request_timeout_s=timeout_s),
        "tls_cert": None if tls_cert is None else str(tls_cert),
        "tls_key": None if tls_key is None else str(tls_key),
    }


async def _start_page(
    host: str,
    port: int,
    name: str,
    line_data: dict[str, Any],
    key: bytes,
    operators: dict[str, Any],
    zc: tuple[str, int] | None,
    stations: tuple[str, int] | None,
    options: dict[str, Any],
) -> _Page:
    import asyncio

    import uvicorn

    from railstop.live.page import Broadcast, make_app, page_config

    broadcast = Broadcast()
    stores: list[Any] = []  # the office's open store, once it is open

    def history(after: int, n: int) -> list[dict[str, Any]]:
        return stores[0].office_reports(after_id=after, limit=n, latest=True) if stores else []

    def stop_history() -> list[dict[str, Any]]:  # the page's stop chart: the whole record
        return (
            stores[0].office_reports(kind="stop-result", limit=STOP_CHART_MAX, latest=True) if stores else []
        )

    log = _ActionLog(stores, broadcast)
    desk = None
    if zc is not None or stations is not None:
        desk = _OperatorDesk(
            key=key,
            log=log,
            zc=zc,
            stations=stations,
            station_names=[st["name"] for st in line_data["stations"]],
        )
    hosts, limits = options["hosts"], options["limits"]
    app = make_app(
        history=history,
        stops=stop_history,
        broadcast=broadcast,
        title=f"railstop control room: {name}",
        line=line_data,
        operators=operators,
        hosts=hosts,
        limits=limits,
        audit=log.log,
        release=None if desk is None or zc is None else desk.release,
        wcc=None if desk is None or stations is None else desk.wcc,
    )
    tls = options["tls_cert"] is not None
    config = page_config(
        app, host=host, port=port, limits=limits, tls_cert=options["tls_cert"], tls_key=options["tls_key"]
    )
    server = uvicorn.Server(config)
    try:
        config.load()
    except Exception as exc:  # the certificate or key cannot be read: one line
        raise RailstopError(f"--tls-cert / --tls-key: cannot load them ({exc})") from None
    # The page's socket is bound here, not by uvicorn: a port in use (or an address this machine
    # does not have) is one line, where uvicorn would log it and exit the process from its task.
    listening = _listen(host, port)
    task = asyncio.create_task(server.serve(sockets=[listening]))
    while not server.started and not task.done():
        await asyncio.sleep(0.02)
    if task.done():
        raise RailstopError(f"--http-port: cannot serve the control-room page on {host}:{port}")
    bound = server.servers[0].sockets[0].getsockname()
    try:
        hosts.bind(bound[0], bound[1])
    except RailstopError:
        server.should_exit = True
        await task
        raise
    shown = f"[{bound[0]}]" if ":" in bound[0] else bound[0]
    print(
        f"control-room page at {'https' if tls else 'http'}://{shown}:{bound[1]}/",
        file=sys.stderr,
        flush=True,
    )
    return _Page(server, task, broadcast, stores)


def _listen(host: str, port: int) -> socket.socket:
    """A TCP socket bound to (host, port) for the page, or a RailstopError naming the option."""
    try:
        family, kind, proto, _, address = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)[0]
    except OSError as exc:
        raise RailstopError(f"--host: cannot listen on {host}: {exc.strerror or exc}") from None
    sock = socket.socket(family, kind, proto)
    try:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.bind(address)
    except OSError as exc:
        sock.close()
        raise RailstopError(f"--http-port: cannot listen on {host}:{port}: {exc.strerror or exc}") from None
    return sock


class _ActionLog:
    """The operators' actions (logins, refusals, commands) in the office's database, kind
    ``operator-action`` (SPEC §1 claim 20: the history of the commands), and on the open pages."""

    def __init__(self, stores: list[Any], broadcast: Any) -> None:
        from railstop.live.office import new_session

        self.stores, self.broadcast = stores, broadcast
        self.session = new_session()
        self.actions = iter(range(1, 1 << 62))

    async def log(self, data: dict[str, Any]) -> None:
        import asyncio

        from railstop.live.office import OFFICE_ID

        if not self.stores:
            return
        row = await asyncio.to_thread(
            self.stores[0].save_office_report,
            sender_id=OFFICE_ID,
            session=self.session,
            seq=next(self.actions),
            kind="operator-action",
            sent_s=time.time(),
            data=data,
        )
        if row is not None:
            self.broadcast.publish(row)


class _OperatorDesk:
    """The control room's operator commands, once the page has authenticated them (session, one-time
    token, credential): each logged in the database (kind ``operator-action``, with its outcome) and
    sent as an authenticated telegram that carries the operator's id (``link.release_link``): SPEC §4
    step 5, the zone release to the zone controller; SPEC §5, the WCC's switch of a station's WPCS
    to manual (and the platform panel's buttons) to the stations."""

    def __init__(
        self,
        *,
        key: bytes,
        log: _ActionLog,
        zc: tuple[str, int] | None,
        stations: tuple[str, int] | None,
        station_names: list[str],
    ) -> None:
        import socket

        from railstop.link.release_link import WCC_ADDRESS, OperatorConsole, release_key, wcc_key

        self.log = log
        self.zc, self.stations, self.station_names = zc, stations, station_names
        self.consoles = {
            "zc": OperatorConsole(key=release_key(key)),
            "wcc": OperatorConsole(key=wcc_key(key), to=WCC_ADDRESS),
        }
        # [interpretation] The operator links' sequence numbers go on across office restarts: they
        # start at the tenths of seconds since 2026 (a receiver refuses a number it has had);
        # 2**32 of them last until 2039.
        for console in self.consoles.values():
            console.sender.next_seq = int((time.time() - 1_767_225_600.0) * 10.0)
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)

    async def release(self, order: Any) -> tuple[int, str]:
        if self.zc is None:
            return 503, "this office has no zone controller link"
        action = {"operator": order.operator, "operator_id": order.operator_id, "action": "zone-release"}
        frame = self.consoles["zc"].release(order.train, time.time(), operator_id=order.operator_id)
        self.sock.sendto(frame, self.zc)
        await self.log.log({**action, "train": order.train, "result": "sent to the zone controller"})
        return 200, f"release of train {order.train}'s zone sent to the zone controller"

    async def wcc(self, order: Any) -> tuple[int, str]:
        if self.stations is None:
            return 503, "this office has no link to the stations"
        if order.station >= len(self.station_names):
            return 400, f"no station {order.station} on this line"
        name = self.station_names[order.station]
        what = f"WPCS {order.mode}" + (f", panel {order.panel}" if order.panel != "none" else "")
        action = {"operator": order.operator, "operator_id": order.operator_id, "action": "wcc"}
        frame = self.consoles["wcc"].wcc(
            order.station,
            manual=order.mode == "manual",
            panel_open=order.panel == "open",
            panel_close=order.panel == "close",
            now_s=time.time(),
            operator_id=order.operator_id,
        )
        self.sock.sendto(frame, self.stations)
        await self.log.log({**action, "station": name, "command": what, "result": "sent to the station"})
        return 200, f"{name}: {what} sent to the station"


@office_app.command("add-operator")
def add_operator_cmd(
    file: Annotated[Path, typer.Argument(help="The operators file (created if missing, mode 0600).")],
    name: Annotated[str, typer.Argument(help="The operator's name.")],
    op_id: Annotated[
        int | None,
        typer.Option(
            "--id",
            min=1,
            max=65535,
            help="The operator's id in the command telegrams (default: "
            "the operator's so far, or the next free one).",
        ),
    ] = None,
    credential_file: Annotated[
        Path | None,
        typer.Option(
            "--credential-file",
            help=f"Read the credential from this file's first line (or set "
            f"{CREDENTIAL_ENV}; default: a prompt).",
        ),
    ] = None,
    credential: Annotated[str | None, typer.Option("--credential", hidden=True)] = None,
) -> None:
    """Add an operator (or change one's credential); only a salted PBKDF2 hash is written. The
    credential comes from a prompt, a file or the environment, never from the command line."""
    from railstop.live.operators import add_operator

    if credential is not None:
        fail(
            "--credential: a credential is never given on the command line (shell history, process list): "
            f"use the prompt, --credential-file or {CREDENTIAL_ENV}"
        )
    try:
        if credential_file is not None:
            try:
                secret = (
                    credential_file.read_text(encoding="utf-8").splitlines()[0]
                    if credential_file.stat().st_size
                    else ""
                )
            except (OSError, UnicodeDecodeError) as exc:
                raise RailstopError(f"--credential-file: {credential_file}: cannot read it ({exc})") from None
        elif os.environ.get(CREDENTIAL_ENV):
            secret = os.environ[CREDENTIAL_ENV]
        elif sys.stdin.isatty():
            secret = typer.prompt("Credential", hide_input=True, confirmation_prompt=True)
        else:
            raise RailstopError(
                f"no credential: answer the prompt, or give --credential-file or {CREDENTIAL_ENV}"
            )
        given = add_operator(file, name, secret, op_id=op_id)
    except RailstopError as exc:
        fail(str(exc))
    print(f"operator {name} (id {given}) written to {file} (mode 0600)")


@office_app.command("new-key")
def new_key_cmd(
    out: Annotated[
        Path,
        typer.Option(
            "--out", help="The key file to create (mode 0600); an existing file is never overwritten."
        ),
    ],
) -> None:
    """Write a fresh random master key for the links (32 bytes, in hex) to a new file with mode
    0600, for --key-file; the key itself is never printed."""
    import secrets

    flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0)
    try:
        # O_EXCL: a key in use (or a link planted at the name) is never overwritten or followed.
        fd = os.open(out, flags, 0o600)
    except FileExistsError:
        fail(f"--out: {out}: exists already (a key in use is never overwritten): remove it or pick another")
    except OSError as exc:
        fail(f"--out: {out}: cannot create it ({exc.strerror or exc})")
    with os.fdopen(fd, "w", encoding="ascii") as fh:
        if os.name == "posix":
            os.fchmod(fd, 0o600)  # whatever the umask
        fh.write(secrets.token_bytes(32).hex() + "\n")
    print(f"a new master key written to {out} (mode 0600): give the line's processes --key-file {out}")


@office_app.command("reports")
def reports_cmd(
    db: Annotated[str, typer.Option(help="The office's database (SQLite file or PostgreSQL URL).")],
    kind: Annotated[str | None, typer.Option(help="Only reports of this kind.")] = None,
    last: Annotated[int, typer.Option(min=1, max=1_000_000, help="The latest this many reports.")] = 20,
    as_json: Annotated[bool, typer.Option("--json", help="One JSON object per report (JSON lines).")] = False,
) -> None:
    """The reports the office has stored, latest last (SPEC §1 claim 20: the history of the
    commands, with their inputs), and a summary of the station stops among them."""
    from rich.console import Console
    from rich.table import Table

    from railstop.link.office_link import KINDS
    from railstop.store import open_store

    if kind is not None and kind not in KINDS:
        fail(f"--kind: one of {', '.join(KINDS)} (got {kind!r})")
    if not db.startswith(("sqlite:", "postgresql")) and not Path(db).is_file():
        fail(f"--db: {db}: no such database file")
    try:
        with open_store(db) as store:
            rows = store.office_reports(kind=kind, limit=last, latest=True)
            total = store.office_report_count()
    except RailstopError as exc:
        fail(str(exc))
    if as_json:
        for r in rows:
            print(json.dumps(r, sort_keys=True))
        return
    table = Table(title=f"{len(rows)} of {total} reports in {db}", title_justify="left")
    for col in ("id", "received (UTC)", "sender", "kind"):
        table.add_column(col, no_wrap=True)
    table.add_column("data", overflow="fold")
    for r in rows:
        data = json.dumps(r["data"], separators=(", ", ": "))
        received = r["received_utc"][11:19]  # the day is in --json
        table.add_row(str(r["id"]), received, str(r["sender_id"]), r["kind"], data)
    console = Console()
    console.print(table)
    for line in stop_summary_lines([r["data"] for r in rows if r["kind"] == "stop-result"]):
        console.print(line, highlight=False)
    for line in dwell_summary_lines([r["data"] for r in rows if r["kind"] == "dwell-result"]):
        console.print(line, highlight=False)


def stop_summary_lines(stops: list[dict[str, Any]]) -> list[str]:
    """Per station and controller: stops, within tolerance, |error| max, emergency brakes."""
    groups: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for s in stops:
        groups.setdefault((str(s.get("station")), str(s.get("controller"))), []).append(s)
    out = []
    for (station, controller), items in sorted(groups.items()):
        within = sum(bool(s.get("within")) for s in items)
        worst = max(abs(float(s.get("error_m", 0.0))) for s in items)
        ebs = sum(s.get("emergency_brake") is not None for s in items)
        out.append(
            f"{station} ({controller}): {len(items)} stop(s), {within} within tolerance, "
            f"|error| max {worst:.3f} m, {ebs} emergency brake(s)"
        )
    return out


def dwell_summary_lines(dwells: list[dict[str, Any]]) -> list[str]:
    """Per station (SPEC §5): dwells, start enables, faults, corrections, the longest to start
    enable."""
    groups: dict[str, list[dict[str, Any]]] = {}
    for d in dwells:
        groups.setdefault(str(d.get("station")), []).append(d)
    out = []
    for station, items in sorted(groups.items()):
        enabled = [d for d in items if d.get("outcome") == "start-enable"]
        faults = sum(d.get("outcome") == "fault" for d in items)
        corrections = sum(int(d.get("corrections") or 0) for d in items)
        longest = max((float(d["dwell_s"]) for d in enabled if d.get("dwell_s") is not None), default=None)
        out.append(
            f"{station} (doors): {len(items)} dwell(s), {len(enabled)} start enable, {faults} fault(s), "
            f"{corrections} correction(s)" + ("" if longest is None else f", longest {longest:.1f} s")
        )
    return out
