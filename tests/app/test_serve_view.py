"""``activetouch serve`` runs the live 3D view beside the app: the dashboard finds it at
``GET /api/v1/viz``, it follows a trial run through the API to its end, and ``--no-viz``
leaves it out."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import httpx
import numpy as np
import pytest

from app.cli.serve import ServedApp, listening_url
from app.viz.follower import wait_for_belief_mean
from tests.app.conftest import experiment1_document, make_settings
from tests.app.served import start_in_thread
from tests.app.waits import finished, wait_until

API = "/api/v1"


@pytest.fixture
def served(tmp_path: Path, request: pytest.FixtureRequest) -> Iterator[ServedApp]:
    """The app on a free port of 127.0.0.1, in a thread, with or without the view."""
    viz = bool(getattr(request, "param", True))
    served = ServedApp(make_settings(tmp_path, port=0, viz=viz, viz_port=0), log_level="warning")
    thread = start_in_thread(served.server, served.run)
    try:
        yield served
    finally:
        served.server.should_exit = True
        thread.join(timeout=30)
        assert not thread.is_alive(), "the server did not stop"


def test_serve_runs_the_view_and_it_follows_a_trial(served: ServedApp) -> None:
    assert served.live is not None
    view = served.live.view
    base = listening_url(served.server, "127.0.0.1")
    with httpx.Client(base_url=base, timeout=30) as client:
        info = client.get(f"{API}/viz").json()
        assert info["port"] == view.port > 0
        page = httpx.get(f"http://127.0.0.1:{view.port}/", timeout=30)
        assert page.status_code == 200
        assert "<html" in page.text.lower()
        imported = client.post(f"{API}/models/import", json=experiment1_document(0))
        assert imported.status_code == 201, imported.text
        created = client.post(
            f"{API}/trials",
            json={
                "model_id": imported.json()["id"], "mode": "simulated", "target": "O2",
                "seed": 4, "max_steps": 4,
                "simulation": {"world": "exp1", "step_interval_s": 0.0},
            },
        )  # fmt: skip
        assert created.status_code == 201, created.text
        trial = wait_until(client, f"{API}/trials/{created.json()['id']}", finished, 60)
    assert trial["status"] == "completed"
    final_mean = np.asarray(trial["steps"][-1]["belief"]["mean"])
    wait_for_belief_mean(view, final_mean)
    assert view.model is not None
    assert list(view.model.object_names) == ["O1", "O2", "O3", "O4"]
    assert view.belief is not None
    np.testing.assert_allclose(view.belief.mean, final_mean, rtol=1e-12)


@pytest.mark.parametrize("served", [False], indirect=True)
def test_no_viz_serves_the_app_alone(served: ServedApp) -> None:
    assert served.live is None
    base = listening_url(served.server, "127.0.0.1")
    assert httpx.get(f"{base}{API}/viz", timeout=30).status_code == 404
    assert httpx.get(f"{base}{API}/health", timeout=30).status_code == 200


@pytest.mark.parametrize(
    ("host", "expected"),
    [("0.0.0.0", "127.0.0.1"), ("::", "127.0.0.1"), ("::1", "[::1]"), ("10.0.0.5", "10.0.0.5")],
)
def test_listening_url_names_an_address_this_machine_can_reach(
    tmp_path: Path, host: str, expected: str
) -> None:
    served = ServedApp(make_settings(tmp_path, port=8123, viz=False))
    assert listening_url(served.server, host) == f"http://{expected}:8123"
