"""``railstop office serve``: the management office (SPEC §1 claims 7, 20) as a service."""

from __future__ import annotations

import asyncio
import json
import os
import signal
import sys
from typing import Annotated, Any

import typer

from railstop.cli_common import LineOpt, fail
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
    line: LineOpt = None,
) -> None:
    """Receive, store and acknowledge the wayside's reports until stopped (SIGTERM, Ctrl-C); with
    --http-port, serve the control-room page too."""
    from railstop.config import load_line
    from railstop.link.udp import EpochClock
    from railstop.live.office import serve_office

    try:
        key = master_key(key_hex)
        ids = sender_ids(senders)
        ln = load_line(line)
    except RailstopError as exc:
        fail(str(exc))
    stations = [{"name": st.name, "chainage_m": st.stop_point_m} for st in ln.stations]
    length = ln.line.length_m or max(st.stop_point_m for st in ln.stations) + 500.0
    line_data = {"name": ln.line.name, "length_m": length, "stations": stations}

    async def main() -> dict[str, object]:
        stop = asyncio.Event()
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(sig, stop.set)

        def ready(addr: tuple[str, int]) -> None:
            print(f"office listening on {addr[0]}:{addr[1]} (database {db})", file=sys.stderr, flush=True)

        page = None if http_port is None else await _start_page(host, http_port, ln.line.name, line_data)
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

    try:
        result = asyncio.run(main())
    except RailstopError as exc:
        fail(str(exc))
    print(json.dumps(result))


class _Page:
    """The control-room page running beside the office (uvicorn in the office's event loop)."""

    def __init__(self, server: Any, task: asyncio.Task[None], broadcast: Any, stores: list[Any]) -> None:
        self.server, self.task, self.broadcast, self.stores = server, task, broadcast, stores

    async def close(self) -> None:
        self.server.should_exit = True
        await self.task


async def _start_page(host: str, port: int, name: str, line_data: dict[str, Any]) -> _Page:
    import uvicorn

    from railstop.live.page import Broadcast, make_app

    broadcast = Broadcast()
    stores: list[Any] = []  # the office's open store, once it is open

    def history(after: int) -> list[dict[str, Any]]:
        return stores[0].office_reports(after_id=after) if stores else []

    app = make_app(
        history=history, broadcast=broadcast, title=f"railstop control room: {name}", line=line_data
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
