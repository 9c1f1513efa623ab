"""``/evaluations``: the job lifecycle through the REST API, its exports, bad input, restarts
and the migration that stores it.

The engine is :func:`app.evaluation.runner.run_evaluation`; the API's summary and trials are
compared with a run of the engine itself on the same model and spec.
"""

from __future__ import annotations

import csv
import io
import json
import signal
from pathlib import Path
from typing import Any

import httpx
import pytest
from alembic import command
from alembic.config import Config
from sqlalchemy import inspect, text

from app import crud
from app.config import Settings
from app.db import Database, upgrade_to_head
from app.documents.model import model_from_document
from app.evaluation.runner import run_evaluation
from app.evaluation.spec import EvaluationSpec
from app.main import create_app
from tests.app.conftest import (
    TestClient,
    experiment1_csv,
    experiment1_document,
    import_model,
    make_settings,
)
from tests.app.test_crash import _free_port, server
from tests.app.waits import UNFINISHED, wait_until

API = "/api/v1"


def wait_ended(client: TestClient | httpx.Client, evaluation_id: int) -> dict[str, Any]:
    """The evaluation once its job has ended (final state and, unless it failed, a summary)."""
    return wait_until(
        client,
        f"{API}/evaluations/{evaluation_id}",
        lambda e: (
            e["status"] not in UNFINISHED
            and (e["status"] == "failed" or not e["summary"].get("partial", False))
        ),
    )


def events_of(client: TestClient) -> list[dict[str, Any]]:
    stream = client.get(f"{API}/events?after=0&follow=false").text
    return [
        json.loads(line.removeprefix("data: "))
        for line in stream.splitlines()
        if line.startswith("data: ")
    ]


def start(client: TestClient | httpx.Client, **body: Any) -> dict[str, Any]:
    response = client.post(f"{API}/evaluations", json=body)
    assert response.status_code == 202, response.text
    created: dict[str, Any] = response.json()
    return created


def without(document: dict[str, Any], *keys: str) -> dict[str, Any]:
    return {k: v for k, v in document.items() if k not in keys}


# --- the lifecycle ----------------------------------------------------------------------------


def test_an_evaluation_runs_to_the_engines_report(client: TestClient) -> None:
    model_id = import_model(client)
    body = {
        "model_id": model_id,
        "world": "exp1",
        "policies": ["active", "passive"],
        "trials_per_target": 2,
        "steps": 4,
        "seed": 3,
    }
    created = start(client, **body)
    assert created["status"] == "queued"
    assert (created["done"], created["total"]) == (0, 2 * 4 * 2)  # policies x objects x trials
    assert created["spec"]["world"] == "exp1"
    assert created["spec"]["plan_under"] == "objects"  # the default, recorded

    ended = wait_ended(client, created["id"])
    assert ended["status"] == "completed", ended
    assert ended["done"] == ended["total"] == 16
    assert ended["started_at"] is not None
    assert ended["finished_at"] is not None

    # The same evaluation run by the engine directly gives the same summary and trials.
    model = model_from_document(experiment1_document())
    spec = EvaluationSpec(
        world="exp1", policies=("active", "passive"), trials_per_target=2, steps=4, seed=3
    )
    report = run_evaluation(model, spec).to_dict()
    summary = ended["summary"]
    # The stored summary leaves out the trial-level lists (completed and refused trials).
    trial_lists = ("trials", "refused")
    assert without(summary, "seconds", "workers") == without(
        report, "seconds", "workers", *trial_lists
    )
    assert summary["seconds"] == pytest.approx(ended["seconds"])
    exported = client.get(f"{API}/evaluations/{created['id']}/export?format=json")
    assert exported.status_code == 200
    document = exported.json()
    assert document["format"] == "activetouch-evaluation/2"
    assert document["trials"] == report["trials"]
    assert without(document, *trial_lists) == summary
    # Each policy's calibration: over every (trial, touch), at T and by touch, sure-and-wrong at
    # the evaluation's confidence.
    for policy in ("active", "passive"):
        calibration = summary["policies"][policy]["calibration"]
        assert calibration["all_touches"]["answers"] == 8 * 4
        assert calibration["final"]["answers"] == 8
        assert len(calibration["all_touches"]["reliability"]) == 10
        assert calibration["final"]["sure_and_wrong"]["threshold"] == 0.95
        by_touch = [t["accuracy"] for t in calibration["by_touch"]]
        assert by_touch == pytest.approx(summary["policies"][policy]["accuracy_by_touch"])

    # Progress was published as trials finished, and every change of state.
    events = events_of(client)
    mine = [e for e in events if e["data"].get("evaluation_id") == created["id"]]
    states = [e["data"]["status"] for e in mine if e["type"] == "evaluation.status"]
    assert states == ["queued", "running", "completed"]
    progress = [e["data"] for e in mine if e["type"] == "evaluation.progress"]
    assert progress
    assert progress[-1]["done"] == 16
    assert [p["done"] for p in progress] == sorted(p["done"] for p in progress)

    # Listed, newest first, with its summary.
    listed = client.get(f"{API}/evaluations").json()
    assert listed["count"] == 1
    assert listed["data"][0]["id"] == created["id"]
    assert listed["data"][0]["summary"] == summary
    filtered = client.get(f"{API}/evaluations?status=completed&model_id={model_id}").json()
    assert filtered["count"] == 1
    assert client.get(f"{API}/evaluations?status=running").json()["count"] == 0
    assert client.get(f"{API}/evaluations?model_id={model_id + 1}").json()["count"] == 0


def test_stop_at_confidence_is_taken_recorded_and_stops_trials(client: TestClient) -> None:
    model_id = import_model(client)
    body = {"model_id": model_id, "world": "exp1", "trials_per_target": 1, "steps": 6}
    created = start(client, **body, confidence=0.6, stop_at_confidence=True)
    assert created["spec"]["stop_at_confidence"] is True
    ended = wait_ended(client, created["id"])
    assert ended["status"] == "completed", ended
    assert ended["summary"]["stop_at_confidence"] is True
    document = client.get(f"{API}/evaluations/{created['id']}/export?format=json").json()
    assert "confident" in {trial["stop_reason"] for trial in document["trials"]}
    default = start(client, **body)
    assert default["spec"]["stop_at_confidence"] is False


def test_trials_are_readable_one_by_one_and_export_as_csv(client: TestClient) -> None:
    model_id = import_model(client)
    created = start(client, model_id=model_id, world="exp1", trials_per_target=1, steps=5, seed=1)
    evaluation_id = created["id"]
    wait_ended(client, evaluation_id)
    document = client.get(f"{API}/evaluations/{evaluation_id}/export").json()
    by_key = {(t["policy"], t["target"], t["trial"]): t for t in document["trials"]}

    listed = client.get(f"{API}/evaluations/{evaluation_id}/trials").json()
    assert listed["count"] == len(by_key) == 8
    assert [t["number"] for t in listed["data"]] == list(range(1, 9))
    objects = [o["name"] for o in client.get(f"{API}/models/{model_id}").json()["objects"]]
    for summary in listed["data"]:
        one = client.get(f"{API}/evaluations/{evaluation_id}/trials/{summary['number']}")
        assert one.status_code == 200
        trial = one.json()
        record = by_key[(trial["policy"], trial["target"], trial["trial"])]
        assert trial["record"] == record
        assert trial["objects"] == objects
        assert trial["model_id"] == model_id
        assert trial["answer"] == record["answers"][-1]
        assert trial["correct"] == (record["answers"][-1] == record["target"])
    missing = client.get(f"{API}/evaluations/{evaluation_id}/trials/9")
    assert missing.status_code == 404
    assert "8 finished" in missing.json()["detail"]

    exported = client.get(f"{API}/evaluations/{evaluation_id}/export?format=csv")
    assert exported.status_code == 200
    assert exported.headers["content-type"].startswith("text/csv")
    rows = list(csv.DictReader(io.StringIO(exported.text)))
    assert len(rows) == sum(t["touches"] for t in document["trials"])
    first = document["trials"][0]
    mine = [r for r in rows if (r["policy"], r["target"], r["trial"]) == (
        first["policy"], first["target"], str(first["trial"]))]  # fmt: skip
    assert [r["answer"] for r in mine] == first["answers"]
    assert [float(r["mutual_information"]) for r in mine] == first["mutual_information"]
    target = objects.index(first["target"])
    assert [float(r["target_probability"]) for r in mine] == [
        p[target] for p in first["probabilities"]
    ]


def test_stopping_keeps_the_finished_trials(client: TestClient) -> None:
    model_id = import_model(client)
    created = start(
        client, model_id=model_id, world="exp1", trials_per_target=500, steps=10, seed=2
    )
    evaluation_id = created["id"]
    wait_until(client, f"{API}/evaluations/{evaluation_id}", lambda e: e["done"] >= 2)
    # While it runs, the summary is that of the trials finished so far.
    running = client.get(f"{API}/evaluations/{evaluation_id}").json()
    if running["status"] == "running":
        assert running["summary"]["partial"] is True
        counted = sum(p["trials"] for p in running["summary"]["policies"].values())
        assert counted >= 2

    stopped = client.post(f"{API}/evaluations/{evaluation_id}/stop")
    assert stopped.status_code == 200, stopped.text
    assert stopped.json()["status"] == "stopped"
    ended = wait_ended(client, evaluation_id)
    assert ended["status"] == "stopped"
    assert ended["reason"] == "stop requested"
    assert 2 <= ended["done"] < ended["total"] == 2 * 4 * 500
    trials = client.get(f"{API}/evaluations/{evaluation_id}/trials?limit=1000").json()
    assert trials["count"] == ended["done"]
    # The final summary covers exactly the kept trials.
    assert sum(p["trials"] for p in ended["summary"]["policies"].values()) == ended["done"]
    document = client.get(f"{API}/evaluations/{evaluation_id}/export").json()
    assert len(document["trials"]) == ended["done"]

    again = client.post(f"{API}/evaluations/{evaluation_id}/stop")
    assert again.status_code == 409
    assert again.json()["current_state"] == "stopped"


def test_a_shutdown_fails_a_running_evaluation_as_interrupted(settings: Settings) -> None:
    with TestClient(create_app(settings)) as client:
        model_id = import_model(client)
        created = start(
            client, model_id=model_id, world="exp1", trials_per_target=500, steps=10, seed=4
        )
        evaluation_id = created["id"]
        wait_until(client, f"{API}/evaluations/{evaluation_id}", lambda e: e["done"] >= 1)
    with TestClient(create_app(settings)) as client:
        ended = client.get(f"{API}/evaluations/{evaluation_id}").json()
        assert ended["status"] == "failed"
        assert ended["reason"] == "interrupted"
        assert ended["done"] >= 1
        trials = client.get(f"{API}/evaluations/{evaluation_id}/trials?limit=1000").json()
        assert trials["count"] == ended["done"]


def test_a_restart_after_a_crash_fails_it_as_interrupted_keeping_its_trials(
    tmp_path: Path,
) -> None:
    """SIGKILL the server mid-evaluation; the next server marks it failed "interrupted"."""
    database_url = f"sqlite:///{tmp_path / 'crash.db'}"
    port = _free_port()
    base = f"http://127.0.0.1:{port}"
    with server(database_url, port, tmp_path / "server.log") as process:
        with httpx.Client(base_url=base, timeout=30) as http:
            imported = http.post(f"{API}/models/import", json=experiment1_document())
            assert imported.status_code == 201, imported.text
            created = start(
                http,
                model_id=imported.json()["id"],
                world="exp1",
                trials_per_target=500,
                steps=10,
            )
            wait_until(http, f"{API}/evaluations/{created['id']}", lambda e: e["done"] >= 3)
        process.send_signal(signal.SIGKILL)
        process.wait(timeout=10)
    database = Database(database_url)
    try:
        with database.session() as session:
            row = crud.get_evaluation(session, created["id"])
            assert row is not None
            assert row.status == "running"  # as the killed server left it
            kept = len(crud.evaluation_trials(session, created["id"]))
            assert kept >= 3
    finally:
        database.dispose()
    settings = make_settings(tmp_path, database_url=database_url)
    with TestClient(create_app(settings)) as client:
        ended = client.get(f"{API}/evaluations/{created['id']}").json()
        assert (ended["status"], ended["reason"]) == ("failed", "interrupted")
        assert ended["done"] == kept
        assert ended["summary"]["partial"] is True
        assert sum(p["trials"] for p in ended["summary"]["policies"].values()) == kept
        events = [e for e in events_of(client) if e["type"] == "evaluation.status"]
        assert {"evaluation_id": created["id"], "status": "failed", "reason": "interrupted"} in [
            e["data"] for e in events
        ]


# --- replay and bad input ---------------------------------------------------------------------


def upload(client: TestClient, text_: str) -> int:
    response = client.post(f"{API}/datasets", content=text_, headers={"Content-Type": "text/csv"})
    assert response.status_code == 201, response.text
    dataset_id: int = response.json()["id"]
    return dataset_id


def test_a_replay_evaluation_draws_from_the_held_out_touches(client: TestClient) -> None:
    model_id = import_model(client)
    held_out = upload(client, experiment1_csv(seed=11, touches_per_object=4))
    created = start(
        client,
        model_id=model_id,
        world="replay",
        dataset_id=held_out,
        trials_per_target=2,
        steps=3,
    )
    assert created["dataset_id"] == held_out
    ended = wait_ended(client, created["id"])
    assert ended["status"] == "completed", ended
    document = client.get(f"{API}/evaluations/{created['id']}/export").json()
    assert len(document["trials"]) == 2 * 4 * 2
    assert all(t["touches"] <= 3 for t in document["trials"])


def post(client: TestClient, **body: Any) -> httpx.Response:
    return client.post(f"{API}/evaluations", json=body)


def test_bad_requests_name_what_is_wrong(client: TestClient, settings: Settings) -> None:
    model_id = import_model(client)
    unknown_model = post(client, model_id=999, world="exp1")
    assert unknown_model.status_code == 404
    assert "Model 999" in unknown_model.json()["detail"]

    unknown_dataset = post(client, model_id=model_id, world="replay", dataset_id=999)
    assert unknown_dataset.status_code == 404
    assert "Dataset 999" in unknown_dataset.json()["detail"]

    no_dataset = post(client, model_id=model_id, world="replay")
    assert no_dataset.status_code == 422
    assert no_dataset.json()["field"] == "dataset_id"

    trained_on = client.get(f"{API}/models/{model_id}").json()["dataset_id"]
    own = post(client, model_id=model_id, world="replay", dataset_id=trained_on)
    assert own.status_code == 422
    assert "fitted to" in own.json()["detail"]

    stray_dataset = post(client, model_id=model_id, world="exp1", dataset_id=1)
    assert stray_dataset.status_code == 422
    assert stray_dataset.json()["field"] == "dataset_id"

    world = post(client, model_id=model_id, world="mars")
    assert world.status_code == 422
    message = json.dumps(world.json())
    for allowed in ("exp1", "exp2", "rig", "model", "replay"):
        assert allowed in message

    policy = post(client, model_id=model_id, world="exp1", policies=["active", "clairvoyant"])
    assert policy.status_code == 422
    detail = policy.json()["detail"]
    assert "clairvoyant" in detail
    assert "active" in detail
    assert "passive" in detail

    # A replay dataset of other objects: the message names them.
    others = experiment1_csv(seed=2, touches_per_object=3).replace("O4,", "cup,")
    mismatch = post(client, model_id=model_id, world="replay", dataset_id=upload(client, others))
    assert mismatch.status_code == 422
    assert "cup" in mismatch.json()["detail"]

    # A replay dataset of other dimensions (two observation features instead of three).
    lines = experiment1_csv(seed=3, touches_per_object=3).splitlines()
    narrow = "\n".join(",".join(line.split(",")[:-1]) for line in lines) + "\n"
    dims = post(client, model_id=model_id, world="replay", dataset_id=upload(client, narrow))
    assert dims.status_code == 422
    assert "dy=2" in dims.json()["detail"]
    assert "dy=3" in dims.json()["detail"]

    for field, value in (
        ("trials_per_target", 0),
        ("steps", 0),
        ("confidence", 1.5),
        ("stop_at_confidence", "yes"),
        ("stop_at_confidence", 1),
        ("plan_under", "mixture"),
    ):
        out_of_range = post(client, model_id=model_id, world="exp1", **{field: value})
        assert out_of_range.status_code == 422, field

    # A model still fitting: 409 with its state.
    database = Database(settings.database_url)
    try:
        with database.session() as session:
            dataset_id = crud.get_model(session, model_id).dataset_id  # type: ignore[union-attr]
            fitting = crud.create_model(
                session, dataset_id=dataset_id, status="fitting", latent_dim=1
            )
            session.commit()
            fitting_id = fitting.id
    finally:
        database.dispose()
    busy = post(client, model_id=fitting_id, world="exp1")
    assert busy.status_code == 409
    assert busy.json()["current_state"] == "fitting"

    assert client.get(f"{API}/evaluations").json()["count"] == 0  # nothing was started
    assert client.get(f"{API}/evaluations/5").status_code == 404
    assert client.post(f"{API}/evaluations/5/stop").status_code == 404


def test_an_unreachable_scheduler_fails_the_job_with_a_clear_reason(tmp_path: Path) -> None:
    port = _free_port()  # nothing listens there
    settings = make_settings(tmp_path, dask_scheduler=f"tcp://127.0.0.1:{port}")
    with TestClient(create_app(settings)) as client:
        model_id = import_model(client)
        created = start(client, model_id=model_id, world="exp1", trials_per_target=1, steps=2)
        assert created["workers"] is None
        ended = wait_ended(client, created["id"])
        assert ended["status"] == "failed"
        assert f"127.0.0.1:{port}" in ended["reason"]
        assert ended["done"] == 0


def test_the_server_runs_trials_on_its_dask_cluster_or_local_workers(
    tmp_path: Path, dask_cluster: Any, monkeypatch: pytest.MonkeyPatch
) -> None:
    """ACTIVETOUCH_DASK_SCHEDULER sends the trials to that cluster; ``workers`` without it
    starts a local cluster; both give the serial engine's trials."""
    monkeypatch.setenv("ACTIVETOUCH_DASK_SCHEDULER", dask_cluster.scheduler_address)
    settings = make_settings(tmp_path)
    assert settings.dask_scheduler == dask_cluster.scheduler_address
    body = {"world": "exp1", "trials_per_target": 1, "steps": 3, "seed": 9}
    model = model_from_document(experiment1_document())
    serial = run_evaluation(
        model, EvaluationSpec(world="exp1", trials_per_target=1, steps=3, seed=9)
    ).to_dict()
    with TestClient(create_app(settings)) as client:
        model_id = import_model(client)
        created = start(client, model_id=model_id, workers=3, **body)  # the cluster wins
        assert created["workers"] is None
        ended = wait_ended(client, created["id"])
        assert ended["status"] == "completed", ended
        assert ended["workers"] == 2  # the cluster's
        document = client.get(f"{API}/evaluations/{created['id']}/export").json()
        assert document["trials"] == serial["trials"]
        assert document["policies"] == serial["policies"]
    monkeypatch.delenv("ACTIVETOUCH_DASK_SCHEDULER")
    local = make_settings(tmp_path / "local")
    assert local.dask_scheduler is None
    with TestClient(create_app(local)) as client:
        model_id = import_model(client)
        created = start(client, model_id=model_id, workers=2, **body)
        assert created["workers"] == 2
        ended = wait_ended(client, created["id"])
        assert ended["status"] == "completed", ended
        assert ended["workers"] == 2
        document = client.get(f"{API}/evaluations/{created['id']}/export").json()
        assert document["trials"] == serial["trials"]


# --- the migration ----------------------------------------------------------------------------


def test_the_migration_adds_and_removes_the_evaluation_tables(tmp_path: Path) -> None:
    settings = make_settings(tmp_path)
    database = Database(settings.database_url)
    config = Config()
    config.set_main_option("script_location", str(settings.migrations_dir))
    try:
        upgrade_to_head(database.engine, settings.migrations_dir)
        tables = set(inspect(database.engine).get_table_names())
        assert {"evaluations", "evaluation_trials"} <= tables
        with database.engine.begin() as connection:
            config.attributes["connection"] = connection
            command.downgrade(config, "0002")
        tables = set(inspect(database.engine).get_table_names())
        assert not {"evaluations", "evaluation_trials"} & tables
        assert {"models", "trials", "datasets"} <= tables
        with database.engine.begin() as connection:
            config.attributes["connection"] = connection
            command.upgrade(config, "0003_evaluations")
        with database.engine.connect() as connection:
            count = connection.execute(text("SELECT count(*) FROM evaluations")).scalar()
            assert count == 0
            unique = inspect(database.engine).get_unique_constraints("evaluation_trials")
            assert sorted(tuple(u["column_names"]) for u in unique) == [
                ("evaluation_id", "number"),
                ("evaluation_id", "policy", "target", "trial"),
            ]
    finally:
        database.dispose()


def test_a_summary_stored_before_calibration_reads_with_it(
    client: TestClient, settings: Settings
) -> None:
    """A completed evaluation whose stored summary is an ``activetouch-evaluation/1`` one (no
    calibration) is summarised again from its trials when read; the list shows it as stored."""
    model_id = import_model(client)
    created = start(client, model_id=model_id, world="exp1", trials_per_target=1, steps=3)
    ended = wait_ended(client, created["id"])
    assert ended["status"] == "completed"
    old = json.loads(json.dumps(ended["summary"]))
    old["format"] = "activetouch-evaluation/1"
    for entry in old["policies"].values():
        del entry["calibration"]
    database = Database(settings.database_url)
    try:
        with database.session() as session:
            row = crud.get_evaluation(session, created["id"])
            assert row is not None
            row.summary = old
            session.commit()
    finally:
        database.dispose()
    listed = client.get(f"{API}/evaluations").json()["data"][0]["summary"]
    assert listed["format"] == "activetouch-evaluation/1"
    assert all(p["calibration"] is None for p in listed["policies"].values())
    again = client.get(f"{API}/evaluations/{created['id']}").json()["summary"]
    assert again == ended["summary"]
    assert again["format"] == "activetouch-evaluation/2"
