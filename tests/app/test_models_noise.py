"""POST /models with a noise model and latent_dim "auto"; GET /models/{id} reports both."""

from __future__ import annotations

import json

import numpy as np

from app.config import Settings
from app.documents.model import model_to_document
from app.main import create_app
from tests.app.conftest import TestClient
from tests.app.test_documents_noise import correlated_model
from tests.app.test_models import API, upload, wait_ready


def test_fit_with_a_correlated_noise_model_is_reported(client: TestClient) -> None:
    dataset_id = upload(client)
    accepted = client.post(
        f"{API}/models",
        json={"dataset_id": dataset_id, "latent_dim": 1, "restarts": 0, "seed": 0,
              "noise_model": "correlated"},
    )  # fmt: skip
    assert accepted.status_code == 202
    model = wait_ready(client, accepted.json()["id"])
    assert model["status"] == "ready", model["reason"]
    noise = model["noise_model"]
    assert noise["kind"] == "correlated"
    correlation = np.asarray(noise["correlation"])
    assert correlation.shape == (3, 3)
    np.testing.assert_allclose(np.diag(correlation), 1.0)
    assert noise["note"].startswith("correlated (as asked)")
    exported = client.get(f"{API}/models/{model['id']}/export").json()
    assert exported["noise_model"]["kind"] == "correlated"


def test_latent_dim_auto_reports_every_candidate(client: TestClient) -> None:
    dataset_id = upload(client, touches_per_object=8)
    accepted = client.post(
        f"{API}/models",
        json={"dataset_id": dataset_id, "latent_dim": "auto", "restarts": 0, "seed": 0,
              "noise_model": "independent"},
    )  # fmt: skip
    assert accepted.status_code == 202
    assert client.get(f"{API}/models/{accepted.json()['id']}").json()["latent_dim"] in (0, 1, 2, 3)
    model = wait_ready(client, accepted.json()["id"], timeout_s=300)
    assert model["status"] == "ready", model["reason"]
    selection = model["latent_selection"]
    assert [c["latent_dim"] for c in selection["candidates"]] == [1, 2, 3]  # L = 4
    assert selection["n_folds"] == 5
    assert all(len(c["fold_scores"]) == 5 for c in selection["candidates"])
    assert model["latent_dim"] == selection["chosen"]
    assert len(model["objects"][0]["latent"]) == selection["chosen"]
    assert f"ds = {selection['chosen']}" in selection["explanation"]
    exported = client.get(f"{API}/models/{model['id']}/export").json()
    assert exported["latent_selection"] == selection


def test_latent_dim_auto_needs_four_touches_per_object(client: TestClient) -> None:
    dataset_id = upload(client, touches_per_object=3)
    response = client.post(f"{API}/models", json={"dataset_id": dataset_id, "latent_dim": "auto"})
    assert response.status_code == 422
    assert "at least 4 touches" in response.text
    wrong = client.post(f"{API}/models", json={"dataset_id": dataset_id, "noise_model": "full"})
    assert wrong.status_code == 422


def test_imported_correlated_model_survives_a_fresh_app(settings: Settings) -> None:
    original = correlated_model()
    document = json.loads(json.dumps(model_to_document(original)))
    with TestClient(create_app(settings)) as client:
        created = client.post(f"{API}/models/import", json=document)
        assert created.status_code == 201, created.text
        model_id = created.json()["id"]
        assert created.json()["noise_model"]["kind"] == "correlated"
    with TestClient(create_app(settings)) as client:  # empty cache: rebuilt from the row
        exported = client.get(f"{API}/models/{model_id}/export").json()
        context = client.app.state.context  # type: ignore[attr-defined]
        with context.database.session() as session:
            rebuilt = context.models.load(session, model_id)
    assert exported["noise_model"] == document["noise_model"]
    np.testing.assert_array_equal(
        exported["training_data"]["observations"], document["training_data"]["observations"]
    )
    assert rebuilt.transform is not None
    assert rebuilt.log_likelihood == original.log_likelihood


def test_a_model_without_transform_reports_identity(client: TestClient) -> None:
    from core.gp.posterior import condition
    from tests.app.posterior_cases import HYPER, LATENTS, random_data

    document = json.loads(json.dumps(model_to_document(condition(random_data(), LATENTS, HYPER))))
    created = client.post(f"{API}/models/import", json=document)
    assert created.status_code == 201
    assert created.json()["noise_model"]["kind"] == "identity"
    assert created.json()["latent_selection"] is None


def test_a_server_fit_carries_the_latent_uncertainty_unless_asked_not_to(
    client: TestClient,
) -> None:
    """The server's fits calibrate as ``activetouch fit`` does (core.recognition.calibrate)."""
    dataset_id = upload(client)
    exported, model_ids = {}, {}
    for latent_uncertainty, tempering in ((True, True), (False, False)):
        accepted = client.post(
            f"{API}/models",
            json={"dataset_id": dataset_id, "latent_dim": 1, "restarts": 0, "seed": 0,
                  "noise_model": "independent", "latent_uncertainty": latent_uncertainty,
                  "tempering": tempering},
        )  # fmt: skip
        assert accepted.status_code == 202
        model = wait_ready(client, accepted.json()["id"])
        assert model["status"] == "ready", model["reason"]
        exported[latent_uncertainty] = client.get(f"{API}/models/{model['id']}/export").json()
        model_ids[latent_uncertainty] = model["id"]
    covariance = np.asarray(exported[True]["latent_uncertainty"]["covariance"])
    assert covariance.shape == (4, 1, 1)
    assert np.all(covariance > 0)
    public = client.get(f"{API}/models/{model_ids[True]}").json()["latent_uncertainty"]
    np.testing.assert_allclose(public["std"], np.sqrt(covariance[:, :, 0]))
    assert client.get(f"{API}/models/{model_ids[False]}").json()["latent_uncertainty"] is None
    assert 0 < exported[True]["tempering"]["exponent"] <= 1
    assert "latent_uncertainty" not in exported[False]
    assert "tempering" not in exported[False]
    default = client.post(f"{API}/models", json={"dataset_id": dataset_id, "latent_dim": 1})
    assert default.status_code == 202
    assert wait_ready(client, default.json()["id"])["status"] == "ready"
    document = client.get(f"{API}/models/{default.json()['id']}/export").json()
    assert "latent_uncertainty" in document
