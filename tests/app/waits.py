"""Waiting on the REST API in tests: poll a resource until it reaches the state a test needs."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any, Protocol

UNFINISHED = ("queued", "running", "paused")


class _Getter(Protocol):
    def get(self, url: str) -> Any: ...


def poll(
    fetch: Callable[[], dict[str, Any]],
    done: Callable[[dict[str, Any]], bool],
    timeout_s: float = 120.0,
    what: str = "the resource",
) -> dict[str, Any]:
    """Call ``fetch()`` (a resource's JSON) until ``done(body)``; return that body.

    Raises:
        AssertionError: ``done`` still false after ``timeout_s``; names ``what`` and the last body.
    """
    deadline = time.monotonic() + timeout_s
    while True:
        body = fetch()
        if done(body):
            return body
        assert time.monotonic() < deadline, (
            f"{what}: still {body.get('status')} after {timeout_s:g} s: {body}"
        )
        time.sleep(0.05)


def wait_until(
    client: _Getter,
    path: str,
    done: Callable[[dict[str, Any]], bool],
    timeout_s: float = 120.0,
) -> dict[str, Any]:
    """Poll ``GET path`` (a TestClient or an httpx client) until ``done(body)``; return the body."""
    return poll(lambda: client.get(path).json(), done, timeout_s, path)


def finished(body: dict[str, Any]) -> bool:
    """Whether a run (trial, collection, evaluation) has reached a final status."""
    return body["status"] not in UNFINISHED


def completed_collection(client: Any, body: dict[str, Any]) -> dict[str, Any]:
    """Start ``POST /api/v1/collections`` with ``body`` and wait until it completed; the run."""
    created = client.post("/api/v1/collections", json=body)
    assert created.status_code == 201, created.text
    run: dict[str, Any] = wait_until(
        client, f"/api/v1/collections/{created.json()['id']}", finished
    )
    assert run["status"] == "completed", run
    return run


def completed_rig_trial(client: Any, document: dict[str, Any], **fields: Any) -> dict[str, Any]:
    """Import the model ``document``, run a simulated trial of it on the rig world with
    ``fields`` (target, max_steps, ...), wait until it completed; the trial."""
    imported = client.post("/api/v1/models/import", json=document)
    assert imported.status_code == 201, imported.text
    body = {"model_id": imported.json()["id"], "mode": "simulated", "tolerance": 0.0, "seed": 1,
            "simulation": {"world": "rig"}, **fields}  # fmt: skip
    created = client.post("/api/v1/trials", json=body)
    assert created.status_code == 201, created.text
    trial: dict[str, Any] = wait_until(client, f"/api/v1/trials/{created.json()['id']}", finished)
    assert trial["status"] == "completed", trial
    return trial
