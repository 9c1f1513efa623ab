"""Models: background fit with progress events, status, latents, hyperparameters."""

from __future__ import annotations

import json
from typing import Any

from app.db.tables import ModelRecord
from tests.app.conftest import TestClient, experiment1_csv
from tests.app.waits import wait_until

API = "/api/v1"


def upload(client: TestClient, touches_per_object: int = 10) -> int:
    response = client.post(
        f"{API}/datasets",
        content=experiment1_csv(touches_per_object=touches_per_object),
        headers={"content-type": "text/csv"},
    )
    assert response.status_code == 201
    dataset_id: int = response.json()["id"]
    return dataset_id


def wait_ready(client: TestClient, model_id: int, timeout_s: float = 120) -> dict[str, Any]:
    return wait_until(
        client, f"{API}/models/{model_id}", lambda m: m["status"] != "fitting", timeout_s
    )


def test_fit_in_background_with_progress(client: TestClient) -> None:
    dataset_id = upload(client)
    accepted = client.post(
        f"{API}/models",
        json={"dataset_id": dataset_id, "latent_dim": 1, "optimizer": "lbfgs", "restarts": 0,
              "seed": 0},
    )  # fmt: skip
    assert accepted.status_code == 202
    assert accepted.json()["status"] == "fitting"
    model = wait_ready(client, accepted.json()["id"])
    assert model["status"] == "ready", model["reason"]
    assert [o["name"] for o in model["objects"]] == ["O1", "O2", "O3", "O4"]
    assert all(len(o["latent"]) == 1 for o in model["objects"])
    assert len(model["hyperparameters"]) == 3
    assert model["fit_seconds"] > 0
    assert model["log_likelihood"] == model["progress"]["best_log_likelihood"]
    # The last progress: the fit (no selection) done, nothing left.
    assert model["progress"]["stage"] == "fit"
    assert model["progress"]["fraction"] == 1.0
    assert model["progress"]["remaining_s"] == 0.0
    events = client.get(f"{API}/events?after=0&follow=false").text
    assert '"type": "model.progress"' in events
    progress = [json.loads(line.removeprefix("data: ")) for line in events.splitlines()
                if line.startswith("data: ") and '"model.progress"' in line]  # fmt: skip
    fractions = [p["data"]["fraction"] if "data" in p else p["fraction"] for p in progress]
    assert fractions
    assert fractions == sorted(fractions)
    assert all(0.0 <= f <= 1.0 for f in fractions)
    assert '"status": "ready"' in events
    listing = client.get(f"{API}/models", params={"status": "ready"}).json()
    assert listing["count"] == 1
    # The fit's posterior is recorded on the row (rebuilt from it once out of the cache).
    context = client.app.state.context  # type: ignore[attr-defined]
    with context.database.session() as session:
        row = session.get(ModelRecord, model["id"])
        assert row is not None
        assert row.posterior is not None
        assert row.posterior["structure"] == "dense"  # random actions, N = 40
        # The default noise model "auto" standardised the features (and chose a kind).
        assert row.posterior["noise_model"]["kind"] in ("independent", "correlated")
    exported = client.get(f"{API}/models/{model['id']}/export").json()
    assert exported["posterior"] == {"structure": "dense"}
    assert exported["noise_model"]["kind"] == model["noise_model"]["kind"]
    assert model["noise_model"]["note"].startswith("auto: ")
    assert model["latent_selection"] is None


def test_fit_requests_are_checked(client: TestClient) -> None:
    missing = client.post(f"{API}/models", json={"dataset_id": 42, "latent_dim": 1})
    assert missing.status_code == 404
    bad = client.post(f"{API}/models", json={"dataset_id": 1, "latent_dim": 0})
    assert bad.status_code == 422
    assert bad.json()["detail"][0]["loc"][:2] == ["body", "latent_dim"]
    optimizer = client.post(f"{API}/models", json={"dataset_id": 1, "optimizer": "sgd"})
    assert optimizer.status_code == 422
    assert client.get(f"{API}/models/7").status_code == 404
    assert client.get(f"{API}/models/7/export").status_code == 404


def test_too_many_touches_for_this_server(tmp_path) -> None:  # type: ignore[no-untyped-def]
    from app.main import create_app
    from tests.app.conftest import make_settings

    with TestClient(create_app(make_settings(tmp_path, max_training_touches=20))) as client:
        dataset_id = upload(client, touches_per_object=6)
        response = client.post(f"{API}/models", json={"dataset_id": dataset_id})
        assert response.status_code == 422
        assert "24 touches" in response.json()["detail"]


def test_tied_kernels_reach_the_fit_and_are_recorded(client: TestClient) -> None:
    dataset_id = upload(client)
    unknown = client.post(f"{API}/models", json={"dataset_id": dataset_id, "kernels": "shared"})
    assert unknown.status_code == 422
    assert unknown.json()["detail"][0]["loc"][:2] == ["body", "kernels"]
    accepted = client.post(
        f"{API}/models",
        json={"dataset_id": dataset_id, "latent_dim": 1, "restarts": 0, "seed": 0,
              "kernels": "tied"},
    )  # fmt: skip
    assert accepted.status_code == 202
    model = wait_ready(client, accepted.json()["id"])
    assert model["status"] == "ready", model["reason"]
    assert model["diagnostics"]["kernels"] == "tied"
    lengthscales = {tuple(h["latent_lengthscales"]) for h in model["hyperparameters"]}
    assert len(lengthscales) == 1  # shared by the three features
    exported = client.get(f"{API}/models/{model['id']}/export").json()
    assert exported["diagnostics"]["kernels"] == "tied"
