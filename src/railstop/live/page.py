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
from collections.abc import AsyncIterator, Awaitable, Callable
from importlib import resources
from typing import Any, Literal

from fastapi import FastAPI, Query
from fastapi.responses import HTMLResponse, JSONResponse, StreamingResponse
from pydantic import BaseModel, Field

HISTORY = 200  # reports a page gets when it connects
QUEUE = 1000  # reports a page may lag behind before its oldest are dropped
REPORTS_PAGE = 10_000  # GET /api/reports: at most this many after the id asked for (the latest)


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


class ReleaseRequest(BaseModel):
    """SPEC §4 step 5: an operator releases a train's protection zone after visual confirmation."""

    train: int = Field(ge=0, le=4095)
    operator: str = Field(min_length=1, max_length=40)
    credential: str = Field(min_length=1, max_length=200)
    confirmed: bool  # the page's confirmation: the operator has seen the train


#: ``release(request) -> (HTTP status, message)``: checks the credential, logs, sends.
Release = Callable[[ReleaseRequest], Awaitable[tuple[int, str]]]


class WccRequest(BaseModel):
    """SPEC §5: the WCC switches a station's WPCS to manual (and presses the platform panel's open or
    close button) or back to automatic."""

    station: int = Field(ge=0, le=0xFFFF)
    mode: Literal["manual", "auto"]
    panel: Literal["none", "open", "close"] = "none"
    operator: str = Field(min_length=1, max_length=40)
    credential: str = Field(min_length=1, max_length=200)
    confirmed: bool  # the page's confirmation


Wcc = Callable[[WccRequest], Awaitable[tuple[int, str]]]


def make_app(
    *,
    history: Callable[[int, int], list[dict[str, Any]]],
    broadcast: Broadcast,
    title: str,
    line: dict[str, Any],
    release: Release | None = None,
    wcc: Wcc | None = None,
) -> FastAPI:
    """The page's app. ``history(after_id, n)``: the last ``n`` stored reports after that id (oldest
    first);
    ``line``: what the page draws the line from (``length_m``, ``stations``: name, chainage_m);
    ``release``: the manual zone release, ``wcc``: the WCC's commands to the stations' WPCS (None:
    the page offers none)."""
    app = FastAPI(title=title, docs_url=None, redoc_url=None, openapi_url=None)

    @app.post("/api/release")
    async def release_zone(request: ReleaseRequest) -> JSONResponse:
        if release is None:
            return JSONResponse({"message": "this office has no zone controller link"}, status_code=503)
        if not request.confirmed:
            return JSONResponse({"message": "the release needs the operator's confirmation"}, status_code=400)
        status, message = await release(request)
        return JSONResponse({"message": message}, status_code=status)

    @app.post("/api/wcc")
    async def wcc_command(request: WccRequest) -> JSONResponse:
        if wcc is None:
            return JSONResponse({"message": "this office has no link to the stations"}, status_code=503)
        if not request.confirmed:
            return JSONResponse({"message": "the command needs the operator's confirmation"}, status_code=400)
        if request.panel != "none" and request.mode != "manual":
            return JSONResponse({"message": "the panel's buttons act only in manual"}, status_code=400)
        status, message = await wcc(request)
        return JSONResponse({"message": message}, status_code=status)

    page = resources.files("railstop.live").joinpath("static/control_room.html").read_text(encoding="utf-8")

    @app.get("/", response_class=HTMLResponse)
    async def index() -> str:
        return (
            page.replace("{{title}}", title)
            .replace("{{release}}", "1" if release is not None else "0")
            .replace("{{wcc}}", "1" if wcc is not None else "0")
        )

    @app.get("/api/line")
    async def line_data() -> dict[str, Any]:
        return line

    @app.get("/api/reports")
    async def reports(after: int = Query(0, ge=0)) -> list[dict[str, Any]]:
        return await asyncio.to_thread(history, after, REPORTS_PAGE)

    @app.get("/events")
    async def events() -> StreamingResponse:
        q = broadcast.subscribe()

        async def stream() -> AsyncIterator[bytes]:
            try:
                past = await asyncio.to_thread(history, 0, HISTORY)
                last = 0
                for event in past:
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
