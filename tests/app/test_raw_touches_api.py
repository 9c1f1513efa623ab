"""The API and raw touches: a model's features shown, scripted trials fed raw touches."""

from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path
from typing import Any

import numpy as np

from app.documents.model import model_from_document, model_to_document
from app.documents.raw_touches import featurise, read_raw_touches
from app.main import create_app
from core.features.pipeline import fit_features
from core.gp.manifold import FitOptions, fit_manifold
from tests.app.conftest import TestClient, experiment1_csv, make_settings
from tests.app.test_raw_touches import raw_file, touch_line, twins_channel_model

API = "/api/v1"


def whole_touch_model(client: TestClient) -> int:
    touches = read_raw_touches(raw_file(8))
    pipeline = fit_features(touches.touches, touches.object_index, "whole")
    model = fit_manifold(
        featurise(touches, pipeline), 2, np.random.default_rng(0), FitOptions(restarts=0)
    )
    document = model_to_document(dataclasses.replace(model, features=pipeline))
    response = client.post(f"{API}/models/import", json=json.loads(json.dumps(document)))
    assert response.status_code == 201, response.text
    model_id: int = response.json()["id"]
    return model_id


def scripted_answer(
    client: TestClient, model_id: int, seed: int, surface: str, frequency_hz: float
) -> str:
    """The answer of a scripted trial on ``model_id`` after one raw touch of ``surface``."""
    trial = client.post(
        f"{API}/trials", json={"model_id": model_id, "mode": "scripted", "seed": 1}
    ).json()
    line = json.loads(touch_line(np.random.default_rng(seed), surface, frequency_hz))
    response = client.post(
        f"{API}/trials/{trial['id']}/observations",
        json={"action": line["action"], "channels": line["channels"]},
    )
    assert response.status_code == 200, response.text
    return str(response.json()["answer"])


def test_a_model_shows_its_features_and_a_scripted_trial_takes_raw_touches(
    client: TestClient,
) -> None:
    model_id = whole_touch_model(client)
    features = client.get(f"{API}/models/{model_id}").json()["features"]
    assert features["kind"] == "whole"
    assert features["channels"] == ["pressure_kpa", "electrode", "vibration"]
    assert features["reduced_features"] == 4 + 10 + 11
    assert features["output_names"][0] == "pc_1"
    assert "held-out touches recognised" in features["explanation"]
    trial = client.post(
        f"{API}/trials", json={"model_id": model_id, "mode": "scripted", "seed": 1}
    ).json()
    rng = np.random.default_rng(5)
    for _ in range(2):
        line = json.loads(touch_line(rng, "coarse", 50.0))
        response = client.post(
            f"{API}/trials/{trial['id']}/observations",
            json={"action": line["action"], "channels": line["channels"]},
        )
        assert response.status_code == 200, response.text
    assert response.json()["answer"] == "coarse"
    line["channels"]["vibration"]["samples"] = line["channels"]["vibration"]["samples"][:100]
    refused = client.post(
        f"{API}/trials/{trial['id']}/observations",
        json={"action": line["action"], "channels": line["channels"]},
    )
    assert refused.status_code == 422
    assert "'vibration': 100 samples" in refused.text
    both = client.post(
        f"{API}/trials/{trial['id']}/observations",
        json={"action": line["action"], "observation": [0.0], "channels": line["channels"]},
    )
    assert both.status_code == 422


def test_raw_touches_upload_and_come_back_to_be_featurised_again(client: TestClient) -> None:
    text = raw_file(3)
    response = client.post(
        f"{API}/datasets?name=raw",
        content=text.encode(),
        headers={"Content-Type": "application/x-ndjson"},
    )
    assert response.status_code == 201, response.text
    dataset = response.json()
    assert dataset["n_samples"] == 9
    assert dataset["observation_dim"] == 5  # pressure, 3 electrodes, vibration: their means
    back = client.get(f"{API}/datasets/{dataset['id']}/raw-touches")
    assert back.status_code == 200
    assert back.headers["content-type"].startswith("application/x-ndjson")
    again, original = read_raw_touches(back.text), read_raw_touches(text)
    assert again.object_names == original.object_names
    for a, b in zip(again.touches, original.touches, strict=True):
        for ca, cb in zip(a.channels, b.channels, strict=True):
            assert ca.rate_hz == cb.rate_hz
            np.testing.assert_array_equal(ca.samples, cb.samples)
    rows = text.splitlines()
    rows[6] = rows[6].replace('"rate_hz": 1000.0, ', "")
    before = client.get(f"{API}/datasets").json()["count"]
    refused = client.post(
        f"{API}/datasets",
        content="\n".join(rows).encode(),
        headers={"Content-Type": "application/x-ndjson"},
    )
    assert refused.status_code == 422
    assert "line 7" in refused.text
    assert "'vibration'" in refused.text
    assert client.get(f"{API}/datasets").json()["count"] == before


def test_a_stored_model_keeps_its_pipeline_after_a_restart(tmp_path: Path) -> None:
    settings = make_settings(tmp_path)
    with TestClient(create_app(settings)) as client:
        model_id = whole_touch_model(client)
    with TestClient(create_app(settings)) as client:  # a new server: the model is rebuilt
        assert client.get(f"{API}/models/{model_id}").json()["features"]["kind"] == "whole"
        assert scripted_answer(client, model_id, 2, "fine", 200.0) == "fine"


def test_a_raw_upload_is_checked_against_the_pipeline_it_is_meant_for(client: TestClient) -> None:
    short = raw_file(3) + touch_line(np.random.default_rng(1), "fine", 200.0, 100) + "\n"
    ndjson = {"Content-Type": "application/x-ndjson"}
    refused = client.post(f"{API}/datasets", content=short.encode(), headers=ndjson)
    assert refused.status_code == 422
    assert "line 10" in refused.text
    assert "'vibration': 100 samples, shorter than the pipeline's window of 256" in refused.text
    means = client.post(f"{API}/datasets?features=means", content=short.encode(), headers=ndjson)
    assert means.status_code == 201, means.text
    assert means.json()["n_samples"] == 10
    wrong = client.post(f"{API}/datasets?features=all", content=short.encode(), headers=ndjson)
    assert wrong.status_code == 422
    assert "features" in wrong.text


def wait_ready(client: TestClient, path: str, timeout_s: float = 180.0) -> dict[str, Any]:
    """Poll ``GET path`` until its job has ended; the body (asserting it did not fail)."""
    deadline = time.monotonic() + timeout_s
    while True:
        body: dict[str, Any] = client.get(path).json()
        if body["status"] in ("ready", "completed"):
            return body
        assert body["status"] not in ("failed", "stopped"), body
        assert time.monotonic() < deadline, f"{path}: still {body['status']}"
        time.sleep(0.05)


def upload_raw(client: TestClient, text: str) -> int:
    response = client.post(
        f"{API}/datasets", content=text.encode(), headers={"Content-Type": "application/x-ndjson"}
    )
    assert response.status_code == 201, response.text
    dataset_id: int = response.json()["id"]
    return dataset_id


FIT = {"latent_dim": 2, "restarts": 0, "noise_model": "independent", "seed": 0}


def test_a_stored_raw_dataset_is_fitted_from_its_whole_touches_without_uploading_again(
    tmp_path: Path,
) -> None:
    settings = make_settings(tmp_path)
    lines = raw_file(12).splitlines()
    with TestClient(create_app(settings)) as client:
        dataset_id = upload_raw(client, "\n".join(lines[:27]) + "\n")
        held_out = upload_raw(client, "\n".join(lines[27:]) + "\n")
        assert client.get(f"{API}/datasets/{dataset_id}").json()["observation_dim"] == 5
        fits = {
            kind: client.post(
                f"{API}/models", json={"dataset_id": dataset_id, "features": kind, **FIT}
            )
            for kind in ("whole", "means")
        }
        for response in fits.values():
            assert response.status_code == 202, response.text
        whole = wait_ready(client, f"{API}/models/{fits['whole'].json()['id']}")
        means = wait_ready(client, f"{API}/models/{fits['means'].json()['id']}")
        assert whole["features"]["kind"] == "whole"
        assert "held-out touches recognised" in whole["features"]["explanation"]
        dy = len(whole["features"]["output_names"])
        assert whole["observation_dim"] == dy == len(whole["hyperparameters"])
        assert means["features"]["kind"] == "means"
        assert means["observation_dim"] == 5
        document = client.get(f"{API}/models/{whole['id']}/export").json()
        assert document["features"]["kind"] == "whole"
        # The model's y are its pipeline's features of the stored series.
        touches = read_raw_touches("\n".join(lines[:27]) + "\n")
        pipeline = model_from_document(document).features
        assert pipeline is not None
        np.testing.assert_allclose(
            np.asarray(document["training_data"]["observations"]),
            featurise(touches, pipeline).observations,
        )
        evaluation = client.post(
            f"{API}/evaluations",
            json={
                "model_id": whole["id"],
                "world": "replay",
                "dataset_id": held_out,
                "policies": ["passive"],
                "trials_per_target": 2,
                "steps": 1,
            },
        )
        assert evaluation.status_code == 202, evaluation.text
        ended = wait_ready(client, f"{API}/evaluations/{evaluation.json()['id']}")
        # Held-out raw touches went through the model's pipeline (means would not fit its dy).
        assert ended["summary"]["policies"]["passive"]["accuracy_by_touch"][0] >= 2 / 3
    with TestClient(create_app(settings)) as client:  # a new server rebuilds the model
        again = client.get(f"{API}/models/{whole['id']}").json()
        assert again["features"] == whole["features"]
        assert client.get(f"{API}/models/{whole['id']}/export").json() == document
        assert scripted_answer(client, whole["id"], 4, "medium", 100.0) == "medium"


def test_features_need_raw_touches_that_the_pipeline_can_take(client: TestClient) -> None:
    csv = client.post(
        f"{API}/datasets",
        content=experiment1_csv(touches_per_object=4),
        headers={"Content-Type": "text/csv"},
    ).json()["id"]
    refused = client.post(f"{API}/models", json={"dataset_id": csv, "features": "whole", **FIT})
    assert refused.status_code == 422
    assert "sample 1 has no raw series" in refused.text
    short = raw_file(3) + touch_line(np.random.default_rng(1), "fine", 200.0, 100) + "\n"
    upload = client.post(
        f"{API}/datasets?features=means",
        content=short.encode(),
        headers={"Content-Type": "application/x-ndjson"},
    )
    raw = upload.json()["id"]
    refused = client.post(f"{API}/models", json={"dataset_id": raw, "features": "whole", **FIT})
    assert refused.status_code == 422
    assert "sample 10: channel 'vibration': 100 samples" in refused.text
    means_dim = client.post(
        f"{API}/models",
        json={"dataset_id": raw, "features": "means", "feature_dim": 3, **FIT},
    )
    assert means_dim.status_code == 422
    assert "feature_dim" in means_dim.text
    assert client.get(f"{API}/models").json()["count"] == 0


def test_rig_trials_of_a_model_with_features_need_the_channels_it_reads(tmp_path: Path) -> None:
    document = json.loads(json.dumps(model_to_document(twins_channel_model())))
    for table, expected in (("twins", 201), ("default", 422)):
        settings = make_settings(tmp_path / table, sim_table=table)
        with TestClient(create_app(settings)) as client:
            model_id = client.post(f"{API}/models/import", json=document).json()["id"]
            response = client.post(
                f"{API}/trials",
                json={
                    "model_id": model_id,
                    "mode": "simulated",
                    "target": "twin_fine_edge",
                    "max_steps": 1,
                    "simulation": {"world": "rig"},
                },
            )
            assert response.status_code == expected, response.text
    assert "the model's features read" in response.text
