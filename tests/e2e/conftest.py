"""Fixtures of the browser tests: the demo (web app + viser view) and headless Chromium.

Chromium is Debian's (``scripts/install_browser.sh``), driven by Playwright's Python package
through ``executable_path``; Playwright's own browser download is never used. Screenshots go to
``artifacts/screenshots/`` (test artefacts, not committed); with
``ACTIVETOUCH_UPDATE_DOCS_SCREENSHOTS=1`` the README's copies in ``docs/screenshots/`` are
refreshed too.
"""

from __future__ import annotations

import os
import shutil
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest
from rich.console import Console

from app.cli.demo import DemoOptions, DemoServer, DemoState
from tests.conftest import SETTLE_S

ROOT = Path(__file__).resolve().parents[2]
CHROMIUM = Path(os.environ.get("ACTIVETOUCH_CHROMIUM", "/usr/bin/chromium"))
CHROMIUM_ARGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]
SCREENSHOTS = ROOT / "artifacts" / "screenshots"
DOCS_SCREENSHOTS = ROOT / "docs" / "screenshots"
VIEWPORT = {"width": 1440, "height": 1000}
DOCS_FLAG = "ACTIVETOUCH_UPDATE_DOCS_SCREENSHOTS"


@dataclass
class Demo:
    """The running demo of a test module."""

    server: DemoServer
    state: DemoState

    def get(self, path: str) -> Any:
        """GET ``/api/v1{path}`` as JSON."""
        response = self.server.client.get(path)
        response.raise_for_status()
        return response.json()


@dataclass
class PageErrors:
    """JavaScript errors and failed requests seen by a page."""

    exceptions: list[str] = field(default_factory=list)
    console: list[str] = field(default_factory=list)


def save_screenshot(page: Any, name: str, docs: bool = False, **kwargs: Any) -> Path:
    """Screenshot to ``artifacts/screenshots/{name}.png`` (and the docs copy when asked)."""
    SCREENSHOTS.mkdir(parents=True, exist_ok=True)
    path = SCREENSHOTS / f"{name}.png"
    page.screenshot(path=str(path), **kwargs)
    if docs and os.environ.get(DOCS_FLAG) == "1":
        DOCS_SCREENSHOTS.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(path, DOCS_SCREENSHOTS / f"{name}.png")
    return path


@pytest.fixture(scope="module")
def browser() -> Iterator[Any]:
    """Headless Debian Chromium under Playwright, closed after the module that used it."""
    if not CHROMIUM.exists():
        pytest.fail(
            f"{CHROMIUM} is missing: run scripts/install_browser.sh (Debian's chromium package)."
        )
    from playwright.sync_api import sync_playwright

    with sync_playwright() as playwright:
        launched = playwright.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_ARGS)
        yield launched
        launched.close()


@contextmanager
def running_demo(
    database_dir: Path,
    settings_overrides: dict[str, Any] | None = None,
    **options: Any,
) -> Iterator[Demo]:
    """The demo on free loopback ports with a fresh SQLite file in ``database_dir``, prepared.

    Args:
        database_dir: Folder of the demo's database.
        settings_overrides: Server settings besides ``_env_file=None`` and
            ``settle_s=``:data:`SETTLE_S`.
        options: :class:`DemoOptions` fields instead of the defaults here (the simulated rig's
            ``default`` table, whose objects any touch tells apart, 10 touches per object at
            action std 1, ds = 2, a short fit: the UI flows, fast; the demo's own table needs
            100 touches per object, see ``bench/readme_screenshots.py``).
    """
    chosen: dict[str, Any] = {
        "host": "127.0.0.1",
        "port": 0,
        "viz_port": 0,
        "database_url": f"sqlite:///{database_dir / 'demo.db'}",
        "world": "rig",
        "table": "default",
        "touches_per_object": 10,
        "action_scale": 1.0,
        "latent_dim": 2,
        "restarts": 1,
        "max_iterations": 150,
        "seed": 0,
        "open_browser": False,
        **options,
    }
    server = DemoServer(
        DemoOptions(**chosen),
        console=Console(stderr=True, force_terminal=False),
        settings_overrides={"_env_file": None, "settle_s": SETTLE_S, **(settings_overrides or {})},
    )
    server.start()
    try:
        yield Demo(server=server, state=server.prepare())
    finally:
        server.stop()


@pytest.fixture(scope="session")
def demo(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Demo]:
    """The demo on free loopback ports with a fresh SQLite file, prepared (dataset + model).

    Collecting and fitting take half a minute, so every module that uses it shares one: a test
    may add to it (trials, collections) but must not count on being the first to.
    """
    with running_demo(tmp_path_factory.mktemp("demo")) as running:
        yield running


@pytest.fixture
def page_errors() -> PageErrors:
    """Errors collected by :func:`page`."""
    return PageErrors()


@pytest.fixture
def page(browser: Any, page_errors: PageErrors) -> Iterator[Any]:
    """A fresh browser page; the test fails if the page throws a JavaScript error."""
    context = browser.new_context(viewport=VIEWPORT, accept_downloads=True)
    created = context.new_page()
    created.set_default_timeout(20_000)
    created.on("pageerror", lambda error: page_errors.exceptions.append(str(error)))
    created.on(
        "console",
        lambda message: (
            page_errors.console.append(message.text) if message.type == "error" else None
        ),
    )
    yield created
    context.close()
    assert page_errors.exceptions == [], f"JavaScript errors: {page_errors.exceptions}"


def record_touch_counts(page: Any) -> None:
    """Record every touch count the trial page shows (``window.__touchCounts``), to see it
    update while a trial runs."""
    page.evaluate(
        """() => {
          window.__touchCounts = [];
          new MutationObserver(() => {
            const node = document.querySelector('[data-testid="trial-touches"]');
            if (node) window.__touchCounts.push(node.textContent);
          }).observe(document.getElementById("trial-facts"), {
            childList: true, subtree: true, characterData: true,
          });
        }"""
    )
