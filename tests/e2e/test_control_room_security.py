"""The control room's page under attack: raw HTTP on real sockets against ``railstop office serve``.

Each attack found on the page is replayed here against the real office
process (loopback, real UDP to a zone controller's socket the test holds):
no login, a replayed release, guessing credentials, a foreign Host or Origin,
markup in a name, a huge body, idle and slow clients, 1,100 connections
under the default 1,024-descriptor limit, credentials on the command line, a
readable operators file, the operator's id in the release telegram. The
session, token and lockout rules are also checked on :class:`Guard` alone
(the time is an argument there) under hypothesis.
"""

from __future__ import annotations

import contextlib
import http.client
import json
import math
import os
import resource
import shutil
import signal
import socket
import ssl
import subprocess
import sys
import time
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from railstop.link.office_link import OfficeOutbox
from railstop.link.release_link import ReleaseGate, release_key
from railstop.live.operators import add_operator, load_operators
from railstop.live.page import AllowedHosts, Guard, PageError, PageLimits

KEY = bytes(range(32))
ALICE, BOB = ("alice", "correct horse battery"), ("bob", "tr0ub4dor&3")
CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
CHROMIUM_ARGS = ["--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update",
                 "--disable-sync"]  # fmt: skip


# ---------------------------------------------------------------------------------------- the office


@dataclass
class Office:
    proc: subprocess.Popen[str]
    host: str
    port: int  # the page's
    udp_port: int  # the office link's
    zc: socket.socket  # what the zone controller would receive
    ops: dict[str, int]  # operator -> id

    @property
    def origin(self) -> str:
        return f"http://{self.host}:{self.port}"

    def request(
        self,
        method: str,
        path: str,
        body: Any = None,
        *,
        cookie: str | None = None,
        headers: Mapping[str, str | None] | None = None,
        source: str | None = None,
    ) -> tuple[int, dict[str, str], bytes]:
        """One request on a new connection; the page's Origin on a POST unless ``headers`` say
        otherwise."""
        conn = http.client.HTTPConnection(
            self.host, self.port, timeout=10, source_address=None if source is None else (source, 0)
        )
        h: dict[str, str | None] = {"Origin": self.origin} if method == "POST" else {}
        data = None if body is None else json.dumps(body).encode()
        if data is not None:
            h["Content-Type"] = "application/json"
        if cookie:
            h["Cookie"] = f"railstop_session={cookie}"
        h.update(headers or {})
        sent = {k: v for k, v in h.items() if v is not None}
        try:
            conn.request(method, path, body=data, headers=sent)
            res = conn.getresponse()
            return res.status, {k.lower(): v for k, v in res.getheaders()}, res.read()
        finally:
            conn.close()

    def login(self, user: str, secret: str, source: str | None = None) -> str:
        status, headers, body = self.request(
            "POST", "/api/login", {"user": user, "secret": secret}, source=source
        )
        assert status == 200, body
        return headers["set-cookie"].split(";")[0].split("=", 1)[1]

    def token(self, cookie: str) -> str:
        status, _, body = self.request("POST", "/api/token", {}, cookie=cookie)
        assert status == 200, body
        return str(json.loads(body)["token"])

    def actions(self, cookie: str) -> list[dict[str, Any]]:
        status, _, body = self.request("GET", "/api/reports", cookie=cookie)
        assert status == 200
        return [r["data"] for r in json.loads(body) if r["kind"] == "operator-action"]

    def rss_mib(self) -> float:
        for line in Path(f"/proc/{self.proc.pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
        raise AssertionError("no VmRSS")


def start_office(tmp_path: Path, *extra: str, nofile: int | None = None) -> Office:
    ops = tmp_path / "operators.toml"
    ids = {}
    if not ops.exists():
        # Fewer PBKDF2 rounds than the default keep the many logins of these tests quick.
        ids = {u: add_operator(ops, u, s, iterations=20_000) for u, s in (ALICE, BOB)}
    zc = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    zc.bind(("127.0.0.1", 0))
    zc.settimeout(2.0)

    def limit() -> None:  # the office as a default Debian process gets it: 1,024 descriptors
        if nofile is not None:
            resource.setrlimit(resource.RLIMIT_NOFILE, (nofile, nofile))

    proc = subprocess.Popen(
        [sys.executable, "-m", "railstop.cli", "office", "serve", "--db", str(tmp_path / "office.db"),
         "--port", "0", "--http-port", "0", "--senders", "1-10", "--operators", str(ops),
         "--zc", f"127.0.0.1:{zc.getsockname()[1]}", *extra],
        env={**os.environ, "RAILSTOP_OFFICE_KEY": KEY.hex()},
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, preexec_fn=limit,
    )  # fmt: skip
    assert proc.stderr is not None
    lines = [proc.stderr.readline(), proc.stderr.readline()]
    page = next(ln.split("://")[1].strip().rstrip("/") for ln in lines if ln.startswith("control-room page"))
    udp = next(int(ln.split(" on ")[1].split()[0].split(":")[1]) for ln in lines if ln.startswith("office"))
    host, port = page.rsplit(":", 1)
    return Office(proc, host, int(port), udp, zc, ids)


def stop_office(office: Office) -> str:
    office.proc.send_signal(signal.SIGTERM)
    out, _ = office.proc.communicate(timeout=20)
    office.zc.close()
    return out


@pytest.fixture(scope="module")
def shared(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Office]:
    """One office for the tests that do not lock anyone out (starting one takes seconds)."""
    o = start_office(tmp_path_factory.mktemp("office"), "--http-timeout-s", "1.5")
    try:
        yield o
    finally:
        stop_office(o)


@pytest.fixture
def office(shared: Office) -> Office:
    """The shared office, its zone controller's socket emptied of earlier tests' telegrams."""
    shared.zc.setblocking(False)
    try:
        while True:
            shared.zc.recv(2048)
    except BlockingIOError:
        pass
    shared.zc.settimeout(2.0)
    return shared


@pytest.fixture
def own_office(tmp_path: Path) -> Iterator[Office]:
    o = start_office(tmp_path, "--http-timeout-s", "1.5")
    try:
        yield o
    finally:
        stop_office(o)


def ack_one_report(udp_port: int, n: int) -> None:
    """A wayside unit's report over the office link, until the office acknowledges it."""
    outbox = OfficeOutbox(own_id=3, office_id=900, master_key=KEY, session=int(time.time() * 1000) + n)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.settimeout(0.3)
        _, frame = outbox.submit(
            "stop-result", {"station": "Museum", "train": n, "error_m": 0.0}, time.time()
        )
        sock.sendto(frame, ("127.0.0.1", udp_port))
        deadline = time.monotonic() + 15.0
        while outbox.pending and time.monotonic() < deadline:
            try:
                outbox.on_frame(sock.recv(2048), time.time())
            except TimeoutError:
                for again in outbox.due(time.time()):
                    sock.sendto(again, ("127.0.0.1", udp_port))
        assert not outbox.pending, "the office did not acknowledge a report"


def read_until(res: http.client.HTTPResponse, needle: bytes, within_s: float) -> bytes:
    got, deadline = b"", time.monotonic() + within_s
    while needle not in got and time.monotonic() < deadline:
        got += res.read1(65536)
    return got


def is_closed(sock: socket.socket) -> bool:
    """Whether the office has closed ``sock`` (without waiting)."""
    sock.setblocking(False)
    try:
        return sock.recv(4096) == b""
    except BlockingIOError:
        return False
    except OSError:  # reset
        return True


def closed_by_peer(sock: socket.socket, within_s: float) -> float | None:
    """When the office closed ``sock`` (seconds from now), or None if it is still open then."""
    start = time.monotonic()
    sock.settimeout(0.1)
    while time.monotonic() - start < within_s:
        try:
            if sock.recv(4096) == b"":
                return time.monotonic() - start
        except TimeoutError:
            continue
        except OSError:  # reset: closed too
            return time.monotonic() - start
    return None


# ---------------------------------------------------------------------------------------- login


def test_nothing_is_shown_or_commanded_without_a_login(office: Office) -> None:
    status, headers, _ = office.request("GET", "/")
    assert status == 303 and headers["location"] == "/login"
    for path in ("/api/line", "/api/reports", "/events", "/api/session"):
        assert office.request("GET", path)[0] == 401, path
    assert office.request("POST", "/api/token", {})[0] == 401
    body = {"train": 1, "credential": ALICE[1], "confirmed": True, "token": "x"}
    assert office.request("POST", "/api/release", body)[0] == 401
    assert office.request("GET", "/api/line", cookie="forged-session-id")[0] == 401
    assert office.request("GET", "/login")[0] == 200  # the login page itself is public


def test_a_login_gives_a_strict_cookie_and_logout_ends_it(office: Office) -> None:
    status, headers, body = office.request("POST", "/api/login", {"user": ALICE[0], "secret": ALICE[1]})
    assert status == 200 and json.loads(body)["operator_id"] == office.ops["alice"]
    cookie = headers["set-cookie"]
    flags = {f.strip().split("=")[0].lower() for f in cookie.split(";")[1:]}
    assert {"httponly", "max-age", "path", "samesite"} <= flags and "samesite=strict" in cookie.lower()
    assert "secure" not in flags  # plain HTTP here (see the TLS test)
    sid = cookie.split(";")[0].split("=", 1)[1]
    assert len(sid) >= 40  # 256 random bits
    assert office.request("GET", "/api/line", cookie=sid)[0] == 200
    status, _, page = office.request("GET", "/", cookie=sid)
    assert status == 200 and b"control_room.js" in page
    assert office.request("POST", "/api/logout", {}, cookie=sid)[0] == 200
    assert office.request("GET", "/api/line", cookie=sid)[0] == 401
    # A wrong credential or an unknown name: the same answer.
    wrong = office.request("POST", "/api/login", {"user": "alice", "secret": "wrong guess"})
    unknown = office.request("POST", "/api/login", {"user": "mallory", "secret": "wrong guess"})
    assert wrong[0] == unknown[0] == 403 and wrong[2] == unknown[2]
    assert "set-cookie" not in wrong[1]


def test_the_event_stream_needs_a_session_and_is_bounded(office: Office) -> None:
    sid = office.login(*ALICE)
    conns = []
    try:
        for _ in range(PageLimits().max_streams_per_session):
            c = http.client.HTTPConnection(office.host, office.port, timeout=5)
            c.request("GET", "/events", headers={"Cookie": f"railstop_session={sid}"})
            res = c.getresponse()
            assert res.status == 200 and res.getheader("content-type", "").startswith("text/event-stream")
            assert b"event: ready" in read_until(res, b"event: ready", 10.0)
            conns.append(c)
        assert office.request("GET", "/events", cookie=sid)[0] == 503  # one stream too many
    finally:
        for c in conns:
            c.close()
    # A logout ends the session's streams (the closed ones are counted off as the office notices).
    deadline = time.monotonic() + 5.0
    while True:
        c = http.client.HTTPConnection(office.host, office.port, timeout=10)
        c.request("GET", "/events", headers={"Cookie": f"railstop_session={sid}"})
        res = c.getresponse()
        if res.status == 200 or time.monotonic() > deadline:
            break
        c.close()
        time.sleep(0.1)
    assert res.status == 200
    office.request("POST", "/api/logout", {}, cookie=sid)
    got = read_until(res, b"event: ended", PageLimits().stream_check_s + 5.0)
    c.close()
    assert b"event: ended" in got


# ---------------------------------------------------------------------------------------- commands


def test_a_replayed_release_is_refused_logged_and_never_sent_again(office: Office) -> None:
    sid = office.login(*ALICE)
    request = {"train": 2, "credential": ALICE[1], "confirmed": True, "token": office.token(sid)}
    assert not [a for a in office.actions(sid) if a["action"] == "zone-release" and a["train"] == 2]
    status, _, body = office.request("POST", "/api/release", request, cookie=sid)
    assert status == 200, body
    gate = ReleaseGate(key=release_key(KEY))
    frame = office.zc.recv(2048)
    assert gate.accept(frame, time.time()) is not None
    # The telegram names alice, not a fixed operator.
    assert gate.released_by == {office.ops["alice"]: 1} and office.ops["alice"] != office.ops["bob"]
    # The captured request, sent again with the same cookie: refused, nothing sent.
    status, _, body = office.request("POST", "/api/release", request, cookie=sid)
    assert status == 403 and b"token" in body
    office.zc.settimeout(0.5)
    with pytest.raises(TimeoutError):
        office.zc.recv(2048)
    # A token issued to another session is no good either; a command with none is invalid.
    bob = office.login(*BOB)
    stolen = {**request, "token": office.token(bob)}
    assert office.request("POST", "/api/release", stolen, cookie=sid)[0] == 403
    assert office.request("POST", "/api/release", {**request, "token": ""}, cookie=sid)[0] == 422
    results = [a["result"] for a in office.actions(sid) if a["action"] == "zone-release" and a["train"] == 2]
    assert results == ["sent to the zone controller"] + ["refused: replayed or unknown command token"] * 2


def test_bob_s_release_carries_bob_s_id_and_needs_his_credential_again(office: Office) -> None:
    sid = office.login(*BOB)
    bad = {"train": 5, "credential": ALICE[1], "confirmed": True, "token": office.token(sid)}
    assert office.request("POST", "/api/release", bad, cookie=sid)[0] == 403  # alice's, not his
    unconfirmed = {**bad, "credential": BOB[1], "confirmed": False, "token": office.token(sid)}
    assert office.request("POST", "/api/release", unconfirmed, cookie=sid)[0] == 400
    good = {**unconfirmed, "confirmed": True, "token": office.token(sid)}
    assert office.request("POST", "/api/release", good, cookie=sid)[0] == 200
    gate = ReleaseGate(key=release_key(KEY))
    assert gate.accept(office.zc.recv(2048), time.time()) is not None
    assert gate.released_by == {office.ops["bob"]: 1}


def test_wrong_credentials_lock_the_user_and_the_address_out_with_back_off(own_office: Office) -> None:
    office, lim = own_office, PageLimits()
    # From one address, any names: the address is locked after the free failures.
    for i in range(lim.lockout_free + 1):
        assert office.request("POST", "/api/login", {"user": f"guess{i}", "secret": "x"})[0] == 403
    status, headers, _ = office.request("POST", "/api/login", {"user": ALICE[0], "secret": ALICE[1]})
    assert status == 429 and int(headers["retry-after"]) >= 1  # even the right one: nothing checked
    # The user alice, from other addresses (127.0.0.2..): her name is locked too, wherever from.
    for i in range(lim.lockout_free + 1):
        got = office.request(
            "POST", "/api/login", {"user": "bob", "secret": "nope"}, source=f"127.0.0.{10 + i}"
        )
        assert got[0] == 403
    status, headers, _ = office.request(
        "POST", "/api/login", {"user": "bob", "secret": BOB[1]}, source="127.0.0.20"
    )
    assert status == 429
    first = int(headers["retry-after"])
    time.sleep(first + 0.2)
    # The wait is over: another wrong one doubles it.
    assert (
        office.request("POST", "/api/login", {"user": "bob", "secret": "nope"}, source="127.0.0.21")[0] == 403
    )
    status, headers, _ = office.request(
        "POST", "/api/login", {"user": "bob", "secret": BOB[1]}, source="127.0.0.22"
    )
    assert status == 429 and int(headers["retry-after"]) >= 2 * first - 1
    # alice from a clean address is not locked by the others' failures.
    assert office.login(*ALICE, source="127.0.0.30")


# ---------------------------------------------------------------------------------------- HTTP


def test_foreign_hosts_and_origins_are_refused(office: Office) -> None:
    sid = office.login(*ALICE)
    # DNS rebinding: the attacker's name pointing at the office.
    assert office.request("GET", "/login", headers={"Host": "evil.example"})[0] == 421
    assert (
        office.request("GET", "/api/line", cookie=sid, headers={"Host": f"evil.example:{office.port}"})[0]
        == 421
    )
    login = {"user": ALICE[0], "secret": ALICE[1]}
    for origin in (
        "http://evil.example",
        f"http://127.0.0.1:{office.port + 1}",
        f"https://{office.host}:{office.port}",
        None,
    ):
        assert office.request("POST", "/api/login", login, headers={"Origin": origin})[0] == 403, origin
    token = office.token(sid)
    release = {"train": 1, "credential": ALICE[1], "confirmed": True, "token": token}
    assert (
        office.request(
            "POST", "/api/release", release, cookie=sid, headers={"Origin": "http://evil.example"}
        )[0]
        == 403
    )
    cross = {"Sec-Fetch-Site": "cross-site"}
    assert office.request("GET", "/api/reports", cookie=sid, headers=cross)[0] == 403
    # The refused command did not use the token up: the page's own request still goes.
    assert office.request("POST", "/api/release", release, cookie=sid)[0] == 200
    assert office.request("PUT", "/api/release", release, cookie=sid)[0] == 405


def test_every_response_has_the_security_headers_and_the_page_has_no_inline_code(office: Office) -> None:
    for path in (
        "/login",
        "/static/control_room.js",
        "/static/login.js",
        "/static/control_room.css",
        "/nothing",
    ):
        _, headers, _ = office.request("GET", path)
        csp = headers["content-security-policy"]
        for part in (
            "default-src 'self'",
            "script-src 'self'",
            "frame-ancestors 'none'",
            "object-src 'none'",
        ):
            assert part in csp, (path, part)
        assert "unsafe-inline" not in csp and "unsafe-eval" not in csp
        assert headers["x-content-type-options"] == "nosniff" and headers["referrer-policy"] == "no-referrer"
    sid = office.login(*ALICE)
    _, _, page = office.request("GET", "/", cookie=sid)
    _, _, login = office.request("GET", "/login")
    for html in (page.decode(), login.decode()):
        assert "<style" not in html and " style=" not in html and "{{" not in html
        assert all(part.startswith(' src="/static/') for part in html.split("<script")[1:])
    for name in ("control_room.js", "login.js"):
        js = office.request("GET", f"/static/{name}")[2].decode()
        assert "innerHTML" not in js and "insertAdjacentHTML" not in js and "document.write" not in js


def test_a_huge_body_is_refused_before_it_is_read(office: Office) -> None:
    before = office.rss_mib()
    with socket.create_connection((office.host, office.port), timeout=5) as s:
        s.sendall(
            f"POST /api/login HTTP/1.1\r\nHost: {office.host}:{office.port}\r\nOrigin: {office.origin}\r\n"
            f"Content-Type: application/json\r\nContent-Length: {256 << 20}\r\n\r\n".encode()
        )
        answer = s.recv(4096)
        assert answer.startswith(b"HTTP/1.1 413"), answer
        sent = 0
        chunk = b"x" * (1 << 20)
        with pytest.raises(OSError):
            while sent < 256 << 20:  # the office has closed the connection: sending fails early
                s.sendall(chunk)
                sent += len(chunk)
    # Chunked, without a length: refused once the limit is passed.
    with socket.create_connection((office.host, office.port), timeout=5) as s:
        s.sendall(
            f"POST /api/login HTTP/1.1\r\nHost: {office.host}:{office.port}\r\nOrigin: {office.origin}\r\n"
            "Transfer-Encoding: chunked\r\n\r\n".encode()
            + b"1000\r\n"
            + b"y" * 4096
            + b"\r\n"
            + b"10\r\n"
            + b"y" * 16
            + b"\r\n"
        )
        assert s.recv(4096).startswith(b"HTTP/1.1 413")
    after = office.rss_mib()
    print(
        f"office RSS {before:.0f} MiB before, {after:.0f} MiB after a 256 MiB body was offered "
        f"({sent >> 20} MiB of it sent before the office closed the connection)"
    )
    assert after - before < 32


def test_idle_slow_and_slow_body_clients_are_cut_off(office: Office) -> None:
    timeout_s = 1.5  # the fixture's --http-timeout-s
    idle = socket.create_connection((office.host, office.port))
    assert closed_by_peer(idle, timeout_s + 3.0) is not None
    idle.close()
    # Slow loris: a byte of the headers every 0.2 s keeps coming, and is cut off all the same.
    loris = socket.create_connection((office.host, office.port))
    loris.sendall(b"GET /login HTTP/1.1\r\n")
    start = time.monotonic()
    cut = False
    while time.monotonic() - start < timeout_s + 3.0:
        try:
            loris.sendall(b"X")
        except OSError:
            cut = True
            break
        if closed_by_peer(loris, 0.2) is not None:
            cut = True
            break
    assert cut and time.monotonic() - start < timeout_s + 3.0
    loris.close()
    # A body that never finishes: 408.
    with socket.create_connection((office.host, office.port), timeout=timeout_s + 5.0) as s:
        s.sendall(
            f"POST /api/login HTTP/1.1\r\nHost: {office.host}:{office.port}\r\nOrigin: {office.origin}\r\n"
            "Content-Type: application/json\r\nContent-Length: 100\r\n\r\n{".encode()
        )
        assert s.recv(4096).startswith(b"HTTP/1.1 408")
    assert office.login(*ALICE)  # and the office serves on


def test_the_office_survives_1100_idle_connections_with_1024_descriptors(tmp_path: Path) -> None:
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if soft < 1300:
        resource.setrlimit(resource.RLIMIT_NOFILE, (min(4096, hard), hard))
    office = start_office(tmp_path, "--http-timeout-s", "2", nofile=1024)
    socks: list[socket.socket] = []
    try:
        for _ in range(1100):  # all at once, as an attacker would
            s = socket.socket()
            s.setblocking(False)
            s.connect_ex((office.host, office.port))
            socks.append(s)
        # Every one is connected (the handshake done: they hold the office's accept queue or a
        # descriptor of its own), none refused.
        import selectors

        with selectors.DefaultSelector() as sel:
            for s in socks:
                sel.register(s, selectors.EVENT_WRITE)
            pending, deadline = set(socks), time.monotonic() + 15.0
            while pending and time.monotonic() < deadline:
                for key, _ in sel.select(0.5):
                    sel.unregister(key.fileobj)
                    pending.discard(key.fileobj)
        assert not pending
        assert all(s.getsockopt(socket.SOL_SOCKET, socket.SO_ERROR) == 0 for s in socks)
        # The office's own work goes on (its reports over UDP, its database) while they hang on.
        ack_one_report(office.udp_port, 1)

        # Each batch the office holds waits out its 2 s header time-out before the next is
        # accepted: that many time-outs, and a loaded machine's slack.
        def wait_closed(open_: list[socket.socket]) -> list[socket.socket]:
            deadline = time.monotonic() + 2.0 * (math.ceil(1100 / 200) + 1) + 10.0
            while open_ and time.monotonic() < deadline:
                open_ = [s for s in open_ if not is_closed(s)]
                time.sleep(0.2)
            return open_

        open_ = wait_closed(list(socks))
        # A handshake the kernel finished with a SYN cookie (its listen queue overflowed) is not
        # known to the office until the client sends something: it holds no descriptor of the
        # office's. As soon as such a client speaks, the office takes it and times it out too.
        for s in open_:
            with contextlib.suppress(OSError):
                s.send(b"G")
        open_ = wait_closed(open_)
        assert not open_, f"{len(open_)} of 1100 idle connections still open"
        assert len(os.listdir(f"/proc/{office.proc.pid}/fd")) < 200  # none of them held
        assert office.proc.poll() is None
        sid = office.login(*ALICE)
        ack_one_report(office.udp_port, 2)
        status, _, body = office.request("GET", "/api/reports", cookie=sid)
        assert status == 200 and [r["kind"] for r in json.loads(body)].count("stop-result") == 2
    finally:
        for s in socks:
            s.close()
        stop_office(office)


def test_tls_sets_a_secure_cookie_and_hsts(tmp_path: Path) -> None:
    openssl = shutil.which("openssl")
    if openssl is None:
        pytest.skip("no openssl to make a test certificate")
    cert, key = tmp_path / "cert.pem", tmp_path / "key.pem"
    subprocess.run(
        [openssl, "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-keyout", str(key), "-out", str(cert),
         "-days", "1", "-subj", "/CN=127.0.0.1"],
        check=True, capture_output=True,
    )  # fmt: skip
    office = start_office(tmp_path, "--tls-cert", str(cert), "--tls-key", str(key))
    try:
        ctx = ssl.create_default_context(cafile=str(cert))
        ctx.check_hostname = False
        conn = http.client.HTTPSConnection(office.host, office.port, context=ctx, timeout=10)
        conn.request(
            "POST",
            "/api/login",
            body=json.dumps({"user": ALICE[0], "secret": ALICE[1]}),
            headers={"Origin": f"https://{office.host}:{office.port}", "Content-Type": "application/json"},
        )
        res = conn.getresponse()
        res.read()
        assert res.status == 200
        assert "secure" in res.getheader("set-cookie", "").lower()
        assert res.getheader("strict-transport-security", "").startswith("max-age=")
        conn.close()
    finally:
        stop_office(office)


# ---------------------------------------------------------------------------------------- the browser


@pytest.mark.skipif(
    CHROMIUM is None and not os.environ.get("RAILSTOP_REQUIRE_BROWSER"),
    reason="no chromium on this machine (Debian package chromium)",
)
def test_markup_in_the_line_s_names_is_shown_as_text_and_never_runs(tmp_path: Path) -> None:
    from importlib import resources

    from playwright.sync_api import sync_playwright

    evil = '<img src=x onerror="window.pwned=1">'
    line = resources.files("railstop.data").joinpath("line.toml").read_text(encoding="utf-8")
    line = line.replace('name = "railstop demo line"', f"name = '{evil}'", 1)
    line = line.replace('name = "Museum"', "name = '<b>Museum</b><script>window.pwned=2</script>'", 1)
    (tmp_path / "line.toml").write_text(line, encoding="utf-8")
    office = start_office(tmp_path, "--line", str(tmp_path / "line.toml"))
    try:
        with sync_playwright() as pw:
            browser = pw.chromium.launch(executable_path=CHROMIUM, headless=True, args=CHROMIUM_ARGS)
            try:
                page = browser.new_page()
                violations: list[str] = []
                page.on(
                    "console", lambda m: violations.append(m.text) if "Content Security" in m.text else None
                )
                page.goto(f"{office.origin}/")
                page.fill("#user", ALICE[0])
                page.fill("#secret", ALICE[1])
                page.click("#login-send")
                page.wait_for_selector("#status.ok", timeout=15_000)
                assert page.inner_text("#title") == f"railstop control room: {evil}"
                assert page.locator("header img").count() == 0
                page.wait_for_selector("#platforms tbody tr:nth-child(3)", timeout=10_000)
                assert "<b>Museum</b>" in page.inner_text("#platforms")
                assert page.locator("#platforms b").count() == 0
                # Markup that would run if it were parsed: it is not; and inline script is refused.
                assert page.evaluate("window.pwned") is None
                page.evaluate(
                    "() => { const s = document.createElement('script'); s.textContent = 'window.pwned = 3';"
                    " document.body.append(s); }"
                )
                assert page.evaluate("window.pwned") is None
                assert violations  # the CSP refused the inline script
                page.click("#logout")
                page.wait_for_selector("form#login", timeout=10_000)
            finally:
                browser.close()
    finally:
        stop_office(office)


# ---------------------------------------------------------------------------------------- the CLI


def _cli(
    *args: str, env: dict[str, str] | None = None, cwd: Path | None = None
) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "railstop.cli", *args],
        capture_output=True, text=True, timeout=60, env={**os.environ, **(env or {})}, cwd=cwd,
        stdin=subprocess.DEVNULL,
    )  # fmt: skip


def test_credentials_never_come_from_the_command_line_and_the_file_is_private(tmp_path: Path) -> None:
    ops = tmp_path / "ops.toml"
    got = _cli("office", "add-operator", str(ops), "carol", "--credential", "on the command line")
    assert got.returncode == 2 and got.stderr.count("\n") == 1 and "--credential" in got.stderr
    assert not ops.exists()
    got = _cli("office", "add-operator", str(ops), "carol")  # no prompt without a terminal
    assert got.returncode == 2 and got.stderr.startswith("error: no credential")
    got = _cli("office", "add-operator", str(ops), "carol", "--id", "7",
               env={"RAILSTOP_OPERATOR_CREDENTIAL": "from the environment"})  # fmt: skip
    assert got.returncode == 0, got.stderr
    assert (ops.stat().st_mode & 0o777) == 0o600
    assert "from the environment" not in ops.read_text()
    assert load_operators(ops)["carol"].id == 7
    secret = tmp_path / "secret.txt"
    secret.write_text("from a file, first line\n")
    assert _cli("office", "add-operator", str(ops), "dave", "--credential-file", str(secret)).returncode == 0
    assert load_operators(ops)["dave"].id == 8
    # No credential at all is refused whatever its length: blanks, one character repeated.
    for empty in ("", "\n", " " * 12 + "\n", "x" * 12 + "\n"):
        secret.write_text(empty)
        got = _cli("office", "add-operator", str(ops), "erin", "--credential-file", str(secret))
        assert got.returncode == 2 and got.stderr.count("\n") == 1 and "credential" in got.stderr, empty
    assert "erin" not in load_operators(ops)
    # Readable by others: the office refuses it in one line.
    ops.chmod(0o644)
    got = _cli(
        "office", "serve", "--http-port", "0", "--operators", str(ops), env={"RAILSTOP_OFFICE_KEY": KEY.hex()}
    )
    assert got.returncode == 2 and got.stderr.count("\n") == 1 and "chmod 600" in got.stderr


def test_an_operators_file_without_ids_or_with_a_shared_id_is_refused(tmp_path: Path) -> None:
    from railstop.errors import ConfigError

    ops = tmp_path / "ops.toml"
    add_operator(ops, "alice", ALICE[1], iterations=1000)
    text = ops.read_text()
    for bad in (text.replace("id = 1\n", ""), text + text.replace("[operators.alice]", "[operators.eve]")):
        ops.write_text(bad)
        ops.chmod(0o600)
        with pytest.raises(ConfigError, match=r"\.id"):
            load_operators(ops)


# ---------------------------------------------------------------------------------------- the units


def test_allowed_hosts_default_to_the_bound_address() -> None:
    hosts = AllowedHosts()
    hosts.bind("127.0.0.1", 8080)
    assert hosts.allows("127.0.0.1:8080", 80) and hosts.allows("localhost:8080", 80)
    assert not hosts.allows("127.0.0.1:8081", 80) and not hosts.allows("evil.example:8080", 80)
    assert not hosts.allows("127.0.0.1", 80) and not hosts.allows(None, 80) and not hosts.allows("a/b", 80)
    assert hosts.allows_origin("http://127.0.0.1:8080", "http") and not hosts.allows_origin("null", "http")
    named = AllowedHosts(["office.example", "10.0.0.5:9000"])
    named.bind("0.0.0.0", 8443)
    assert named.allows("OFFICE.example:8443", 443) and named.allows("10.0.0.5:9000", 80)
    assert not named.allows("127.0.0.1:8443", 443)
    with pytest.raises(PageError, match="--allowed-hosts"):
        AllowedHosts().bind("0.0.0.0", 80)
    with pytest.raises(PageError, match="--allowed-hosts"):
        AllowedHosts(["http://x/"])


LIM = PageLimits(session_max_s=100.0, session_idle_s=10.0, token_ttl_s=5.0, tokens_per_session=4)


@settings(max_examples=60, deadline=None)
@given(gaps=st.lists(st.floats(0.0, 12.0), min_size=1, max_size=30))
def test_a_session_ends_when_idle_or_too_old_and_never_comes_back(gaps: list[float]) -> None:
    guard = Guard(LIM)
    sid = guard.open("alice", 1, 0.0)
    now, seen, ended = 0.0, 0.0, False
    for gap in gaps:
        now += gap
        alive = guard.get(sid, now) is not None
        expected = not ended and now - seen < LIM.session_idle_s and now < LIM.session_max_s
        assert alive == expected
        ended = ended or not alive
        seen = now if alive else seen


@settings(max_examples=60, deadline=None)
@given(plan=st.lists(st.tuples(st.booleans(), st.floats(0.0, 3.0)), min_size=1, max_size=25))
def test_a_command_token_is_good_once_for_its_session_only(plan: list[tuple[bool, float]]) -> None:
    guard = Guard(LIM)
    mine = guard.get(guard.open("alice", 1, 0.0), 0.0)
    other = guard.get(guard.open("bob", 2, 0.0), 0.0)
    assert mine is not None and other is not None
    held: list[tuple[str, float]] = []
    spent: list[str] = []
    now = 0.0
    for use_now, gap in plan:
        now += gap
        token = guard.issue(mine, now)
        assert not guard.redeem(other, token, now)  # never another session's
        if use_now:
            assert guard.redeem(mine, token, now)
            spent.append(token)
        else:
            held.append((token, now))
        assert not any(guard.redeem(mine, t, now) for t in spent)  # never twice
    assert not any(guard.redeem(mine, t, now) for t, at in held if now - at > LIM.token_ttl_s)


@settings(max_examples=60, deadline=None)
@given(failures=st.integers(1, 40))
def test_the_lockout_doubles_and_nothing_is_checked_while_locked(failures: int) -> None:
    guard = Guard(PageLimits())
    lim = guard.limits
    now, waits = 0.0, []
    for _ in range(failures):
        wait = guard.attempt("alice", "10.0.0.1", now)
        assert wait == 0.0  # the previous lock is over: checked (and failed)
        waits.append(guard.locked_for_s("alice", "10.0.0.1", now))
        # While locked, another try is refused without a check (attempt answers the wait).
        if waits[-1] > 0.0:
            assert guard.attempt("alice", "10.0.0.9", now + waits[-1] / 2) > 0.0
        now += waits[-1] + 0.001
    for i, w in enumerate(waits):
        extra = i + 1 - lim.lockout_free
        want = 0.0 if extra <= 0 else min(lim.lockout_base_s * 2 ** (extra - 1), lim.lockout_max_s)
        assert w == pytest.approx(want, abs=1e-6)
    guard.succeeded("alice", "10.0.0.1")
    assert guard.locked_for_s("alice", "10.0.0.1", now) == 0.0
