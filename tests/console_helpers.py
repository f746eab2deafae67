"""The console tests' helpers: a console on an ephemeral loopback port, Debian's chromium
through Playwright (never a downloaded browser), polling with a deadline."""

from __future__ import annotations

import json
import os
import shutil
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

import pytest

TOKEN = "console-test-token"
#: Debian's chromium (``.ci/run`` installs it); ``$BTRUN_CHROMIUM`` names another
CHROMIUM_FLAGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]
#: screenshots for docs/console.md are written only when this is set
SCREENSHOTS_ENV = "BTRUN_CONSOLE_SCREENSHOTS"
REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def chromium_path() -> str:
    """The chromium executable; skips the test where there is none (fails in CI)."""
    path = os.environ.get("BTRUN_CHROMIUM") or shutil.which("chromium")
    if path:
        return path
    if os.environ.get("CI"):
        pytest.fail("Debian's chromium is missing: .ci/run installs it (apt-get install chromium)")
    pytest.skip("no chromium on this machine: apt-get install chromium (CI installs it)")


@contextmanager
def browser_page() -> Iterator[Any]:
    """A fresh headless chromium page (a new profile every time)."""
    sync_api = pytest.importorskip("playwright.sync_api")
    exe = chromium_path()
    with sync_api.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=exe, headless=True, args=CHROMIUM_FLAGS)
        try:
            context = browser.new_context(viewport={"width": 1400, "height": 1000})
            page = context.new_page()
            errors: list[str] = []
            page.on("pageerror", lambda e: errors.append(str(e)))
            page.errors = errors  # type: ignore[attr-defined]
            yield page
        finally:
            browser.close()


@contextmanager
def console(runs: str, gallery: str | None = None) -> Iterator[Any]:
    """A console on ``runs`` served on 127.0.0.1 at a free port (its ``url``)."""
    from nodes.console.app import ConsoleConfig
    from nodes.console.cli import ConsoleServer

    server = ConsoleServer(ConsoleConfig(runs, TOKEN, gallery), "127.0.0.1", 0).start()
    try:
        yield server
    finally:
        server.stop()


def wait_for(check: Callable[[], Any], timeout_s: float = 20.0, what: str = "condition") -> Any:
    """Poll ``check`` until it returns something true; fail after ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    while True:
        value = check()
        if value:
            return value
        if time.monotonic() > deadline:
            pytest.fail(f"timed out after {timeout_s:g} s waiting for {what}")
        time.sleep(0.05)


def screenshot(page: Any, name: str) -> None:
    """docs/img/console_<name>.png, only when $BTRUN_CONSOLE_SCREENSHOTS is set."""
    if os.environ.get(SCREENSHOTS_ENV):
        page.screenshot(path=os.path.join(REPO, "docs", "img", f"console_{name}.png"))


def make_run(
    root: Any, name: str, rows: list[dict], planned: list[str], header: dict | None = None
):
    """A run folder ``root/name`` holding an inventory of ``rows`` (``planned`` places) and
    a tick log of one header line (the mission, plus ``header``)."""
    from nodes.inventory_log import write_inventory

    run = root / name
    run.mkdir(parents=True)
    head = {"mission": "missions/inventory.xml", **(header or {})}
    (run / "ticks.jsonl").write_text(json.dumps({"header": head}) + "\n")
    write_inventory(str(run), rows, planned)
    return run
