"""The control-room page the management office serves (issue 17 item 3), FastAPI + server-sent events.

``GET /`` is one static page (``live/static/control_room.html``: plain HTML,
CSS and JavaScript, no build step). ``GET /events`` is a server-sent-event
stream: first the last reports the office has stored (so a page opened late
shows the line's recent history), then every report as the office stores it.
``GET /api/reports?after=ID`` gives the same reports as JSON.

The office hands each stored report to :meth:`Broadcast.publish` (from its
event loop); every open page has a bounded queue of its own, so a slow browser
loses its oldest events rather than holding the office up (it then reloads
the history on reconnecting).
"""

from __future__ import annotations

import asyncio
import json
from collections.abc import AsyncIterator, Callable
from importlib import resources
from typing import Any

from fastapi import FastAPI, Query
from fastapi.responses import HTMLResponse, StreamingResponse

HISTORY = 200  # reports a page gets when it connects
QUEUE = 1000  # reports a page may lag behind before its oldest are dropped


class Broadcast:
    """Fan-out of stored reports to the open pages (all on the office's event loop)."""

    def __init__(self) -> None:
        self._queues: set[asyncio.Queue[dict[str, Any]]] = set()
        self.dropped = 0

    def publish(self, event: dict[str, Any]) -> None:
        for q in self._queues:
            if q.full():
                q.get_nowait()
                self.dropped += 1
            q.put_nowait(event)

    def subscribe(self) -> asyncio.Queue[dict[str, Any]]:
        q: asyncio.Queue[dict[str, Any]] = asyncio.Queue(maxsize=QUEUE)
        self._queues.add(q)
        return q

    def unsubscribe(self, q: asyncio.Queue[dict[str, Any]]) -> None:
        self._queues.discard(q)

    @property
    def pages(self) -> int:
        return len(self._queues)


def _sse(event: dict[str, Any]) -> bytes:
    return f"id: {event['id']}\nevent: report\ndata: {json.dumps(event, separators=(',', ':'))}\n\n".encode()


def make_app(
    *,
    history: Callable[[int], list[dict[str, Any]]],
    broadcast: Broadcast,
    title: str,
    line: dict[str, Any],
) -> FastAPI:
    """The page's app. ``history(after_id)``: the stored reports after that id (oldest first);
    ``line``: what the page draws the line from (``length_m``, ``stations``: name, chainage_m)."""
    app = FastAPI(title=title, docs_url=None, redoc_url=None, openapi_url=None)
    page = resources.files("railstop.live").joinpath("static/control_room.html").read_text(encoding="utf-8")

    @app.get("/", response_class=HTMLResponse)
    async def index() -> str:
        return page.replace("{{title}}", title)

    @app.get("/api/line")
    async def line_data() -> dict[str, Any]:
        return line

    @app.get("/api/reports")
    async def reports(after: int = Query(0, ge=0)) -> list[dict[str, Any]]:
        return await asyncio.to_thread(history, after)

    @app.get("/events")
    async def events() -> StreamingResponse:
        q = broadcast.subscribe()

        async def stream() -> AsyncIterator[bytes]:
            try:
                past = await asyncio.to_thread(history, 0)
                last = 0
                for event in past[-HISTORY:]:
                    last = event["id"]
                    yield _sse(event)
                yield b"event: ready\ndata: {}\n\n"
                while True:
                    try:
                        event = await asyncio.wait_for(q.get(), timeout=10.0)
                    except TimeoutError:
                        yield b": keep-alive\n\n"
                        continue
                    if event["id"] > last:
                        last = event["id"]
                        yield _sse(event)
            finally:
                broadcast.unsubscribe(q)

        return StreamingResponse(
            stream(), media_type="text/event-stream", headers={"Cache-Control": "no-store"}
        )

    return app
