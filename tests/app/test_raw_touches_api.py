"""The API and raw touches: a model's features shown, scripted trials fed raw touches."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np

from app.documents.model import model_to_document
from app.documents.raw_touches import featurise, read_raw_touches
from app.main import create_app
from core.features.pipeline import fit_features
from core.gp.manifold import FitOptions, fit_manifold
from tests.app.conftest import TestClient, make_settings
from tests.app.test_raw_touches import raw_file, touch_line

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
        trial = client.post(
            f"{API}/trials", json={"model_id": model_id, "mode": "scripted", "seed": 1}
        ).json()
        line = json.loads(touch_line(np.random.default_rng(2), "fine", 200.0))
        response = client.post(
            f"{API}/trials/{trial['id']}/observations",
            json={"action": line["action"], "channels": line["channels"]},
        )
        assert response.status_code == 200, response.text
        assert response.json()["answer"] == "fine"
