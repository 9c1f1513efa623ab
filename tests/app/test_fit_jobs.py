"""Fits as jobs: several at once up to ``max_concurrent_fits``, the rest queued with their place,
a stop for a queued or running fit, and an interruption at shutdown.

Each fit here waits at a gate the test opens (a wrapper around the real fit body,
:func:`app.services.fits.run_fit`), so what runs at once and what waits is seen without
relying on how long a fit takes; once through the gate the fit is the real one.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterator
from typing import Any

import pytest

from app import crud
from app.db import Database
from app.main import create_app
from app.services import fits
from app.services.jobs import Job
from tests.app.conftest import TestClient, experiment1_csv, make_settings
from tests.app.waits import wait_until

API = "/api/v1"
FIT = {
    "latent_dim": 1,
    "optimizer": "lbfgs",
    "restarts": 0,
    "seed": 0,
    "noise_model": "independent",
}


class Gates:
    """One gate per model id: the fit of that model waits there until the test opens it (or
    the job is stopped, which ends it at its checkpoint)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._gates: dict[int, threading.Event] = {}
        self.passed: list[int] = []

    def gate(self, model_id: int) -> threading.Event:
        with self._lock:
            return self._gates.setdefault(model_id, threading.Event())

    def open(self, model_id: int) -> None:
        self.gate(model_id).set()

    def wrap(self, real: Callable[..., Any]) -> Callable[..., Any]:
        def gated(request: fits.FitRequest, job: Job, report: Any) -> Any:
            gate = self.gate(request.model_id)
            while not gate.wait(0.01):
                job.checkpoint()
            self.passed.append(request.model_id)
            return real(request, job, report)

        return gated


@pytest.fixture
def gates(monkeypatch: pytest.MonkeyPatch) -> Gates:
    gates = Gates()
    monkeypatch.setattr(fits, "run_fit", gates.wrap(fits.run_fit))
    return gates


def client_with(tmp_path: Any, limit: int) -> TestClient:
    return TestClient(create_app(make_settings(tmp_path, max_concurrent_fits=limit)))


@pytest.fixture
def two(tmp_path: Any) -> Iterator[TestClient]:
    with client_with(tmp_path, 2) as client:
        yield client


@pytest.fixture
def one(tmp_path: Any) -> Iterator[TestClient]:
    with client_with(tmp_path, 1) as client:
        yield client


def upload(client: TestClient) -> int:
    response = client.post(
        f"{API}/datasets", content=experiment1_csv(), headers={"content-type": "text/csv"}
    )
    assert response.status_code == 201, response.text
    dataset_id: int = response.json()["id"]
    return dataset_id


def post_fit(client: TestClient, dataset_id: int) -> dict[str, Any]:
    response = client.post(f"{API}/models", json={"dataset_id": dataset_id, **FIT})
    assert response.status_code == 202, response.text
    accepted: dict[str, Any] = response.json()
    return accepted


def wait_for(
    client: TestClient,
    model_id: int,
    done: Callable[[dict[str, Any]], bool],
    timeout_s: float = 120,
) -> dict[str, Any]:
    return wait_until(client, f"{API}/models/{model_id}", done, timeout_s)


def test_with_a_limit_of_two_both_fits_run_at_once_and_the_second_does_not_wait(
    two: TestClient, gates: Gates
) -> None:
    dataset_id = upload(two)
    first, second = post_fit(two, dataset_id), post_fit(two, dataset_id)
    assert (first["status"], second["status"]) == ("fitting", "fitting")
    assert first["queue_position"] is None
    assert second["queue_position"] is None
    listing = {m["id"]: m for m in two.get(f"{API}/models").json()["data"]}
    assert [listing[m["id"]]["status"] for m in (first, second)] == ["fitting", "fitting"]
    # The second finishes while the first still holds its gate.
    gates.open(second["id"])
    done = wait_for(two, second["id"], lambda m: m["status"] != "fitting")
    assert done["status"] == "ready", done["reason"]
    assert two.get(f"{API}/models/{first['id']}").json()["status"] == "fitting"
    gates.open(first["id"])
    assert wait_for(two, first["id"], lambda m: m["status"] != "fitting")["status"] == "ready"
    assert gates.passed == [second["id"], first["id"]]


def test_with_a_limit_of_one_the_second_fit_is_queued_first_in_line_then_runs(
    one: TestClient, gates: Gates
) -> None:
    dataset_id = upload(one)
    first, second = post_fit(one, dataset_id), post_fit(one, dataset_id)
    assert first["status"] == "fitting"
    assert (second["status"], second["queue_position"]) == ("queued", 1)
    third = post_fit(one, dataset_id)
    assert (third["status"], third["queue_position"]) == ("queued", 2)
    shown = one.get(f"{API}/models/{second['id']}").json()
    assert (shown["status"], shown["queue_position"]) == ("queued", 1)
    listed = {
        m["id"]: m for m in one.get(f"{API}/models", params={"status": "queued"}).json()["data"]
    }
    assert {i: m["queue_position"] for i, m in listed.items()} == {second["id"]: 1, third["id"]: 2}
    # Stopping the queued second moves the third up; the second never fits.
    stopped = one.post(f"{API}/models/{second['id']}/stop")
    assert stopped.status_code == 200, stopped.text
    assert stopped.json()["status"] == "stopped"
    assert one.get(f"{API}/models/{third['id']}").json()["queue_position"] == 1
    gates.open(first["id"])
    gates.open(third["id"])
    assert wait_for(one, first["id"], lambda m: m["status"] == "ready")
    third_done = wait_for(one, third["id"], lambda m: m["status"] not in ("queued", "fitting"))
    assert third_done["status"] == "ready", third_done["reason"]
    assert third_done["queue_position"] is None
    second_done = one.get(f"{API}/models/{second['id']}").json()
    assert (second_done["status"], second_done["progress"]) == ("stopped", None)
    assert second["id"] not in gates.passed
    again = one.post(f"{API}/models/{second['id']}/stop")
    assert again.status_code == 409
    assert again.json()["current_state"] == "stopped"
    events = one.get(f"{API}/events?after=0&follow=false").text
    assert f'"model_id": {second["id"]}, "status": "queued"' in events


def test_a_running_fit_stops_at_its_next_progress_checkpoint(
    one: TestClient, monkeypatch: pytest.MonkeyPatch
) -> None:
    # The real fit, held after its first progress report until the test has asked it to stop.
    in_fit, go_on = threading.Event(), threading.Event()
    real = fits.run_fit

    def held_after_first_report(request: fits.FitRequest, job: Job, report: Any) -> Any:
        def report_and_hold(progress: Any, elapsed_s: float) -> None:
            report(progress, elapsed_s)
            if not in_fit.is_set():
                in_fit.set()
                assert go_on.wait(60)

        return real(request, job, report_and_hold)

    monkeypatch.setattr(fits, "run_fit", held_after_first_report)
    model = post_fit(one, upload(one))
    assert model["status"] == "fitting"
    assert in_fit.wait(60), "the fit reported no progress"
    assert one.post(f"{API}/models/{model['id']}/stop").json()["status"] == "stopped"
    go_on.set()
    jobs = one.app.state.context.jobs  # type: ignore[attr-defined]
    deadline = time.monotonic() + 60
    while jobs.handle("fit", model["id"]) is not None:
        assert time.monotonic() < deadline, "the stopped fit did not end"
        time.sleep(0.02)
    ended = one.get(f"{API}/models/{model['id']}").json()
    assert (ended["status"], ended["reason"]) == ("stopped", "stop requested")
    assert ended["progress"] is not None  # it was stopped inside the fit loop
    assert ended["log_likelihood"] is None  # and nothing of an unfinished fit was stored


def test_a_shutdown_fails_running_and_queued_fits_as_interrupted(
    tmp_path: Any, gates: Gates
) -> None:
    settings = make_settings(tmp_path, max_concurrent_fits=1)
    with TestClient(create_app(settings)) as client:
        dataset_id = upload(client)
        running, queued = post_fit(client, dataset_id), post_fit(client, dataset_id)
        assert (running["status"], queued["status"]) == ("fitting", "queued")
    with TestClient(create_app(settings)) as client:
        for model in (running, queued):
            ended = client.get(f"{API}/models/{model['id']}").json()
            assert (ended["status"], ended["reason"]) == ("failed", "interrupted")
    assert gates.passed == []


def test_a_restart_fails_the_fits_a_killed_server_left_queued_or_fitting(tmp_path: Any) -> None:
    settings = make_settings(tmp_path)
    with TestClient(create_app(settings)) as client:
        dataset_id = upload(client)
    database = Database(settings.database_url)
    with database.session() as session:  # what a killed server leaves behind
        left = {
            status: crud.create_model(
                session, dataset_id=dataset_id, status=status, latent_dim=1,
                optimizer="lbfgs", restarts=0, seed=None,
            ).id
            for status in ("queued", "fitting", "stopped")
        }  # fmt: skip
        session.commit()
    database.dispose()
    with TestClient(create_app(settings)) as client:
        after = {s: client.get(f"{API}/models/{i}").json() for s, i in left.items()}
        events = client.get(f"{API}/events?after=0&follow=false").text
    for status in ("queued", "fitting"):
        assert (after[status]["status"], after[status]["reason"]) == ("failed", "interrupted")
        assert f'"model_id": {left[status]}, "status": "failed"' in events
    assert after["stopped"]["status"] == "stopped"  # an ended fit is left as it was
