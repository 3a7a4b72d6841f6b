"""``railstop office serve``: the management office (SPEC §1 claims 7, 20) as a service."""

from __future__ import annotations

import asyncio
import json
import os
import signal
import sys
import time
from pathlib import Path
from typing import Annotated, Any

import typer

from railstop.cli_common import LineOpt, address_option, fail
from railstop.errors import RailstopError

office_app = typer.Typer(
    add_completion=False,
    no_args_is_help=True,
    help="The management office: receives the wayside's reports and keeps them in a database.",
)

KEY_ENV = "RAILSTOP_OFFICE_KEY"


def master_key(key_hex: str | None) -> bytes:
    """The link's master key: ``--key-hex`` or the environment's RAILSTOP_OFFICE_KEY (hex, >= 16 bytes)."""
    text = key_hex if key_hex is not None else os.environ.get(KEY_ENV)
    if not text:
        raise RailstopError(f"--key-hex: the office link's master key is needed (or set {KEY_ENV})")
    try:
        key = bytes.fromhex(text)
    except ValueError:
        raise RailstopError("--key-hex: not hexadecimal") from None
    if len(key) < 16:
        raise RailstopError(f"--key-hex: at least 16 bytes (32 hex digits) are needed (got {len(key)})")
    return key


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
    key_hex: Annotated[
        str | None, typer.Option("--key-hex", help=f"The link's master key in hex (or set {KEY_ENV}).")
    ] = None,
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
        typer.Option(help="Operators file (railstop office add-operator) for the page's operator commands."),
    ] = None,
    line: LineOpt = None,
) -> None:
    """Receive, store and acknowledge the wayside's reports until stopped (SIGTERM, Ctrl-C); with
    --http-port, serve the control-room page too (with --operators and --zc: its zone release; with
    --operators and --stations: its WCC commands)."""
    from railstop.config import load_line
    from railstop.link.udp import EpochClock
    from railstop.live.office import serve_office

    try:
        key = master_key(key_hex)
        ids = sender_ids(senders)
        ln = load_line(line)
        if operators is not None and zc is None and stations is None:
            raise RailstopError("--operators: give --zc (zone release) and / or --stations (WCC) too")
        if operators is None and (zc is not None or stations is not None):
            raise RailstopError("--zc / --stations: the operator commands need --operators")
        ops = None
        zc_addr = None if zc is None else address_option(zc, "--zc")
        st_addr = None if stations is None else address_option(stations, "--stations")
        if operators is not None:
            from railstop.live.operators import load_operators

            ops = load_operators(operators)
    except RailstopError as exc:
        fail(str(exc))
    station_list = [{"name": st.name, "chainage_m": st.stop_point_m} for st in ln.stations]
    length = ln.line.length_m or max(st.stop_point_m for st in ln.stations) + 500.0
    line_data = {"name": ln.line.name, "length_m": length, "stations": station_list}

    async def main() -> dict[str, object]:
        stop = asyncio.Event()
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(sig, stop.set)

        def ready(addr: tuple[str, int]) -> None:
            print(f"office listening on {addr[0]}:{addr[1]} (database {db})", file=sys.stderr, flush=True)

        page = (
            None
            if http_port is None
            else await _start_page(host, http_port, ln.line.name, line_data, key, ops, zc_addr, st_addr)
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
        return {"stored": stats.stored, "duplicates": stats.duplicates, "rejected": stats.rejected}

    started = time.monotonic()
    try:
        result = asyncio.run(main())
    except RailstopError as exc:
        fail(str(exc))
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


async def _start_page(
    host: str,
    port: int,
    name: str,
    line_data: dict[str, Any],
    key: bytes,
    operators: dict[str, str] | None,
    zc: tuple[str, int] | None,
    stations: tuple[str, int] | None,
) -> _Page:
    import uvicorn

    from railstop.live.page import Broadcast, make_app

    broadcast = Broadcast()
    stores: list[Any] = []  # the office's open store, once it is open

    def history(after: int, n: int) -> list[dict[str, Any]]:
        return stores[0].office_reports(after_id=after, limit=n, latest=True) if stores else []

    desk = None
    if operators is not None:
        desk = _OperatorDesk(
            operators=operators,
            key=key,
            stores=stores,
            broadcast=broadcast,
            zc=zc,
            stations=stations,
            station_names=[st["name"] for st in line_data["stations"]],
        )
    app = make_app(
        history=history,
        broadcast=broadcast,
        title=f"railstop control room: {name}",
        line=line_data,
        release=None if desk is None or zc is None else desk.release,
        wcc=None if desk is None or stations is None else desk.wcc,
    )
    server = uvicorn.Server(uvicorn.Config(app, host=host, port=port, log_level="warning", lifespan="off"))
    task = asyncio.create_task(server.serve())
    while not server.started and not task.done():
        await asyncio.sleep(0.02)
    if task.done():
        raise RailstopError(f"--http-port: cannot serve the control-room page on {host}:{port}")
    bound = server.servers[0].sockets[0].getsockname()
    print(f"control-room page at http://{bound[0]}:{bound[1]}/", file=sys.stderr, flush=True)
    return _Page(server, task, broadcast, stores)


class _OperatorDesk:
    """The control room's operator commands, each checked against the operators file, logged in the
    database (kind ``operator-action``, with its outcome) and sent as an authenticated telegram
    (``link.release_link``): SPEC §4 step 5, the zone release to the zone controller; SPEC §5, the
    WCC's switch of a station's WPCS to manual (and the platform panel's buttons) to the stations."""

    def __init__(
        self,
        *,
        operators: dict[str, str],
        key: bytes,
        stores: list[Any],
        broadcast: Any,
        zc: tuple[str, int] | None,
        stations: tuple[str, int] | None,
        station_names: list[str],
    ) -> None:
        import socket

        from railstop.link.release_link import WCC_ADDRESS, OperatorConsole, release_key, wcc_key
        from railstop.live.office import new_session

        self.operators, self.stores, self.broadcast = operators, stores, broadcast
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
        self.session = new_session()
        self.actions = iter(range(1, 1 << 62))

    async def _log(self, data: dict[str, Any]) -> None:
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

    async def _checked(self, operator: str, credential: str, action: dict[str, Any]) -> bool:
        from railstop.live.operators import check

        ok = await asyncio.to_thread(check, self.operators, operator, credential)
        if not ok:
            await self._log({**action, "result": "refused: unknown operator or wrong credential"})
        return ok

    async def release(self, request: Any) -> tuple[int, str]:
        action = {"operator": request.operator, "action": "zone-release", "train": request.train}
        if not await self._checked(request.operator, request.credential, action):
            return 403, "refused: unknown operator or wrong credential"
        assert self.zc is not None  # offered only with a zone controller link
        self.sock.sendto(self.consoles["zc"].release(request.train, time.time()), self.zc)
        await self._log({**action, "result": "sent to the zone controller"})
        return 200, f"release of train {request.train}'s zone sent to the zone controller"

    async def wcc(self, request: Any) -> tuple[int, str]:
        if request.station >= len(self.station_names):
            return 400, f"no station {request.station} on this line"
        name = self.station_names[request.station]
        manual = request.mode == "manual"
        what = f"WPCS {request.mode}" + (f", panel {request.panel}" if request.panel != "none" else "")
        action = {"operator": request.operator, "action": "wcc", "station": name, "command": what}
        if not await self._checked(request.operator, request.credential, action):
            return 403, "refused: unknown operator or wrong credential"
        assert self.stations is not None  # offered only with a stations link
        frame = self.consoles["wcc"].wcc(
            request.station,
            manual=manual,
            panel_open=request.panel == "open",
            panel_close=request.panel == "close",
            now_s=time.time(),
        )
        self.sock.sendto(frame, self.stations)
        await self._log({**action, "result": "sent to the station"})
        return 200, f"{name}: {what} sent to the station"


@office_app.command("add-operator")
def add_operator_cmd(
    file: Annotated[Path, typer.Argument(help="The operators file (created if missing).")],
    name: Annotated[str, typer.Argument(help="The operator's name.")],
    credential: Annotated[
        str, typer.Option(prompt=True, hide_input=True, confirmation_prompt=True, help="The credential.")
    ],
) -> None:
    """Add an operator (or change one's credential); only a salted PBKDF2 hash is written."""
    from railstop.live.operators import add_operator

    try:
        add_operator(file, name, credential)
    except RailstopError as exc:
        fail(str(exc))
    print(f"operator {name} written to {file}")


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
