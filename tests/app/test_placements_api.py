"""The server records placements as ``activetouch collect`` does: collections store each touch's
placement, datasets carry them in and out (CSV, JSON, raw touches), and a server fit estimates the
placement effect from them."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

import numpy as np

from app.documents.model import model_from_document
from app.documents.training_csv import read_training_csv, write_training_csv
from app.main import create_app
from core.evaluation.reference_model import experiment1_at_true_latents
from core.gp import estimate_placement_variance, estimate_shift_variance
from core.types import TrainingData
from tests.app.conftest import TestClient, experiment1_csv, make_settings
from tests.app.test_raw_touches import raw_file
from tests.app.waits import finished, wait_until

API = "/api/v1"
CUPS = ["paper_cup", "bumpy_glass", "stainless_cup"]
CSV = {"content-type": "text/csv"}


def start(client: TestClient, **fields: Any) -> Any:
    """``POST /collections`` of the three cups with ``fields``."""
    body = {"objects": [{"name": n, "slot": i} for i, n in enumerate(CUPS)], "seed": 5, **fields}
    return client.post(f"{API}/collections", json=body)


def collected(client: TestClient, **fields: Any) -> tuple[dict[str, Any], TrainingData]:
    """Run a collection of the three cups to its end; the run and its dataset (CSV export)."""
    created = start(client, **fields)
    assert created.status_code == 201, created.text
    run = wait_until(client, f"{API}/collections/{created.json()['id']}", finished)
    assert run["status"] == "completed", run
    text = client.get(f"{API}/datasets/{run['dataset_id']}/export").text
    assert text.startswith("object,placement,time_s,duration_s,x_1")
    return run, read_training_csv(text)


def placements_of(data: TrainingData, obj: int) -> list[int]:
    assert data.placement_index is not None
    return data.placement_index[data.object_index == obj].tolist()


def test_a_collection_records_placements_in_every_stage(client: TestClient) -> None:
    # The default: adaptive, 8 touches in stages of 4, 2, 2, three placements for every four
    # touches (a pair and two singles, two singles, a pair).
    run, data = collected(client, samples_per_object=8, action_scale=0.5)
    assert run["params"]["action_design"] == "adaptive"
    assert run["params"]["placements"] == 6
    runs = [0, 0, 1, 2, 3, 4, 5, 5]
    for obj in range(len(CUPS)):
        assert placements_of(data, obj) == runs
    # The table turns between placements only: a pair's touches follow each other.
    order = [obj for p in range(6) for obj in range(len(CUPS)) for _ in range(runs.count(p))]
    np.testing.assert_array_equal(data.object_index, order)
    # Runs: 3 placements, one per stage: the table turns only between placements.
    run, data = collected(client, samples_per_object=6, action_scale=0.5, placements=3)
    assert run["params"]["placements"] == 3
    for obj in range(len(CUPS)):
        assert placements_of(data, obj) == [0, 0, 0, 1, 1, 2]
    # A placement's touches follow each other: the table turns only between placements.
    keys = list(zip(data.object_index.tolist(), data.placement_index.tolist(), strict=True))
    assert sum(keys[k] != keys[k - 1] for k in range(1, len(keys))) == 3 * len(CUPS) - 1
    # The JSON export and the raw touches carry the same numbers.
    samples = client.get(f"{API}/datasets/{run['dataset_id']}/export?format=json").json()
    assert [s["placement"] for s in samples["samples"]] == data.placement_index.tolist()
    raw = client.get(f"{API}/datasets/{run['dataset_id']}/raw-touches").text.splitlines()
    assert [json.loads(line)["placement"] for line in raw] == data.placement_index.tolist()
    # Named placements with the random design: two per object, two touches in a row at each.
    run, data = collected(
        client, samples_per_object=4, action_design="random", placements=2, action_scale=0.5
    )
    assert run["params"]["placements"] == 2
    np.testing.assert_array_equal(data.object_index, [0, 0, 1, 1, 2, 2] * 2)
    for obj in range(len(CUPS)):
        assert placements_of(data, obj) == [0, 0, 1, 1]
    events = client.get(f"{API}/events?after=0&follow=false").text
    assert '"placement": 1' in events  # each collection.progress event says its placement


def test_bad_placements_are_refused_and_nothing_is_stored(client: TestClient) -> None:
    for fields, needle in (
        ({"samples_per_object": 4, "action_design": "random", "placements": 5}, "1..4"),
        ({"samples_per_object": 6, "placements": 2}, "3 stages"),  # adaptive: 3 stages
        ({"samples_per_object": 4, "placements": 0}, "placements"),
    ):
        refused = start(client, **fields)
        assert refused.status_code == 422, refused.text
        assert "placements" in refused.text
        assert needle in refused.text
    assert client.get(f"{API}/collections").json()["count"] == 0
    assert client.get(f"{API}/datasets").json()["count"] == 0


def placed_data(seed: int = 1) -> TrainingData:
    """Experiment 1's touches (4 objects, 20 each), 4 placements per object of 5 touches, each
    placement shifting its touches alike."""
    rng = np.random.default_rng(0)
    base = experiment1_at_true_latents(seed=seed, touches_per_object=20).data
    placement = np.tile(np.repeat(np.arange(4), 5), 4)
    observations = base.observations.copy()
    for obj in range(4):
        for p in range(4):
            rows = (base.object_index == obj) & (placement == p)
            observations[rows] += rng.normal(0.0, 0.1, size=3)
    return TrainingData(base.object_names, base.object_index, base.actions, observations, placement)


def test_datasets_keep_placements_in_and_out(client: TestClient) -> None:
    data = placed_data()
    text = write_training_csv(data)
    created = client.post(f"{API}/datasets", content=text, headers=CSV)
    assert created.status_code == 201, created.text
    dataset_id = created.json()["id"]
    assert client.get(f"{API}/datasets/{dataset_id}/export").text == text
    exported = client.get(f"{API}/datasets/{dataset_id}/export?format=json").json()
    assert [s["placement"] for s in exported["samples"]] == data.placement_index.tolist()
    again = client.post(f"{API}/datasets", json=exported)  # the JSON format round trips too
    assert again.status_code == 201, again.text
    assert client.get(f"{API}/datasets/{again.json()['id']}/export").text == text
    # A CSV without the column stays without it.
    plain = experiment1_csv(touches_per_object=3)
    dataset = client.post(f"{API}/datasets", content=plain, headers=CSV).json()
    assert client.get(f"{API}/datasets/{dataset['id']}/export").text == plain
    samples = client.get(f"{API}/datasets/{dataset['id']}/export?format=json").json()["samples"]
    assert all("placement" not in s for s in samples)
    # JSON samples give a placement on all or none.
    mixed = exported["samples"][:4]
    del mixed[1]["placement"]
    refused = client.post(f"{API}/datasets", json={"samples": mixed})
    assert refused.status_code == 422, refused.text
    assert "samples[1].placement" in refused.text
    negative = [dict(s, placement=-1) for s in exported["samples"][:4]]
    assert client.post(f"{API}/datasets", json={"samples": negative}).status_code == 422


def test_raw_touches_keep_their_placement(client: TestClient) -> None:
    lines = raw_file(4).splitlines()
    placed = [json.dumps({**json.loads(line), "placement": k // 6}) for k, line in enumerate(lines)]
    ndjson = {"Content-Type": "application/x-ndjson"}
    created = client.post(f"{API}/datasets", content="\n".join(placed), headers=ndjson)
    assert created.status_code == 201, created.text
    dataset_id = created.json()["id"]
    back = client.get(f"{API}/datasets/{dataset_id}/raw-touches").text.splitlines()
    assert [json.loads(line)["placement"] for line in back] == [k // 6 for k in range(12)]
    data = read_training_csv(client.get(f"{API}/datasets/{dataset_id}/export").text)
    np.testing.assert_array_equal(data.placement_index, [k // 6 for k in range(12)])
    # Without placements the lines stay without; a bad or partial placement names its line.
    plain = client.post(f"{API}/datasets", content="\n".join(lines), headers=ndjson).json()
    back = client.get(f"{API}/datasets/{plain['id']}/raw-touches").text.splitlines()
    assert all("placement" not in json.loads(line) for line in back)
    for edited, needle in (
        ([*placed[:2], lines[2], *placed[3:]], "line 3: 'placement' is missing"),
        ([*placed[:4], json.dumps({**json.loads(lines[4]), "placement": -2})], "line 5"),
        ([*placed[:1], json.dumps({**json.loads(lines[1]), "placement": "a"})], "line 2"),
    ):
        refused = client.post(f"{API}/datasets", content="\n".join(edited), headers=ndjson)
        assert refused.status_code == 422, refused.text
        assert needle in refused.text


def fit(client: TestClient, dataset_id: int, **options: Any) -> dict[str, Any]:
    accepted = client.post(
        f"{API}/models",
        json={"dataset_id": dataset_id, "latent_dim": 1, "restarts": 0, "seed": 0,
              "noise_model": "independent", **options},
    )  # fmt: skip
    assert accepted.status_code == 202, accepted.text
    model = wait_until(
        client, f"{API}/models/{accepted.json()['id']}", lambda m: m["status"] != "fitting"
    )
    assert model["status"] == "ready", model["reason"]
    return model


def test_a_server_fit_estimates_the_placement_effect(tmp_path: Path) -> None:
    settings = make_settings(tmp_path)
    with TestClient(create_app(settings)) as client:
        placed = client.post(f"{API}/datasets", content=write_training_csv(placed_data()),
                             headers=CSV).json()  # fmt: skip
        model = fit(client, placed["id"])
        effect = model["placement_effect"]
        assert effect is not None
        noise = np.array([h["noise_variance"] for h in model["hyperparameters"]])
        np.testing.assert_allclose(effect["noise_ratio"], np.array(effect["variance"]) / noise)
        assert effect["in_training_covariance"] is True
        assert np.any(np.array(effect["variance"]) > 0)
        assert effect["by_object"] is None  # each object's own only when asked
        asked = fit(client, placed["id"], object_placement=True)["placement_effect"]
        # Each object's own σ_b² (core.gp.object_placement), one row per object.
        rows = np.array(asked["by_object"])
        assert rows.shape == (len(model["objects"]), noise.size)
        assert np.all((rows >= 0) & (rows < noise))
        refused = client.post(
            f"{API}/models",
            json={"dataset_id": placed["id"], "latent_dim": 1, "placement_pooling": "mode"},
        )
        assert refused.status_code == 422, refused.text
        assert "placement_pooling" in refused.text
        refused = client.post(
            f"{API}/models",
            json={"dataset_id": placed["id"], "latent_dim": 1, "shift_along": "depth"},
        )
        assert refused.status_code == 422, refused.text
        assert "shift_along" in refused.text
        document = client.get(f"{API}/models/{model['id']}/export").json()
        plain = client.post(f"{API}/datasets", content=experiment1_csv(touches_per_object=8),
                            headers=CSV).json()  # fmt: skip
        assert fit(client, plain["id"])["placement_effect"] is None
    # The effect is the CLI's (core.gp.with_placement_effect): in the training covariance, and
    # after its rounds of refits near the estimator's fixed point under the rebuilt model.
    fitted = model_from_document(document)
    assert fitted.placement_in_fit
    assert document["placement_effect"]["in_training_covariance"] is True
    assert fitted.raw_data.placement_index is not None
    expected = estimate_placement_variance(fitted, fitted.raw_data.placement_index).variance
    np.testing.assert_allclose(document["placement_effect"]["variance"], expected, rtol=0.05)
    np.testing.assert_array_equal(effect["variance"], document["placement_effect"]["variance"])
    # The input shift too, estimated after the placement effect under the model that scores.
    shift = estimate_shift_variance(dataclasses.replace(fitted, shift_variance=None))
    assert shift is not None
    np.testing.assert_allclose(document["input_shift"]["variance"], shift.variance, rtol=1e-6)
    with TestClient(create_app(settings)) as client:  # a new server rebuilds the model from its row
        again = client.get(f"{API}/models/{model['id']}/export").json()
        assert again["placement_effect"] == document["placement_effect"]
        assert again["input_shift"] == document["input_shift"]
        assert again["training_data"]["placements"] == document["training_data"]["placements"]
        # An imported document keeps its placement effect too.
        imported = client.post(f"{API}/models/import", json=document)
        assert imported.status_code == 201, imported.text
        assert imported.json()["placement_effect"] == effect
