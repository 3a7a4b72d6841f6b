"""``railstop office serve``: the management office (SPEC §1 claims 7, 20) as a service."""

from __future__ import annotations

import asyncio
import json
import os
import signal
import sys
from typing import Annotated

import typer

from railstop.cli_common import fail
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
) -> None:
    """Receive, store and acknowledge the wayside's reports until stopped (SIGTERM, Ctrl-C)."""
    from railstop.link.udp import EpochClock
    from railstop.live.office import serve_office

    try:
        key = master_key(key_hex)
        ids = sender_ids(senders)
    except RailstopError as exc:
        fail(str(exc))

    async def main() -> dict[str, object]:
        stop = asyncio.Event()
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(sig, stop.set)

        def ready(addr: tuple[str, int]) -> None:
            print(f"office listening on {addr[0]}:{addr[1]} (database {db})", file=sys.stderr, flush=True)

        stats = await serve_office(
            db=db,
            local=(host, port),
            master_key=key,
            senders=ids,
            clock=EpochClock(0.0),
            stop=stop,
            on_ready=ready,
        )
        return {"stored": stats.stored, "duplicates": stats.duplicates, "rejected": stats.rejected}

    try:
        result = asyncio.run(main())
    except RailstopError as exc:
        fail(str(exc))
    print(json.dumps(result))
