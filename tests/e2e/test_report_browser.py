"""The campaign report with all ten controllers, in a real browser (issue 38 item 6).

``railstop compare`` runs every controller on the same draws and ``railstop report`` writes the
page; Debian's chromium (Playwright, never ``playwright install``) lays it out at 1280 px: no
table behind a horizontal scroll, ten distinct controller colours, the controllers in their own
order (TASC first), no parameter a campaign does not vary in its worst-run table (a TASC run
has no driver level), no outcome plotted as a disturbance. The screenshot is kept in the test's
folder for a person to look at.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
from pathlib import Path

import pytest

from railstop.controllers import CONTROLLERS
from zygote import run_cli

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
pytestmark = pytest.mark.skipif(
    CHROMIUM is None and not os.environ.get("RAILSTOP_REQUIRE_BROWSER"),
    reason="no chromium on this machine (Debian package chromium)",
)
CHROMIUM_ARGS = ["--no-sandbox", "--disable-gpu", "--no-first-run", "--disable-background-networking"]


def run(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return run_cli(*args, cwd=cwd, timeout=600)  # forked from a warm zygote (tests/zygote.py)


def test_the_report_of_ten_controllers_fits_the_page_and_tells_them_apart(tmp_path: Path) -> None:
    from playwright.sync_api import sync_playwright

    assert run("compare", "--runs", "40", "--out", "cmp", "--db", "c.db", cwd=tmp_path).returncode == 0
    r = run("report", "cmp", "--worst", "1", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    page_html = (tmp_path / "cmp" / "report.html").read_text(encoding="utf-8")
    # The swatches of the summary: one per controller, ten colours, in the controllers' order.
    swatches = re.findall(r'<span class="swatch" style="background:([^"]+)"></span>([^<]+)</th>', page_html)
    assert [name for _, name in swatches] == list(CONTROLLERS)
    assert len({colour for colour, _ in swatches}) == len(CONTROLLERS) == 10
    # Outcomes are not disturbances: the manual stop's first stand is not plotted against.
    drives = page_html.split("<h2>What drives the misses</h2>", 1)[1].split("</p>", 1)[0]
    for outcome in ("first_stop_error_m", "restops", "lamp"):
        assert outcome not in drives
    # A TASC campaign's worst runs show no driver level (it is -1 in every TASC run).
    tasc = page_html.split("<h3>tasc-pwm</h3>", 1)[1].split("<h3>", 1)[0]
    assert "driver_level" not in tasc
    with sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=CHROMIUM, headless=True, args=CHROMIUM_ARGS)
        try:
            page = browser.new_page(viewport={"width": 1280, "height": 900})
            page.goto((tmp_path / "cmp" / "report.html").as_uri())
            overflow = page.evaluate(
                "Array.from(document.querySelectorAll('.wide'))"
                ".filter(e => e.scrollWidth > e.clientWidth + 1).map(e => [e.scrollWidth, e.clientWidth])"
            )
            assert overflow == [], overflow  # nothing behind a horizontal scroll
            assert page.evaluate("document.documentElement.scrollWidth <= window.innerWidth")
            page.screenshot(path=str(tmp_path / "report.png"), full_page=False)
        finally:
            browser.close()
    assert (tmp_path / "report.png").stat().st_size > 10_000
