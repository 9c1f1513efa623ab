"""The server records when each touch was made as ``activetouch collect`` does: collections store
each touch's ``time_s`` (seconds since the collection's first touch), datasets carry the times in
and out (CSV, JSON, raw touches) and build training data with ``touch_times_s`` when every sample
has one."""

from __future__ import annotations

import dataclasses
import json
from typing import Any

import numpy as np

from app import crud
from app.documents.training_csv import read_training_csv, write_training_csv
from app.services.datasets import training_data
from core.types import TrainingData
from tests.app.conftest import TestClient, experiment1_csv
from tests.app.test_raw_touches import raw_file
from tests.app.waits import completed_collection
from tests.conftest import SETTLE_S

API = "/api/v1"
CUPS = ["paper_cup", "bumpy_glass", "stainless_cup"]
CSV = {"content-type": "text/csv"}
NDJSON = {"content-type": "application/x-ndjson"}


def stored(client: TestClient, dataset_id: int) -> TrainingData:
    """The dataset as the server's fits get it."""
    context = client.app.state.context  # type: ignore[attr-defined]
    with context.database.session() as session:
        return training_data(session, dataset_id)


def timed_data() -> TrainingData:
    """Experiment 1's touches (4 objects, 5 each), one every 24.1 s from an arbitrary origin."""
    base = read_training_csv(experiment1_csv(touches_per_object=5))
    return dataclasses.replace(base, touch_times_s=1e4 + 24.1 * np.arange(base.n_touches) / 3)


def test_a_collection_stores_each_touch_time_since_its_first(client: TestClient) -> None:
    body = {
        "objects": [{"name": n, "slot": i} for i, n in enumerate(CUPS)],
        "seed": 5,
        "samples_per_object": 2,
        "action_design": "random",
        "action_scale": 0.5,
    }
    run = completed_collection(client, body)
    dataset_id = run["dataset_id"]
    text = client.get(f"{API}/datasets/{dataset_id}/export").text
    assert text.startswith("object,placement,time_s,duration_s,x_1")
    data = read_training_csv(text)
    times_s = data.touch_times_s
    assert times_s is not None
    assert times_s[0] == 0.0
    assert np.all(np.diff(times_s) >= SETTLE_S)  # each touch rests first, on the rig's clock
    np.testing.assert_array_equal(stored(client, dataset_id).touch_times_s, times_s)
    samples = client.get(f"{API}/datasets/{dataset_id}/export?format=json").json()["samples"]
    assert [s["time_s"] for s in samples] == times_s.tolist()
    raw = client.get(f"{API}/datasets/{dataset_id}/raw-touches").text.splitlines()
    assert [json.loads(line)["time_s"] for line in raw] == times_s.tolist()
    events = [
        json.loads(line.removeprefix("data: "))
        for line in client.get(f"{API}/events?after=0&follow=false").text.splitlines()
        if line.startswith("data: ")
    ]
    sent = [e["data"]["time_s"] for e in events if e["type"] == "collection.progress"]
    assert sent == times_s.tolist()  # each collection.progress event says its time


def test_datasets_keep_times_in_and_out(client: TestClient) -> None:
    data = timed_data()
    text = write_training_csv(data)
    created = client.post(f"{API}/datasets", content=text, headers=CSV)
    assert created.status_code == 201, created.text
    dataset_id = created.json()["id"]
    assert client.get(f"{API}/datasets/{dataset_id}/export").text == text
    assert data.touch_times_s is not None
    assert stored(client, dataset_id).touch_times_s.tolist() == data.touch_times_s.tolist()
    exported = client.get(f"{API}/datasets/{dataset_id}/export?format=json").json()
    assert [s["time_s"] for s in exported["samples"]] == data.touch_times_s.tolist()
    again = client.post(f"{API}/datasets", json=exported)  # the JSON format round trips too
    assert again.status_code == 201, again.text
    assert client.get(f"{API}/datasets/{again.json()['id']}/export").text == text
    # A CSV without the column stays without it, in both formats and as training data.
    plain = experiment1_csv(touches_per_object=3)
    dataset = client.post(f"{API}/datasets", content=plain, headers=CSV).json()
    assert client.get(f"{API}/datasets/{dataset['id']}/export").text == plain
    samples = client.get(f"{API}/datasets/{dataset['id']}/export?format=json").json()["samples"]
    assert all("time_s" not in s for s in samples)
    assert stored(client, dataset["id"]).touch_times_s is None
    # JSON samples give a time on all or none; a CSV's empty cell is named by row and column.
    mixed = exported["samples"][:4]
    del mixed[1]["time_s"]
    refused = client.post(f"{API}/datasets", json={"samples": mixed})
    assert refused.status_code == 422, refused.text
    assert "samples[1].time_s" in refused.text
    rows = text.splitlines()
    cells = rows[3].split(",")
    cells[1] = ""
    broken = "\n".join([*rows[:3], ",".join(cells), *rows[4:]]) + "\n"
    refused = client.post(f"{API}/datasets", content=broken, headers=CSV)
    assert refused.status_code == 422, refused.text
    assert "row 4, column time_s" in refused.text
    assert client.get(f"{API}/datasets").json()["count"] == 3


def test_a_dataset_with_a_sample_without_time_has_no_times(client: TestClient) -> None:
    context = client.app.state.context  # type: ignore[attr-defined]
    base = read_training_csv(experiment1_csv(touches_per_object=2))
    with context.database.session() as session:
        dataset = crud.create_dataset(
            session, name="partly timed", source="collection", status="ready",
            object_names=base.object_names, action_dim=1, observation_dim=3,
        )  # fmt: skip
        crud.add_samples(
            session,
            dataset,
            [
                (base.object_names[obj], x, y, None, None, None if k == 2 else 30.0 * k)
                for k, (obj, x, y) in enumerate(
                    zip(base.object_index, base.actions, base.observations, strict=True)
                )
            ],
        )
        session.commit()
        dataset_id = dataset.id
    assert stored(client, dataset_id).touch_times_s is None
    assert "time_s" not in client.get(f"{API}/datasets/{dataset_id}/export").text


def test_raw_touches_keep_their_time(client: TestClient) -> None:
    lines = raw_file(4).splitlines()
    timed = [json.dumps({**json.loads(line), "time_s": 24.5 * k}) for k, line in enumerate(lines)]
    created = client.post(f"{API}/datasets", content="\n".join(timed), headers=NDJSON)
    assert created.status_code == 201, created.text
    dataset_id = created.json()["id"]
    back = client.get(f"{API}/datasets/{dataset_id}/raw-touches").text.splitlines()
    expected = [24.5 * k for k in range(12)]
    assert [json.loads(line)["time_s"] for line in back] == expected
    data = read_training_csv(client.get(f"{API}/datasets/{dataset_id}/export").text)
    assert data.touch_times_s is not None
    assert data.touch_times_s.tolist() == expected
    # Without times the lines stay without; a bad or partial time names its line.
    plain = client.post(f"{API}/datasets", content="\n".join(lines), headers=NDJSON).json()
    back = client.get(f"{API}/datasets/{plain['id']}/raw-touches").text.splitlines()
    assert all("time_s" not in json.loads(line) for line in back)
    bad_time: dict[str, Any] = {**json.loads(lines[1]), "time_s": "later"}
    for edited, needle in (
        ([*timed[:2], lines[2], *timed[3:]], "line 3: 'time_s' is missing"),
        ([*timed[:1], json.dumps(bad_time)], "line 2"),
    ):
        refused = client.post(f"{API}/datasets", content="\n".join(edited), headers=NDJSON)
        assert refused.status_code == 422, refused.text
        assert needle in refused.text
