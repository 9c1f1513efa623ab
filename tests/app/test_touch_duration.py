"""The touches' duration: an action means a trajectory of one duration, so a collection records
it (the training CSV's ``duration_s`` column, a raw-touch line's ``duration_s``, a dataset's
``touch_duration_s``), a model keeps it, and recognition on the rig touches with it."""

from __future__ import annotations

import dataclasses
import json
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient

from app.documents.errors import DocumentError
from app.documents.model import model_from_document, model_to_document
from app.documents.raw_touches import featurise, read_raw_touches
from app.documents.training_csv import read_training_csv, write_training_csv
from app.evaluation.context import TrialContext
from app.evaluation.spec import EvaluationSpec
from app.rig.actions import TouchActions
from core.errors import InvalidInputError
from core.evaluation.worlds import sample_experiment1
from core.features.pipeline import means_pipeline
from core.types import ManifoldModel, TrainingData
from hardware.teaching import PAPER_TOUCH_DURATION_S
from tests.app.test_raw_touches import raw_file
from tests.app.waits import completed_collection, completed_rig_trial

API = "/api/v1"


def lasting(model: ManifoldModel, duration_s: float | None) -> ManifoldModel:
    """``model`` as if its training touches had lasted ``duration_s``."""
    if model.source_data is not None:
        source = dataclasses.replace(model.source_data, touch_duration_s=duration_s)
        return dataclasses.replace(model, source_data=source)
    return dataclasses.replace(
        model, data=dataclasses.replace(model.data, touch_duration_s=duration_s)
    )


def data_lasting(duration_s: float | None) -> TrainingData:
    base = sample_experiment1(np.random.default_rng(2), touches_per_object=3)
    return dataclasses.replace(base, touch_duration_s=duration_s)


def test_the_csv_column_round_trips_and_comes_after_the_times() -> None:
    timed = dataclasses.replace(data_lasting(8.25), touch_times_s=np.arange(12.0))
    text = write_training_csv(timed)
    assert text.splitlines()[0].startswith("object,time_s,duration_s,x_1")
    assert {line.split(",")[2] for line in text.splitlines()[1:]} == {"8.25"}
    again = read_training_csv(text)
    assert again.touch_duration_s == 8.25
    assert again.touch_times_s is not None
    assert again.touch_times_s.tolist() == list(range(12))
    assert read_training_csv(write_training_csv(data_lasting(None))).touch_duration_s is None


def test_a_csv_whose_touches_lasted_differently_is_refused_naming_the_row() -> None:
    lines = write_training_csv(data_lasting(8.0)).splitlines()
    lines[5] = lines[5].replace(",8.0,", ",9.0,", 1)
    differs = r"row 6, column duration_s: 9.0 differs from row 2"
    with pytest.raises(DocumentError, match=differs) as e:
        read_training_csv("\n".join(lines))
    assert (e.value.row, e.value.column) == (6, "duration_s")
    zero = write_training_csv(data_lasting(8.0)).replace(",8.0,", ",0.0,")
    with pytest.raises(DocumentError, match=r"row 2, column duration_s: 0.0 is not a duration"):
        read_training_csv(zero)
    misordered = "object,duration_s,time_s,x_1,y_1\na,1,0,0,0\n"
    with pytest.raises(DocumentError, match="'time_s' must come right after 'object'"):
        read_training_csv(misordered)


def test_raw_touch_lines_give_the_duration_on_every_line_the_same() -> None:
    lines = [json.loads(line) for line in raw_file(2).splitlines()]
    with_duration = "\n".join(json.dumps({**line, "duration_s": 6.5}) for line in lines)
    touches = read_raw_touches(with_duration)
    assert touches.touch_duration_s == 6.5
    assert featurise(touches, means_pipeline(touches.touches[0])).touch_duration_s == 6.5
    assert read_raw_touches(raw_file(2)).touch_duration_s is None

    differing = [{**line, "duration_s": 6.5} for line in lines]
    differing[2]["duration_s"] = 7.0
    with pytest.raises(DocumentError, match=r"line 3: 'duration_s' is 7.0 here but 6.5 on line 1"):
        read_raw_touches("\n".join(map(json.dumps, differing)))
    partial = [{**line, "duration_s": 6.5} if k else line for k, line in enumerate(lines)]
    given = r"line 2: 'duration_s' is given here but not on line 1"
    with pytest.raises(DocumentError, match=given):
        read_raw_touches("\n".join(map(json.dumps, partial)))
    negative = [{**line, "duration_s": -1} for line in lines]
    with pytest.raises(DocumentError, match=r"line 1: 'duration_s' must be a finite number"):
        read_raw_touches("\n".join(map(json.dumps, negative)))


def test_training_data_refuses_a_duration_that_is_not_positive() -> None:
    for bad in (0.0, -3.0, float("inf"), float("nan")):
        with pytest.raises(InvalidInputError, match="touch_duration_s: must be a finite number"):
            data_lasting(bad)


def test_the_model_document_keeps_the_duration(rig_model: ManifoldModel) -> None:
    document = json.loads(json.dumps(model_to_document(lasting(rig_model, 6.0))))
    assert document["training_data"]["duration_s"] == 6.0
    assert model_from_document(document).raw_data.touch_duration_s == 6.0
    assert "duration_s" not in model_to_document(rig_model)["training_data"]
    document["training_data"]["duration_s"] = "long"
    with pytest.raises(DocumentError, match=r"training_data\.duration_s must be a number"):
        model_from_document(document)


def test_the_rig_world_touches_for_as_long_as_the_training_touches(
    rig_model: ManifoldModel,
) -> None:
    spec = EvaluationSpec(world="rig", trials_per_target=1, steps=1, table="default")
    for recorded, expected in ((6.0, 6.0), (None, PAPER_TOUCH_DURATION_S)):
        context = TrialContext(lasting(rig_model, recorded), spec)
        assert context._rig_actions().duration_s == expected


def test_the_servers_collections_record_and_its_trials_use_the_duration(
    client: TestClient, rig_model: ManifoldModel
) -> None:
    body: dict[str, Any] = {
        "objects": [{"name": "paper_cup", "slot": 0}, {"name": "foam_sponge", "slot": 6}],
        "samples_per_object": 2,
        "action_design": "random",
        "press_depth": False,
    }
    dataset_id = completed_collection(client, body)["dataset_id"]
    dataset = client.get(f"{API}/datasets/{dataset_id}").json()
    assert dataset["touch_duration_s"] == PAPER_TOUCH_DURATION_S
    exported = client.get(f"{API}/datasets/{dataset_id}/export").text
    assert read_training_csv(exported).touch_duration_s == PAPER_TOUCH_DURATION_S

    document = model_to_document(lasting(rig_model, 6.0))
    done = completed_rig_trial(client, document, target="paper_cup", max_steps=1)
    six_seconds = TouchActions.from_teaching(duration_s=6.0)
    (step,) = done["steps"]
    commanded = np.asarray(step["trajectory"]["commanded_deg"])
    assert commanded.shape[0] == six_seconds.trajectory(step["action"]).shape[0]
    np.testing.assert_allclose(commanded, six_seconds.trajectory(step["action"]), atol=1e-9)


def test_a_collection_touches_for_the_duration_it_is_given(client: TestClient) -> None:
    body: dict[str, Any] = {
        "objects": [{"name": "paper_cup", "slot": 0}, {"name": "foam_sponge", "slot": 6}],
        "samples_per_object": 2,
        "action_design": "random",
        "touch_duration_s": 8.0,
    }
    run = completed_collection(client, body)
    assert run["params"]["touch_duration_s"] == 8.0
    dataset = client.get(f"{API}/datasets/{run['dataset_id']}").json()
    assert dataset["touch_duration_s"] == 8.0
    raw = client.get(f"{API}/datasets/{run['dataset_id']}/raw-touches").text.splitlines()
    for line in map(json.loads, raw):
        assert line["duration_s"] == 8.0
        # The sensor is read over the trajectory, so each series spans the touch: 8 s, not 14.4.
        for channel in line["channels"].values():
            spanned_s = len(channel["samples"]) / channel["rate_hz"]
            assert 7.5 < spanned_s < 8.5, spanned_s
    too_short = client.post(f"{API}/collections", json={**body, "touch_duration_s": 0.5})
    assert too_short.status_code == 422
    assert "touch_duration_s" in too_short.text


def test_a_json_upload_keeps_the_duration_in_and_out(client: TestClient) -> None:
    data = data_lasting(None)
    samples = [
        {"object": data.object_names[i], "action": x.tolist(), "observation": y.tolist()}
        for i, x, y in zip(data.object_index, data.actions, data.observations, strict=True)
    ]
    created = client.post(f"{API}/datasets", json={"samples": samples, "touch_duration_s": 9.5})
    assert created.status_code == 201, created.text
    assert created.json()["touch_duration_s"] == 9.5
    dataset_id = created.json()["id"]
    again = client.get(f"{API}/datasets/{dataset_id}/export?format=json").json()
    assert again["touch_duration_s"] == 9.5
    csv_text = client.get(f"{API}/datasets/{dataset_id}/export").text
    assert read_training_csv(csv_text).touch_duration_s == 9.5
    refused = client.post(f"{API}/datasets", json={"samples": samples, "touch_duration_s": 0})
    assert refused.status_code == 422
    assert "touch_duration_s" in refused.text
