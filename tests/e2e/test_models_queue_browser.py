"""The Models page shows a running fit's time left, a fit waiting for its turn (queued, with its
place in the queue) and stops it with a click.

The server fits one model at a time here (``max_concurrent_fits=1``) and the first fit waits at
a gate the test holds shut (a wrapper around :func:`app.services.fits.run_fit`), so the second
stays queued for as long as the page is looked at.
"""

from __future__ import annotations

import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest
import uvicorn

from app.cli.serve import GracefulServer, listening_url
from app.config import PROJECT_ROOT
from app.main import create_app
from app.services import fits
from app.services.jobs import Job
from core.gp import FitProgress
from tests.app.conftest import experiment1_csv, make_settings
from tests.app.served import start_in_thread

API = "/api/v1"


def expect(target: Any) -> Any:
    from playwright.sync_api import expect as playwright_expect

    return playwright_expect(target)


@pytest.fixture
def gate(monkeypatch: pytest.MonkeyPatch) -> Iterator[threading.Event]:
    opened = threading.Event()
    real = fits.run_fit

    def gated(request: fits.FitRequest, job: Job, report: Any) -> Any:
        # A quarter of the fit done after 20 s: a minute left.
        report(FitProgress(0, 3, 10, -5.0, -5.0, phase="independent: screen", fraction=0.25), 20.0)
        while not opened.wait(0.01):
            job.checkpoint()
        return real(request, job, report)

    monkeypatch.setattr(fits, "run_fit", gated)
    yield opened
    opened.set()


@pytest.fixture
def base_url(tmp_path: Path, gate: threading.Event) -> Iterator[str]:
    settings = make_settings(
        tmp_path, max_concurrent_fits=1, frontend_dir=PROJECT_ROOT / "frontend"
    )
    config = uvicorn.Config(create_app(settings), host="127.0.0.1", port=0, log_level="warning")
    server = GracefulServer(config)
    thread = start_in_thread(server)
    try:
        yield listening_url(server, "127.0.0.1")
    finally:
        gate.set()
        server.should_exit = True
        thread.join(timeout=30)


def test_a_queued_fit_shows_its_place_and_stops_from_the_page(page: Any, base_url: str) -> None:
    with httpx.Client(base_url=f"{base_url}{API}", timeout=30) as api:
        dataset = api.post(
            "/datasets", content=experiment1_csv(), headers={"content-type": "text/csv"}
        ).json()
        body = {"dataset_id": dataset["id"], "latent_dim": 1, "restarts": 0, "seed": 0}
        first, second = api.post("/models", json=body).json(), api.post("/models", json=body).json()
        assert (first["status"], second["status"]) == ("fitting", "queued")
        page.goto(f"{base_url}/?viz=off#models")
        running = page.get_by_test_id("fit-running")
        expect(running).to_contain_text(f"Model #{first['id']} fitting")
        expect(running).to_contain_text("about 1 min 00 s left of the fit")
        queued = page.get_by_test_id("fit-queued")
        expect(queued).to_contain_text(f"Model #{second['id']} queued: number 1 in the queue")
        expect(page.get_by_test_id("queue-position")).to_have_text(" #1")
        queued.get_by_test_id("fit-stop").click()
        expect(page.get_by_test_id("fit-queued")).to_have_count(0)
        assert api.get(f"/models/{second['id']}").json()["status"] == "stopped"
        assert api.get(f"/models/{first['id']}").json()["status"] == "fitting"
