"""The control-room page in a real browser (issue 17 item 4): Debian's chromium driven by Playwright.

``railstop office serve --http-port 0`` runs as a real process; a wayside
sender in this test sends reports over real UDP through the category-3
office link; headless Chromium shows the page. The page must show a train
and follow it as it moves, and show a station's last stop. The time from a
report's sending to its appearance on the page is measured and printed (a
figure, not a timed assertion).

Chromium is Debian's ``/usr/bin/chromium`` (never ``playwright install``).
Without it the test is skipped, unless ``RAILSTOP_REQUIRE_BROWSER`` is set
(CI sets it: there a missing browser is a failure).
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from railstop.link.office_link import OfficeOutbox

KEY = bytes(range(32))
CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
pytestmark = pytest.mark.skipif(
    CHROMIUM is None and not os.environ.get("RAILSTOP_REQUIRE_BROWSER"),
    reason="no chromium on this machine (Debian package chromium)",
)
# As root and on a closed network: no sandbox, no background connections (they are refused here).
CHROMIUM_ARGS = [
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]


def wait_js(page: Any, expression: str, timeout: float = 30_000) -> None:
    """Wait until ``expression`` is true in the page. (Playwright's ``wait_for_function`` compiles
    its predicate from a string inside the page, which the page's Content-Security-Policy forbids;
    ``evaluate`` goes through the DevTools protocol, which it does not.)"""
    deadline = time.monotonic() + timeout / 1000.0
    while not page.evaluate(expression):
        assert time.monotonic() < deadline, f"timed out waiting for {expression}"
        time.sleep(0.05)


def log_in(page: Any, url: str, user: str, secret: str) -> None:
    """Open the page: the office sends the browser to its login; log in; wait for the live page."""
    page.goto(url)
    page.wait_for_selector("form#login", timeout=15_000)
    page.fill("#user", user)
    page.fill("#secret", secret)
    page.click("#login-send")
    page.wait_for_selector("#status.ok", timeout=15_000)


class Sender:
    """A wayside unit's end of the office link over a plain UDP socket (synchronous, for this test)."""

    def __init__(self, port: int) -> None:
        self.outbox = OfficeOutbox(own_id=3, office_id=900, master_key=KEY, session=int(time.time()))
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.settimeout(0.2)
        self.addr = ("127.0.0.1", port)

    def send(self, kind: str, data: dict[str, object]) -> float:
        """Send one report until acknowledged; return when it was first sent (monotonic)."""
        sent = time.monotonic()
        _, frame = self.outbox.submit(kind, data, time.time())
        self.sock.sendto(frame, self.addr)
        deadline = sent + 20.0
        while self.outbox.pending and time.monotonic() < deadline:
            try:
                self.outbox.on_frame(self.sock.recv(2048), time.time())
            except TimeoutError:
                for again in self.outbox.due(time.time()):
                    self.sock.sendto(again, self.addr)
        assert not self.outbox.pending, "the office did not acknowledge"
        return sent


@pytest.fixture
def office(tmp_path: Path) -> Iterator[tuple[str, int, str]]:
    """The office with its page and no operators file: it prints a one-time login for viewing. Its
    key comes from a key file (mode 0600)."""
    key_file = tmp_path / "office.key"
    key_file.write_text(KEY.hex() + "\n")
    key_file.chmod(0o600)
    proc = subprocess.Popen(
        [sys.executable, "-m", "railstop.cli", "office", "serve", "--db", str(tmp_path / "office.db"),
         "--port", "0", "--http-port", "0", "--key-file", str(key_file), "--senders", "1-10"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    assert proc.stderr is not None
    lines = [proc.stderr.readline(), proc.stderr.readline(), proc.stderr.readline()]
    url = next(ln.split(" at ")[1].strip() for ln in lines if ln.startswith("control-room page at"))
    port = next(
        int(ln.split("127.0.0.1:")[1].split()[0]) for ln in lines if ln.startswith("office listening")
    )
    login = next(ln for ln in lines if ln.startswith("control-room login: viewer / "))
    try:
        yield url, port, login.split(" / ")[1].split()[0]
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.communicate(timeout=20)


def test_the_page_shows_trains_moving_and_the_last_stops(
    office: tuple[str, int, str], tmp_path: Path
) -> None:
    from playwright.sync_api import sync_playwright

    url, port, secret = office
    sender = Sender(port)
    with sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=CHROMIUM, headless=True, args=CHROMIUM_ARGS)
        try:
            page = browser.new_page(viewport={"width": 1280, "height": 720})
            page.clock.install()  # the page's own clock, advanced below (it runs at the real rate)
            page.goto(url)
            assert page.url.endswith("/login")  # nothing is shown without a login
            page.screenshot(path=str(tmp_path / "login.png"))
            log_in(page, url, "viewer", secret)
            assert page.inner_text("#user") == "viewer"
            latencies = []
            for position in (1200.0, 1500.0, 1800.0):
                sent = sender.send("train-state", {"train": 4, "position_m": position, "speed_mps": 12.0})
                page.wait_for_selector(
                    f'g.train[data-train="4"][data-position="{position:.1f}"]', timeout=10_000
                )
                latencies.append(time.monotonic() - sent)
            sent = sender.send(
                "stop-result",
                {"station": "Hillcrest", "train": 4, "controller": "tasc-pwm", "error_m": 0.042, "lamp": "-",
                 "doors": "PSC", "within": True},
            )  # fmt: skip
            row = page.wait_for_selector('#stops tr[data-station="Hillcrest"]', timeout=10_000)
            latencies.append(time.monotonic() - sent)
            assert row is not None and "0.042" in row.inner_text() and "tasc-pwm" in row.inner_text()
            # One marker per train, however many reports: the page follows the train.
            assert page.locator("g.train").count() == 1
            # The stop and the login; train states are on the line only.
            assert page.locator('#log div[data-kind="stop-result"]').count() == 1
            assert page.locator('#log div[data-kind="operator-action"]').count() == 1
            # The log in sentences (issue 38), the record itself only on hover.
            said = page.inner_text('#log div[data-kind="stop-result"]')
            assert "Train 4 stopped at Hillcrest, +0.042 m from the stopping point (within" in said, said
            assert "{" not in said and "{" in (
                page.get_attribute('#log div[data-kind="stop-result"]', "title") or ""
            )
            assert "Operator viewer: login" in page.inner_text('#log div[data-kind="operator-action"]')
            assert page.inner_text("#status") == "live"  # reports keep coming
            page.screenshot(path=str(tmp_path / "control-room.png"))
            # No report for a minute: the page says the record is finished instead of "live".
            page.clock.fast_forward(61_000)
            page.wait_for_selector("#status.quiet", timeout=10_000)
            assert "a finished record" in page.inner_text("#status")
        finally:
            browser.close()
    print(f"report-to-page latency: {', '.join(f'{x * 1000:.0f} ms' for x in latencies)}")
    assert (tmp_path / "control-room.png").stat().st_size > 10_000


def test_a_page_opened_late_gets_the_history(office: tuple[str, int, str]) -> None:
    from playwright.sync_api import sync_playwright

    url, port, secret = office
    sender = Sender(port)
    for i in range(3):
        sender.send("stop-result", {"station": "Museum", "train": i, "error_m": 0.01 * i, "within": True})
    with sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=CHROMIUM, headless=True, args=CHROMIUM_ARGS)
        try:
            page = browser.new_page()
            log_in(page, url, "viewer", secret)
            # The stops and this login (an operator action).
            wait_js(page, "document.querySelectorAll('#log div').length === 4", timeout=10_000)
            assert page.locator('#log div[data-kind="stop-result"]').count() == 3
            assert "0.020" in page.locator('#stops tr[data-station="Museum"]').inner_text()
            # The accuracy chart has a dot per stop, green inside the PSD tolerance.
            assert page.locator("#accuracy circle.stop-dot").count() == 3
            # ... and covers the whole record, not only the last reports the stream starts with:
            # 250 more stops (the stream's history is the last 200 reports), each counted once.
            for i in range(250):
                sender.send("stop-result", {"station": "Riverside", "train": i % 7, "error_m": 0.001 * i,
                                            "within": True})  # fmt: skip
            wait_js(
                page, "document.querySelectorAll('#accuracy circle.stop-dot').length === 253", timeout=20_000
            )
            page.reload()
            wait_js(page, "document.querySelectorAll('#log div').length >= 200", timeout=15_000)
            wait_js(
                page, "document.querySelectorAll('#accuracy circle.stop-dot').length === 253", timeout=15_000
            )
        finally:
            browser.close()


class _Processes:
    """The live line's processes of a browser test (railstop's CLI with the test's key): ``start``
    gives a process's first stderr lines (two for the office), ``stop_all`` stops them, the last
    started first, and gives each one's stdout in that order."""

    def __init__(self) -> None:
        self.env = {**os.environ, "RAILSTOP_OFFICE_KEY": KEY.hex()}
        self.all: list[subprocess.Popen[str]] = []

    def start(self, *args: str) -> list[str]:
        p = subprocess.Popen(
            [sys.executable, "-m", "railstop.cli", *args],
            env=self.env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        )  # fmt: skip
        self.all.append(p)
        assert p.stderr is not None
        return [p.stderr.readline().strip() for _ in range(2 if args[0] == "office" else 1)]

    def stop_all(self) -> list[str]:
        results = []
        for p in reversed(self.all):
            p.send_signal(signal.SIGTERM)
            out, _ = p.communicate(timeout=30)
            results.append(out)
        return results


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def test_a_radio_outage_sets_a_zone_that_an_operator_releases_with_his_credential(tmp_path: Path) -> None:
    """The live line: a train's radio dies, the zone controller sets its protection zone, the page
    shows it; a wrong credential is refused; the right one sends the authenticated release and the
    controller clears the zone; every operator action is in the database."""
    from playwright.sync_api import sync_playwright

    from railstop.live.operators import add_operator

    ops = tmp_path / "operators.toml"
    add_operator(ops, "bob", "another operator")
    alice = add_operator(ops, "alice", "correct horse battery")
    db = str(tmp_path / "office.db")
    zc_port = _free_udp_port()
    epoch = ["--epoch", repr(time.time()), "--scale", "1"]

    procs = _Processes()
    start = procs.start

    try:
        lines = start("office", "serve", "--db", db, "--port", "0", "--http-port", "0", "--zc",
                      f"127.0.0.1:{zc_port}", "--operators", str(ops))  # fmt: skip
        url = next(x.split(" at ")[1] for x in lines if x.startswith("control-room page"))
        office = next(x.split(" on ")[1].split()[0] for x in lines if x.startswith("office listening"))
        start("live", "zc", "--port", str(zc_port), "--trains", "3", "--office", office, "--new", *epoch)
        start("live", "trains", "--zc", f"127.0.0.1:{zc_port}", "--trains", "3", "--spacing-m", "800",
              "--office", office, "--outage-train", "1", *epoch)  # fmt: skip
        trains = procs.all[2]
        with sync_playwright() as pw:
            browser = pw.chromium.launch(executable_path=CHROMIUM, headless=True, args=CHROMIUM_ARGS)
            try:
                page = browser.new_page(viewport={"width": 1280, "height": 900})
                log_in(page, url, "alice", "correct horse battery")
                wait_js(page, "document.querySelectorAll('g.train').length === 3", timeout=15_000)
                assert page.locator("#no-zones").is_visible()
                trains.send_signal(signal.SIGUSR1)  # train 1's radio dies
                page.wait_for_selector('#zones-table tr[data-train="1"]', timeout=15_000)
                page.wait_for_selector('g.train[data-train="1"][data-radio="dead"]', timeout=15_000)
                assert page.inner_text('#zones-table tr[data-train="1"] td.zone-status') == "lost"
                zone_png = tmp_path / "zone.png"
                page.screenshot(path=str(zone_png))
                if os.environ.get("RAILSTOP_SCREENSHOT_DIR"):  # how docs/control-room.png is made
                    shutil.copy(zone_png, Path(os.environ["RAILSTOP_SCREENSHOT_DIR"]) / "control-room.png")

                def release(credential: str) -> str:
                    page.click('#zones-table tr[data-train="1"] button.release')
                    page.check("#release-confirm")
                    page.fill("#release-credential", credential)
                    page.click("#release-send")
                    wait_js(page, "document.getElementById('release-result').textContent !== ''")
                    text = page.inner_text("#release-result")
                    page.evaluate("document.getElementById('release-result').textContent = ''")
                    return text

                assert release("wrong guess").startswith("refused")
                assert page.locator('#zones-table tr[data-train="1"]').count() == 1  # still protected
                assert "sent to the zone controller" in release("correct horse battery")
                # The controller clears the zone: its zone-event says so (while the radio stays
                # dead it protects the train again once it misses its reports: that is right).
                wait_js(
                    page,
                    "[...document.querySelectorAll('#log div[data-kind=\"zone-event\"]')]"
                    ".some(d => d.textContent.includes('protection zone released'))",
                    timeout=10_000,
                )
                trains.send_signal(signal.SIGUSR1)  # the radio comes back
            finally:
                browser.close()
        assert zone_png.stat().st_size > 10_000
    finally:
        results = procs.stop_all()
    zc_counts = json.loads(results[1].strip().splitlines()[-1])
    assert zc_counts["manual_releases"] >= 1 and zc_counts["lost_trains"] >= 1
    # The release telegram named its operator: the zone controller's end recorded alice's id (the
    # second operator of the file), not a fixed one.
    assert alice == 2 and zc_counts["released_by"] == {str(alice): 1}
    from railstop.store import open_store

    with open_store(db) as store:
        actions = [r["data"] for r in store.office_reports(kind="operator-action")]
    assert [a["result"] for a in actions if a["action"] == "login"] == ["logged in"]
    releases = [a for a in actions if a["action"] == "zone-release"]
    assert [a["result"].split(":")[0] for a in releases] == ["refused", "sent to the zone controller"]
    assert all(a["operator"] == "alice" and a["operator_id"] == alice and a["train"] == 1 for a in releases)


def test_the_wcc_switches_a_platform_to_manual_and_the_panel_moves_the_psd(tmp_path: Path) -> None:
    """SPEC §5 live: the page (the WCC) switches Harbour's WPCS to manual before the first train
    arrives. The train stops, PSC goes high, but the ATC's door command no longer opens the PSD;
    the operator's "open" opens it (then the train's doors), his "close" closes it once the train's
    doors are locked, and the train gets start enable. A wrong credential changes nothing; every
    operator action is in the database."""
    from playwright.sync_api import sync_playwright

    from railstop.live.operators import add_operator

    ops = tmp_path / "operators.toml"
    add_operator(ops, "bob", "tr0ub4dor")
    db = str(tmp_path / "office.db")
    zc_port, st_port = _free_udp_port(), _free_udp_port()
    epoch = ["--epoch", repr(time.time()), "--scale", "2"]

    procs = _Processes()
    start = procs.start

    harbour = 'tr[data-station="Harbour"]'
    try:
        lines = start("office", "serve", "--db", db, "--port", "0", "--http-port", "0", "--zc",
                      f"127.0.0.1:{zc_port}", "--stations", f"127.0.0.1:{st_port}",
                      "--operators", str(ops))  # fmt: skip
        url = next(x.split(" at ")[1] for x in lines if x.startswith("control-room page"))
        office = next(x.split(" on ")[1].split()[0] for x in lines if x.startswith("office listening"))
        start("live", "zc", "--port", str(zc_port), "--trains", "2", "--office", office, "--new", *epoch)
        assert start("live", "stations", "--port", str(st_port), "--office", office, *epoch)[0].startswith(
            "stations on"
        )
        with sync_playwright() as pw:
            browser = pw.chromium.launch(executable_path=CHROMIUM, headless=True, args=CHROMIUM_ARGS)
            try:
                page = browser.new_page(viewport={"width": 1280, "height": 1100})
                log_in(page, url, "bob", "tr0ub4dor")

                def wcc(command: str, credential: str = "tr0ub4dor") -> str:
                    page.click(f'#platforms {harbour} button[data-cmd="{command}"]')
                    page.check("#wcc-confirm")
                    page.fill("#wcc-credential", credential)
                    page.click("#wcc-send")
                    wait_js(page, "document.getElementById('wcc-result').textContent !== ''")
                    text = page.inner_text("#wcc-result")
                    page.evaluate("document.getElementById('wcc-result').textContent = ''")
                    return text

                def cell(i: int) -> str:
                    return page.inner_text(f"#platforms {harbour} td:nth-child({i})")

                assert wcc("manual", "guess").startswith("refused")
                assert cell(4) == "auto"
                assert "sent to the station" in wcc("manual")
                wait_js(
                    page,
                    f"document.querySelector('#platforms {harbour} td.wpcs-mode').textContent === 'manual'",
                    timeout=10_000,
                )
                # Only now do the trains run: train 0 starts 100 m before Harbour.
                start("live", "trains", "--zc", f"127.0.0.1:{zc_port}", "--trains", "2", "--spacing-m",
                      "1100", "--stations", f"127.0.0.1:{st_port}", "--office", office, *epoch)  # fmt: skip
                wait_js(
                    page,
                    f"document.querySelector('#platforms {harbour} td:nth-child(5)')"
                    ".textContent.startsWith('psc')",
                    timeout=30_000,
                )
                time.sleep(2.0)  # 4 s of the run: in automatic the PSD would be opening by now
                assert cell(3) == "closed_locked" and cell(5).startswith("psc")
                wcc_png = tmp_path / "wcc.png"
                page.screenshot(path=str(wcc_png), full_page=True)
                if os.environ.get("RAILSTOP_SCREENSHOT_DIR"):  # how docs/control-room-wcc.png is made
                    shutil.copy(wcc_png, Path(os.environ["RAILSTOP_SCREENSHOT_DIR"]) / "control-room-wcc.png")
                assert "sent to the station" in wcc("open")
                wait_js(
                    page,
                    f"document.querySelector('#platforms {harbour} td:nth-child(3)').textContent === 'open'",
                    timeout=10_000,
                )
                # Closing: the PSD waits for the train's doors (its dwell), then closes; start enable.
                assert "sent to the station" in wcc("close")
                wait_js(
                    page,
                    f"document.querySelector('#platforms {harbour} td:nth-child(6)').textContent"
                    ".includes('start enable')",
                    timeout=40_000,
                )
                assert cell(3) == "closed_locked"
                assert "sent to the station" in wcc("auto")
                wait_js(
                    page,
                    f"document.querySelector('#platforms {harbour} td.wpcs-mode').textContent === 'auto'",
                    timeout=10_000,
                )
            finally:
                browser.close()
        assert wcc_png.stat().st_size > 10_000
    finally:
        procs.stop_all()
    from railstop.store import open_store

    with open_store(db) as store:
        actions = [
            r["data"] for r in store.office_reports(kind="operator-action") if r["data"]["action"] == "wcc"
        ]
        events = [r["data"] for r in store.office_reports(kind="dwell-event") if r["data"]["st"] == "Harbour"]
    assert [a["result"].split(":")[0] for a in actions] == ["refused"] + ["sent to the station"] * 4
    assert [a["command"] for a in actions[1:]] == [
        "WPCS manual", "WPCS manual, panel open", "WPCS manual, panel close", "WPCS auto",
    ]  # fmt: skip
    kinds = [e["ev"] for e in events]
    assert kinds[:4] == ["wcc-manual", "psc", "psd-open", "psd-locked"], kinds
    assert "wcc-auto" in kinds
