"""The control-room page the management office serves (SPEC §1 claims 7, 20), FastAPI + server-sent
events, and what guards it.

Static files only (``live/static``: plain HTML, CSS and JavaScript, no build
step, no template: the page builds its DOM with ``textContent`` from JSON).
Nothing but the login page and its static files is served without a session:

* ``POST /api/login`` checks the operator and credential against the
  operators file's PBKDF2 hashes and sets a random session cookie
  (``HttpOnly``, ``SameSite=Strict``, ``Secure`` over TLS), which ends after
  :attr:`PageLimits.session_max_s` or :attr:`PageLimits.session_idle_s`
  without a request; ``POST /api/logout`` ends it.
* ``GET /`` (the page), ``GET /api/line``, ``GET /api/reports?after=ID``, ``GET /api/stops``,
  ``GET /events`` (a server-sent-event stream: the last reports stored, then
  each as it is stored) need a session.
* Every command (``POST /api/release``: SPEC §4 step 5; ``POST /api/wcc``:
  SPEC §5) needs a session, a fresh one-time token (``POST /api/token``)
  and the operator's credential again; a token used twice is refused and
  logged, so a captured request cannot be replayed.
* Failed logins lock the operator and the client address out for a time
  that doubles with every further failure (:class:`Guard`).
* :class:`Shield` (ASGI) refuses unknown ``Host`` and foreign ``Origin``
  headers, bodies over :attr:`PageLimits.body_max_bytes` (413, unread) or
  slower than :attr:`PageLimits.request_timeout_s` (408) and adds a strict
  Content-Security-Policy; :func:`guarded_protocol` closes connections
  beyond a limit and clients that do not finish a request's headers in time.

DESIGN rule 10: anything doubtful (no session, an expired one, a used token,
a foreign origin) ends in "refused" and changes nothing.
"""

from __future__ import annotations

import asyncio
import hashlib
import json
import secrets
import time
from collections.abc import AsyncIterator, Awaitable, Callable, Iterable, Mapping
from dataclasses import dataclass, field
from importlib import resources
from typing import Any, Literal

import uvicorn
from fastapi import FastAPI, HTTPException, Query, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse, RedirectResponse, Response
from pydantic import BaseModel, Field
from starlette.types import ASGIApp, Message, Receive, Scope, Send
from uvicorn.protocols.http.h11_impl import H11Protocol

from railstop.errors import RailstopError
from railstop.live.operators import Operator, check

HISTORY = 200  # reports a page gets when it connects
QUEUE = 1000  # reports a page may lag behind before its oldest are dropped
REPORTS_PAGE = 10_000  # GET /api/reports: at most this many after the id asked for (the latest)
COOKIE = "railstop_session"
VIEW_ONLY_ID = 0  # an operator id that may view but never command (the office's generated login)

# default-src 'self' and nothing inline: a name that slipped through as markup could not run.
CSP = (
    "default-src 'self'; script-src 'self'; style-src 'self'; img-src 'self' data:; connect-src 'self'; "
    "font-src 'self'; object-src 'none'; base-uri 'none'; form-action 'self'; frame-ancestors 'none'"
)
_HEADERS = (
    (b"content-security-policy", CSP.encode()),
    (b"x-content-type-options", b"nosniff"),
    (b"referrer-policy", b"no-referrer"),
    (b"x-frame-options", b"DENY"),
    (b"cross-origin-opener-policy", b"same-origin"),
    (b"cross-origin-resource-policy", b"same-origin"),
    (b"permissions-policy", b"camera=(), microphone=(), geolocation=()"),
    (b"cache-control", b"no-store"),
)
_STATIC = {  # served name -> (package file, content type)
    "control_room.js": ("control_room.js", "text/javascript; charset=utf-8"),
    "control_room.css": ("control_room.css", "text/css; charset=utf-8"),
    "login.js": ("login.js", "text/javascript; charset=utf-8"),
}


class PageError(RailstopError):
    """The page cannot be set up as asked (an allowed host that is no host name)."""


@dataclass(frozen=True, slots=True, kw_only=True)
class PageLimits:
    """The page's limits. [interpretation] The figures are ours (no SPEC section gives any): a shift
    is at most 12 h, a control-room console left alone for 15 min logs out, a command's token lives
    2 min (the time to confirm a dialog), three wrong credentials are typing errors, the fourth
    locks for 2 s and every further one doubles it up to 15 min."""

    session_max_s: float = 12 * 3600.0
    session_idle_s: float = 15 * 60.0
    sessions_max: int = 64  # the least recently used is dropped beyond this
    token_ttl_s: float = 120.0
    tokens_per_session: int = 16  # the oldest is dropped beyond this
    lockout_free: int = 3  # failures before the back-off starts
    lockout_base_s: float = 2.0
    lockout_max_s: float = 900.0
    lockout_forget_s: float = 3600.0  # a failure this long ago is forgotten
    lockout_table: int = 10_000  # names and addresses remembered at most
    hash_checks: int = 2  # PBKDF2 checks at the same time (each costs a CPU for ~0.2 s)
    body_max_bytes: int = 4096  # the largest command is ~300 bytes
    request_timeout_s: float = 10.0  # a request's headers, and its body, must arrive within this
    keep_alive_s: int = 5
    max_connections: int = 200  # far below the 1024 descriptors a process gets by default
    max_connections_per_client: int = 32
    accept_batch: int = 256  # the listen backlog: connections accepted at once (200 + 256 < 1024)
    max_streams: int = 16
    max_streams_per_session: int = 4
    stream_check_s: float = 5.0  # an open stream checks its session this often (and keeps alive)


# ---------------------------------------------------------------------------------------- allowed hosts


def _split_host(value: str) -> tuple[str, int | None]:
    """``name``, ``name:port``, ``[v6]`` or ``[v6]:port`` -> (lower-case name, port or None)."""
    value = value.strip().lower()
    if value.startswith("["):
        name, _, rest = value[1:].partition("]")
        port = rest[1:] if rest.startswith(":") else None
        if rest and port is None:
            raise ValueError(value)
    else:
        name, sep, port_text = value.rpartition(":")
        if not sep:
            name, port = value, None
        else:
            port = port_text
    if not name or any(c in name for c in "/@?#\\ ") or (port is not None and not port.isdigit()):
        raise ValueError(value)
    number = None if port is None else int(port)
    if number is not None and not 0 < number < 65536:
        raise ValueError(value)
    return name, number


class AllowedHosts:
    """The ``Host`` names (and ports) the page answers to: those given, or the address it is bound
    to (a DNS name an attacker controls may point at the office: a page of his would then be "same
    origin", unless the office refuses his name)."""

    def __init__(self, names: Iterable[str] = ()) -> None:
        self.given: list[tuple[str, int | None]] = []
        for n in names:
            try:
                self.given.append(_split_host(n))
            except ValueError:
                raise PageError(f"--allowed-hosts: a host name or HOST:PORT expected (got {n!r})") from None
        self.allowed: set[tuple[str, int]] = set()

    def bind(self, host: str, port: int) -> None:
        """The page is bound to ``host:port``: resolve the defaults. A wildcard address is no name
        a browser could use, so it needs names given."""
        names = [(n, p if p is not None else port) for n, p in self.given]
        if not names:
            if host in ("0.0.0.0", "::", ""):
                raise PageError("--allowed-hosts: the page listens on every address: name its host names")
            names = [(host.lower(), port)]
            if host in ("127.0.0.1", "::1"):
                names.append(("localhost", port))
        self.allowed = set(names)

    def allows(self, value: str | None, default_port: int) -> bool:
        if not value:
            return False
        try:
            name, port = _split_host(value)
        except ValueError:
            return False
        return (name, default_port if port is None else port) in self.allowed

    def allows_origin(self, origin: str | None, scheme: str) -> bool:
        if not origin:
            return False
        prefix = f"{scheme}://"
        if not origin.lower().startswith(prefix):
            return False
        return self.allows(origin[len(prefix) :], 443 if scheme == "https" else 80)


# ---------------------------------------------------------------------------------------- the guard


@dataclass(slots=True)
class Session:
    user: str
    operator_id: int
    created_s: float
    seen_s: float
    tokens: dict[str, float] = field(default_factory=dict)  # token -> when issued, oldest first
    streams: int = 0


@dataclass(slots=True)
class _Failures:
    count: int
    last_s: float
    until_s: float


class Guard:
    """Sessions, one-time command tokens and the login lockout: a unit without I/O (the time is an
    argument). Session ids are kept only as their SHA-256 (a dump of the table opens no session)."""

    def __init__(self, limits: PageLimits) -> None:
        self.limits = limits
        self._sessions: dict[str, Session] = {}
        self._fails: dict[tuple[str, str], _Failures] = {}
        self.replays = 0

    @staticmethod
    def _key(sid: str) -> str:
        return hashlib.sha256(sid.encode()).hexdigest()

    # -- sessions

    def open(self, user: str, operator_id: int, now_s: float) -> str:
        """A new session (never one the client named: no fixation); its id for the cookie."""
        self._expire(now_s)
        while len(self._sessions) >= self.limits.sessions_max:
            oldest = min(self._sessions, key=lambda k: self._sessions[k].seen_s)
            del self._sessions[oldest]
        sid = secrets.token_urlsafe(32)
        self._sessions[self._key(sid)] = Session(
            user=user, operator_id=operator_id, created_s=now_s, seen_s=now_s
        )
        return sid

    def get(self, sid: str | None, now_s: float, *, touch: bool = True) -> Session | None:
        """The live session of this id (``touch``: the user is active), or None: unknown, ended,
        too old or idle too long (then forgotten)."""
        if not sid or len(sid) > 128:
            return None
        key = self._key(sid)
        s = self._sessions.get(key)
        if s is None:
            return None
        if now_s - s.created_s >= self.limits.session_max_s or now_s - s.seen_s >= self.limits.session_idle_s:
            del self._sessions[key]
            return None
        if touch:
            s.seen_s = now_s
        return s

    def close(self, sid: str | None) -> Session | None:
        return self._sessions.pop(self._key(sid), None) if sid else None

    def _expire(self, now_s: float) -> None:
        for key, s in list(self._sessions.items()):
            if (
                now_s - s.created_s >= self.limits.session_max_s
                or now_s - s.seen_s >= self.limits.session_idle_s
            ):
                del self._sessions[key]

    @property
    def sessions(self) -> int:
        return len(self._sessions)

    # -- one-time command tokens

    def issue(self, session: Session, now_s: float) -> str:
        for t, issued in list(session.tokens.items()):
            if now_s - issued > self.limits.token_ttl_s:
                del session.tokens[t]
        while len(session.tokens) >= self.limits.tokens_per_session:
            del session.tokens[next(iter(session.tokens))]
        token = secrets.token_urlsafe(24)
        session.tokens[token] = now_s
        return token

    def redeem(self, session: Session, token: str, now_s: float) -> bool:
        """Whether ``token`` was issued to this session, is fresh and unused; it is used now."""
        issued = session.tokens.pop(token, None)
        ok = issued is not None and now_s - issued <= self.limits.token_ttl_s
        if not ok:
            self.replays += 1
        return ok

    # -- lockout

    def attempt(self, user: str, address: str, now_s: float) -> float:
        """Before a credential is checked: the seconds the user or the address must still wait (then
        nothing is checked), or 0.0: go on. The attempt counts as a failure until
        :meth:`succeeded` says otherwise, so that attempts sent at the same time are counted too."""
        keys = (("user", user), ("address", address))
        wait = max(self._wait(k, now_s) for k in keys)
        if wait > 0.0:
            return wait
        for k in keys:
            self._fail(k, now_s)
        return 0.0

    def succeeded(self, user: str, address: str) -> None:
        self._fails.pop(("user", user), None)
        self._fails.pop(("address", address), None)

    def locked_for_s(self, user: str, address: str, now_s: float) -> float:
        return max(self._wait(("user", user), now_s), self._wait(("address", address), now_s))

    def _wait(self, key: tuple[str, str], now_s: float) -> float:
        f = self._fails.get(key)
        return 0.0 if f is None else max(0.0, f.until_s - now_s)

    def _fail(self, key: tuple[str, str], now_s: float) -> None:
        lim = self.limits
        f = self._fails.get(key)
        if f is None or now_s - f.last_s > lim.lockout_forget_s:
            f = _Failures(count=0, last_s=now_s, until_s=now_s)
        f.count += 1
        f.last_s = now_s
        extra = f.count - lim.lockout_free
        if extra > 0:
            f.until_s = now_s + min(lim.lockout_base_s * 2.0 ** min(extra - 1, 60), lim.lockout_max_s)
        self._fails[key] = f
        if len(self._fails) > lim.lockout_table:
            # Forget the entries that no longer lock, then (a flood of names) the oldest.
            for k, v in list(self._fails.items()):
                if v.until_s <= now_s and now_s - v.last_s > lim.lockout_base_s:
                    del self._fails[k]
            while len(self._fails) > lim.lockout_table:
                del self._fails[min(self._fails, key=lambda k: self._fails[k].last_s)]


# ---------------------------------------------------------------------------------------- the page


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


class LoginRequest(BaseModel):
    user: str = Field(min_length=1, max_length=40)
    secret: str = Field(min_length=1, max_length=200)


class ReleaseRequest(BaseModel):
    """SPEC §4 step 5: an operator releases a train's protection zone after visual confirmation."""

    train: int = Field(ge=0, le=4095)
    credential: str = Field(min_length=1, max_length=200)  # the logged-in operator's, again
    confirmed: bool  # the page's confirmation: the operator has seen the train
    token: str = Field(min_length=1, max_length=64)  # one-time (POST /api/token)


class WccRequest(BaseModel):
    """SPEC §5: the WCC switches a station's WPCS to manual (and presses the platform panel's open or
    close button) or back to automatic."""

    station: int = Field(ge=0, le=0xFFFF)
    mode: Literal["manual", "auto"]
    panel: Literal["none", "open", "close"] = "none"
    credential: str = Field(min_length=1, max_length=200)
    confirmed: bool  # the page's confirmation
    token: str = Field(min_length=1, max_length=64)


@dataclass(frozen=True, slots=True, kw_only=True)
class ReleaseOrder:
    """A release the page has authenticated: the train and the logged-in operator."""

    train: int
    operator: str
    operator_id: int


@dataclass(frozen=True, slots=True, kw_only=True)
class WccOrder:
    """A WCC command the page has authenticated."""

    station: int
    mode: str
    panel: str
    operator: str
    operator_id: int


#: ``release(order) -> (HTTP status, message)``: logs and sends the telegram.
Release = Callable[[ReleaseOrder], Awaitable[tuple[int, str]]]
Wcc = Callable[[WccOrder], Awaitable[tuple[int, str]]]
#: ``audit(data)``: records an operator action (a login, a refusal) in the office's log.
Audit = Callable[[dict[str, Any]], Awaitable[None]]


class _EventStream(Response):
    """A server-sent-event response whose ``cleanup`` runs however it ends (the client gone before
    the first byte too), so that the count of open streams never leaks."""

    def __init__(self, body: AsyncIterator[bytes], cleanup: Callable[[], None]) -> None:
        # As StreamingResponse: no body attribute, so no Content-Length.
        self.status_code, self.media_type, self.background = 200, "text/event-stream", None
        self.init_headers({"Cache-Control": "no-store"})
        self.body_iterator, self.cleanup = body, cleanup

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        async def pump() -> None:
            await send({"type": "http.response.start", "status": 200, "headers": self.raw_headers})
            async for chunk in self.body_iterator:
                await send({"type": "http.response.body", "body": chunk, "more_body": True})
            await send({"type": "http.response.body", "body": b"", "more_body": False})

        async def gone() -> None:
            while (await receive())["type"] != "http.disconnect":
                pass

        tasks = [asyncio.ensure_future(pump()), asyncio.ensure_future(gone())]
        try:
            await asyncio.wait(tasks, return_when=asyncio.FIRST_COMPLETED)
        finally:
            for t in tasks:
                t.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)
            self.cleanup()


@dataclass(slots=True, kw_only=True)
class _Office:
    """What the page's routes share: the stored reports, the live events, who may log in, the
    sessions (``guard``), the command links and the audit record."""

    history: Callable[[int, int], list[dict[str, Any]]]
    broadcast: Broadcast
    title: str
    line: dict[str, Any]
    operators: Mapping[str, Operator]
    release: Release | None
    wcc: Wcc | None
    audit: Audit | None
    lim: PageLimits
    guard: Guard
    hash_slots: asyncio.Semaphore
    clock: Callable[[], float]
    stops: Callable[[], list[dict[str, Any]]] | None = None

    async def record(self, data: dict[str, Any]) -> None:
        if self.audit is not None:
            await self.audit(data)

    @staticmethod
    def client(request: Request) -> str:
        return request.client.host if request.client else "?"

    def session(self, request: Request, *, touch: bool = True) -> tuple[str, Session]:
        sid = request.cookies.get(COOKIE)
        s = self.guard.get(sid, self.clock(), touch=touch)
        if sid is None or s is None:
            raise HTTPException(401, "log in first (or again: the session has ended)")
        return sid, s

    async def checked(self, user: str, secret: str, address: str, action: dict[str, Any]) -> Operator:
        """The operator, when ``secret`` is ``user``'s credential; else a 429 (locked out, nothing
        checked) or a 403 (recorded)."""
        guard, clock = self.guard, self.clock
        wait, ok = guard.locked_for_s(user, address, clock()), False
        if wait <= 0.0:
            async with self.hash_slots:
                wait = guard.attempt(user, address, clock())
                ok = wait <= 0.0 and await asyncio.to_thread(check, dict(self.operators), user, secret)
        if wait > 0.0:
            raise HTTPException(
                429,
                f"refused: too many failed attempts: try again in {wait:.0f} s",
                headers={"Retry-After": str(max(1, round(wait)))},
            )
        if not ok:
            await self.record({**action, "result": "refused: unknown operator or wrong credential"})
            raise HTTPException(403, "refused: unknown operator or wrong credential")
        guard.succeeded(user, address)
        return self.operators[user]

    async def command(
        self, request: Request, token: str, credential: str, confirmed: bool, action: dict[str, Any]
    ) -> tuple[Operator, Session]:
        """A command's checks: a session, a fresh one-time token, the confirmation, the credential
        again. Returns the operator and the session."""
        _, s = self.session(request)
        address = self.client(request)
        action = {**action, "operator": s.user, "operator_id": s.operator_id, "address": address}
        if not self.guard.redeem(s, token, self.clock()):
            # A replayed (or forged, or stale) request: refused and recorded.
            await self.record({**action, "result": "refused: replayed or unknown command token"})
            raise HTTPException(403, "refused: replayed or unknown command token (reload the page)")
        if s.operator_id == VIEW_ONLY_ID:
            raise HTTPException(403, "refused: this login may only view")
        if not confirmed:
            raise HTTPException(400, "the command needs the operator's confirmation")
        return await self.checked(s.user, credential, address, action), s


def make_app(
    *,
    history: Callable[[int, int], list[dict[str, Any]]],
    broadcast: Broadcast,
    title: str,
    line: dict[str, Any],
    operators: Mapping[str, Operator],
    hosts: AllowedHosts,
    release: Release | None = None,
    wcc: Wcc | None = None,
    audit: Audit | None = None,
    limits: PageLimits | None = None,
    clock: Callable[[], float] = time.monotonic,
    stops: Callable[[], list[dict[str, Any]]] | None = None,
) -> Shield:
    """The page's app behind its :class:`Shield`. ``history(after_id, n)``: the last ``n`` stored
    reports after that id (oldest first); ``line``: what the page draws the line from
    (``length_m``, ``stations``: name, chainage_m); ``operators``: who may log in; ``release``: the
    manual zone release, ``wcc``: the WCC's commands to the stations' WPCS (None: the page offers
    none); ``audit``: where logins, refusals and replays are recorded; ``stops()``: every
    stop-result of the record, oldest first (the stop chart covers the whole run, not only the
    reports of the stream's history)."""
    lim = limits or PageLimits()
    office = _Office(
        history=history, broadcast=broadcast, title=title, line=line, operators=operators,
        release=release, wcc=wcc, audit=audit, lim=lim, guard=Guard(lim),
        hash_slots=asyncio.Semaphore(lim.hash_checks), clock=clock, stops=stops,
    )  # fmt: skip
    app = FastAPI(title=title, docs_url=None, redoc_url=None, openapi_url=None)

    @app.exception_handler(HTTPException)
    async def http_error(_request: Request, exc: HTTPException) -> JSONResponse:
        return JSONResponse({"message": exc.detail}, status_code=exc.status_code, headers=exc.headers)

    @app.exception_handler(RequestValidationError)
    async def bad_request(_request: Request, exc: RequestValidationError) -> JSONResponse:
        # Only the fields' names: the input (a credential) is never echoed back.
        where = sorted({".".join(str(p) for p in e.get("loc", ())[1:]) for e in exc.errors()})
        return JSONResponse({"message": f"invalid request: {', '.join(where) or 'body'}"}, status_code=422)

    _login_routes(app, office)
    _view_routes(app, office)
    _command_routes(app, office)
    shield = Shield(app, hosts=hosts, limits=lim)
    shield.guard = office.guard
    return shield


def _login_routes(app: FastAPI, office: _Office) -> None:
    """The login page and its API, the static files, the session and the command tokens."""
    guard, clock, lim = office.guard, office.clock, office.lim
    static = resources.files("railstop.live").joinpath("static")
    files = {name: (static.joinpath(f).read_bytes(), ctype) for name, (f, ctype) in _STATIC.items()}
    login_page = static.joinpath("login.html").read_bytes()

    @app.get("/login")
    async def login_form() -> Response:
        return Response(login_page, media_type="text/html; charset=utf-8")

    @app.get("/static/{name}")
    async def static_file(name: str) -> Response:
        if name not in files:
            raise HTTPException(404, "no such file")
        body, ctype = files[name]
        return Response(body, media_type=ctype)

    @app.post("/api/login")
    async def login(body: LoginRequest, request: Request) -> JSONResponse:
        address = office.client(request)
        op = await office.checked(
            body.user, body.secret, address, {"operator": body.user, "action": "login", "address": address}
        )
        sid = guard.open(body.user, op.id, clock())
        await office.record(
            {"operator": body.user, "action": "login", "address": address, "result": "logged in"}
        )
        out = JSONResponse({"user": body.user, "operator_id": op.id})
        out.set_cookie(
            COOKIE,
            sid,
            max_age=int(lim.session_max_s),
            path="/",
            httponly=True,
            samesite="strict",
            secure=request.url.scheme == "https",
        )
        return out

    @app.post("/api/logout")
    async def logout(request: Request) -> JSONResponse:
        s = guard.close(request.cookies.get(COOKIE))
        if s is not None:
            address = office.client(request)
            await office.record(
                {"operator": s.user, "action": "logout", "address": address, "result": "logged out"}
            )
        out = JSONResponse({"message": "logged out"})
        out.delete_cookie(
            COOKIE, path="/", httponly=True, samesite="strict", secure=request.url.scheme == "https"
        )
        return out

    @app.get("/api/session")
    async def session_info(request: Request) -> dict[str, Any]:
        _, s = office.session(request)
        commands = s.operator_id != VIEW_ONLY_ID
        return {
            "user": s.user,
            "operator_id": s.operator_id,
            "title": office.title,
            "release": office.release is not None and commands,
            "wcc": office.wcc is not None and commands,
            "idle_s": lim.session_idle_s,
        }

    @app.post("/api/token")
    async def token(request: Request) -> dict[str, str]:
        _, s = office.session(request)
        return {"token": guard.issue(s, clock())}


def _view_routes(app: FastAPI, office: _Office) -> None:
    """The page, the line, the stored reports and the event stream (a session each)."""
    guard, clock, lim, broadcast, history = (
        office.guard,
        office.clock,
        office.lim,
        office.broadcast,
        office.history,
    )
    page = resources.files("railstop.live").joinpath("static").joinpath("control_room.html").read_bytes()

    @app.get("/")
    async def index(request: Request) -> Response:
        if guard.get(request.cookies.get(COOKIE), clock()) is None:
            return RedirectResponse("/login", status_code=303)
        return Response(page, media_type="text/html; charset=utf-8")

    @app.get("/api/line")
    async def line_data(request: Request) -> dict[str, Any]:
        office.session(request)
        return office.line

    @app.get("/api/stops")
    async def all_stops(request: Request) -> list[dict[str, Any]]:
        office.session(request)
        return [] if office.stops is None else await asyncio.to_thread(office.stops)

    @app.get("/api/reports")
    async def reports(request: Request, after: int = Query(0, ge=0)) -> list[dict[str, Any]]:
        office.session(request)
        return await asyncio.to_thread(history, after, REPORTS_PAGE)

    @app.get("/events")
    async def events(request: Request) -> Response:
        sid, s = office.session(request)
        if broadcast.pages >= lim.max_streams or s.streams >= lim.max_streams_per_session:
            raise HTTPException(503, "too many open event streams")
        q = broadcast.subscribe()
        s.streams += 1

        def cleanup() -> None:
            broadcast.unsubscribe(q)
            s.streams -= 1

        async def stream() -> AsyncIterator[bytes]:
            past = await asyncio.to_thread(history, 0, HISTORY)
            last = 0
            for event in past:
                last = event["id"]
                yield _sse(event)
            yield b"event: ready\ndata: {}\n\n"
            # The stream lasts as long as its session: a logout or a time-out ends it.
            while guard.get(sid, clock(), touch=False) is not None:
                try:
                    event = await asyncio.wait_for(q.get(), timeout=lim.stream_check_s)
                except TimeoutError:
                    yield b": keep-alive\n\n"
                    continue
                if event["id"] > last:
                    last = event["id"]
                    yield _sse(event)
            yield b"event: ended\ndata: {}\n\n"

        return _EventStream(stream(), cleanup)


def _command_routes(app: FastAPI, office: _Office) -> None:
    """The commands: the manual zone release and the WCC's orders to the stations' WPCS."""

    @app.post("/api/release")
    async def release_zone(body: ReleaseRequest, request: Request) -> JSONResponse:
        if office.release is None:
            return JSONResponse({"message": "this office has no zone controller link"}, status_code=503)
        action = {"action": "zone-release", "train": body.train}
        op, s = await office.command(request, body.token, body.credential, body.confirmed, action)
        status, message = await office.release(
            ReleaseOrder(train=body.train, operator=s.user, operator_id=op.id)
        )
        return JSONResponse({"message": message}, status_code=status)

    @app.post("/api/wcc")
    async def wcc_command(body: WccRequest, request: Request) -> JSONResponse:
        if office.wcc is None:
            return JSONResponse({"message": "this office has no link to the stations"}, status_code=503)
        if body.panel != "none" and body.mode != "manual":
            return JSONResponse({"message": "the panel's buttons act only in manual"}, status_code=400)
        what = f"WPCS {body.mode}" + (f", panel {body.panel}" if body.panel != "none" else "")
        action = {"action": "wcc", "station": body.station, "command": what}
        op, s = await office.command(request, body.token, body.credential, body.confirmed, action)
        order = WccOrder(
            station=body.station, mode=body.mode, panel=body.panel, operator=s.user, operator_id=op.id
        )
        status, message = await office.wcc(order)
        return JSONResponse({"message": message}, status_code=status)


# ---------------------------------------------------------------------------------------- the shield


async def _reply(send: Send, status: int, message: str, extra: Iterable[tuple[bytes, bytes]] = ()) -> None:
    body = json.dumps({"message": message}).encode()
    headers = [
        (b"content-type", b"application/json"),
        (b"content-length", str(len(body)).encode()),
        (b"connection", b"close"),  # nothing more is read from this client on this connection
        *extra,
    ]
    await send({"type": "http.response.start", "status": status, "headers": headers})
    await send({"type": "http.response.body", "body": body, "more_body": False})


class Shield:
    """ASGI middleware in front of the page: ``Host`` and ``Origin`` checks, the body's size and time
    limits, the security headers on every response."""

    guard: Guard | None = None

    def __init__(self, app: ASGIApp, *, hosts: AllowedHosts, limits: PageLimits) -> None:
        self.app, self.hosts, self.limits = app, hosts, limits

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            return  # no lifespan, no websockets: nothing to serve
        scheme = scope.get("scheme", "http")
        extra = list(_HEADERS)
        if scheme == "https":
            extra.append((b"strict-transport-security", b"max-age=31536000"))

        async def secured(message: Message) -> None:
            if message["type"] == "http.response.start":
                have = {k.lower() for k, _ in message.get("headers", [])}
                message = {
                    **message,
                    "headers": [*message.get("headers", []), *(h for h in extra if h[0] not in have)],
                }
            await send(message)

        headers: dict[bytes, bytes] = {}
        for k, v in scope.get("headers", []):
            if k in headers and k in (b"host", b"origin", b"content-length", b"cookie"):
                return await _reply(secured, 400, "a header given twice")
            headers[k] = v
        method = scope.get("method", "GET")
        path = scope.get("path", "/")
        host = headers.get(b"host", b"").decode("latin-1")
        if not self.hosts.allows(host, 443 if scheme == "https" else 80):
            return await _reply(secured, 421, "unknown host")
        if method not in ("GET", "POST"):
            return await _reply(secured, 405, "only GET and POST")
        origin = headers.get(b"origin", b"").decode("latin-1") or None
        site = headers.get(b"sec-fetch-site", b"").decode("latin-1") or None
        data_path = path.startswith("/api/") or path == "/events"
        # A command (every POST) comes only from the page itself: its Origin must be the office's.
        if method == "POST" and not self.hosts.allows_origin(origin, scheme):
            return await _reply(secured, 403, "refused: foreign or missing Origin")
        if origin is not None and not self.hosts.allows_origin(origin, scheme):
            return await _reply(secured, 403, "refused: foreign Origin")
        if (method == "POST" or data_path) and site not in (None, "same-origin", "none"):
            return await _reply(secured, 403, "refused: a cross-site request")
        length_text = headers.get(b"content-length")
        chunked = b"chunked" in headers.get(b"transfer-encoding", b"").lower()
        if length_text is not None:
            if not length_text.isdigit():
                return await _reply(secured, 400, "bad Content-Length")
            # Refused before a byte of the body is read.
            if int(length_text) > self.limits.body_max_bytes:
                return await _reply(secured, 413, f"a body of at most {self.limits.body_max_bytes} bytes")
        if method != "POST":
            if chunked or (length_text is not None and int(length_text) > 0):
                return await _reply(secured, 413, "a GET has no body")
            return await self.app(scope, receive, secured)
        body = await self._body(receive)
        if isinstance(body, int):
            if body:
                await _reply(
                    secured, body, "the body is too large" if body == 413 else "the body came too slowly"
                )
            return None
        sent = False

        async def replay() -> Message:
            nonlocal sent
            if not sent:
                sent = True
                return {"type": "http.request", "body": body, "more_body": False}
            return await receive()

        return await self.app(scope, replay, secured)

    async def _body(self, receive: Receive) -> bytes | int:
        """The whole body, or 413 (too large: reading stops there), 408 (too slow), 0 (gone)."""
        loop = asyncio.get_running_loop()
        deadline = loop.time() + self.limits.request_timeout_s
        body = bytearray()
        while True:
            try:
                message = await asyncio.wait_for(receive(), max(0.0, deadline - loop.time()))
            except TimeoutError:
                return 408
            if message["type"] == "http.disconnect":
                return 0
            body += message.get("body", b"")
            if len(body) > self.limits.body_max_bytes:
                return 413
            if not message.get("more_body", False):
                return bytes(body)


# ---------------------------------------------------------------------------------------- the server


def guarded_protocol(limits: PageLimits) -> type[H11Protocol]:
    """uvicorn's HTTP/1.1 protocol with two more limits: a connection beyond
    ``max_connections`` (or ``max_connections_per_client`` from one address) is closed at once, and
    a client must send a request's headers within ``request_timeout_s`` of connecting or of the
    previous response (uvicorn times out only idle keep-alive connections): idle and slow clients
    cannot hold the office's descriptors."""

    class GuardedH11(H11Protocol):
        _timer: asyncio.TimerHandle | None = None
        _timed: object = None
        refused = 0

        def connection_made(self, transport: Any) -> None:
            super().connection_made(transport)
            host = self.client[0] if self.client else None
            mine = sum(1 for c in self.connections if (getattr(c, "client", None) or ("",))[0] == host)
            if len(self.connections) > limits.max_connections or mine > limits.max_connections_per_client:
                GuardedH11.refused += 1
                transport.abort()
                return
            self._arm()

        def _arm(self) -> None:
            self._disarm()
            self._timer = self.loop.call_later(limits.request_timeout_s, self._too_slow)

        def _disarm(self) -> None:
            if self._timer is not None:
                self._timer.cancel()
                self._timer = None

        def _too_slow(self) -> None:
            self._timer = None
            if not self.transport.is_closing():
                self.transport.abort()

        def handle_events(self) -> None:
            super().handle_events()
            if self.cycle is not None and self.cycle is not self._timed:
                self._timed = self.cycle  # a request's headers are complete: the app's time now
                self._disarm()

        def on_response_complete(self) -> None:
            super().on_response_complete()
            if not self.transport.is_closing():
                self._arm()

        def connection_lost(self, exc: Exception | None) -> None:
            self._disarm()
            super().connection_lost(exc)

    return GuardedH11


def page_config(
    app: Shield,
    *,
    host: str,
    port: int,
    limits: PageLimits,
    tls_cert: str | None = None,
    tls_key: str | None = None,
) -> Any:
    """The uvicorn configuration the page is served with (the office's and the tests' alike)."""
    return uvicorn.Config(
        app,
        host=host,
        port=port,
        http=guarded_protocol(limits),
        ws="none",
        lifespan="off",
        log_level="warning",
        proxy_headers=False,  # the client's address is the socket's (the lockout counts by it)
        server_header=False,
        limit_concurrency=limits.max_connections + 1,
        timeout_keep_alive=limits.keep_alive_s,
        timeout_graceful_shutdown=3,
        h11_max_incomplete_event_size=8192,  # the request line and headers
        # asyncio accepts up to ``backlog`` connections before any of them is set up (and so before
        # the protocol can close those over the limit): a small batch keeps the descriptors the
        # office holds at any moment far below its limit.
        backlog=limits.accept_batch,
        ssl_certfile=tls_cert,
        ssl_keyfile=tls_key,
    )
