"""Trials: scripted flow, validation, state transitions (409), simulated runs, events, recovery."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from app.main import create_app
from core.evaluation.worlds import Experiment1World
from tests.app.conftest import TestClient, import_model, make_settings
from tests.app.waits import wait_until

API = "/api/v1"


@pytest.fixture
def model_id(client: TestClient) -> int:
    return import_model(client)


def scripted(client: TestClient, model_id: int, **extra: Any) -> dict[str, Any]:
    body = {"model_id": model_id, "mode": "scripted", "seed": 3, **extra}
    response = client.post(f"{API}/trials", json=body)
    assert response.status_code == 201, response.text
    trial: dict[str, Any] = response.json()
    return trial


def simulated(client: TestClient, model_id: int, **fields: Any) -> Any:
    """``POST /trials`` of a simulated trial of ``model_id`` with ``fields``; the response."""
    return client.post(f"{API}/trials", json={"model_id": model_id, "mode": "simulated", **fields})


def touch(client: TestClient, trial_id: int, obj: int, rng: np.random.Generator) -> Any:
    advice = client.get(f"{API}/trials/{trial_id}/next-action")
    assert advice.status_code == 200, advice.text
    action = advice.json()["action"]
    y = Experiment1World().observe(obj, np.asarray([action]), rng)[0]
    return client.post(
        f"{API}/trials/{trial_id}/observations",
        json={"action": action, "observation": y.tolist()},
    )


def wait_for(client: TestClient, trial_id: int, predicate: Any, timeout_s: float = 20) -> Any:
    return wait_until(client, f"{API}/trials/{trial_id}", predicate, timeout_s)


def wait_until_steady(client: TestClient, trial_id: int, quiet_s: float = 0.2) -> int:
    """The trial's step count once it has not changed for ``quiet_s`` (a paused run's)."""
    deadline = time.monotonic() + 20
    steps = client.get(f"{API}/trials/{trial_id}").json()["n_steps"]
    while time.monotonic() < deadline:
        time.sleep(quiet_s)
        now = client.get(f"{API}/trials/{trial_id}").json()["n_steps"]
        if now == steps:
            return int(steps)
        steps = now
    raise AssertionError(f"trial {trial_id} still adding steps ({steps}) after 20 s")


def test_scripted_trial_names_the_object(client: TestClient, model_id: int) -> None:
    rng = np.random.default_rng(11)
    trial = scripted(client, model_id, target="O3", max_steps=8, tolerance=0.0)
    assert trial["status"] == "running"
    assert trial["prior_mean"]
    assert trial["prior_cov"]
    for step in range(1, 9):
        update = touch(client, trial["id"], 2, rng)
        assert update.status_code == 200, update.text
        body = update.json()
        assert body["step"] == step
        assert set(body["probabilities"]) == {"O1", "O2", "O3", "O4"}
        assert abs(sum(body["probabilities"].values()) - 1.0) < 1e-9
    assert body["done"] is True
    assert body["status"] == "completed"
    assert body["result"] == {"object": "O3", "correct": True}
    record = client.get(f"{API}/trials/{trial['id']}").json()
    assert [s["step"] for s in record["steps"]] == list(range(1, 9))
    assert record["result"] == {"object": "O3", "correct": True}
    assert record["reason"] == "max_steps"
    # A finished trial takes no more touches: 409 with its state.
    late = client.get(f"{API}/trials/{trial['id']}/next-action")
    assert late.status_code == 409
    assert late.json()["current_state"] == "completed"


def test_caller_may_post_its_own_action_without_asking(client: TestClient, model_id: int) -> None:
    trial = scripted(client, model_id, target="O1")
    response = client.post(
        f"{API}/trials/{trial['id']}/observations",
        json={"action": [0.25], "observation": [0.4, 0.9, 1.0]},
    )
    assert response.status_code == 200, response.text
    step = client.get(f"{API}/trials/{trial['id']}").json()["steps"][0]
    assert step["action"] == [0.25]
    assert step["observation"] == [0.4, 0.9, 1.0]
    assert step["mutual_information"] > 0


@pytest.mark.parametrize("mode", ["scripted", "simulated"])
def test_a_trial_stopped_by_the_confidence_rule_says_so(
    client: TestClient, model_id: int, mode: str
) -> None:
    body = {
        "model_id": model_id,
        "mode": mode,
        "target": "O2",
        "seed": 4,
        "max_steps": 20,
        "tolerance": 0.0,
        "confidence_threshold": 0.9,
    }
    created = client.post(f"{API}/trials", json=body)
    assert created.status_code == 201, created.text
    tid = created.json()["id"]
    if mode == "scripted":
        rng = np.random.default_rng(5)
        while True:
            update = touch(client, tid, 1, rng).json()
            if update["done"]:
                break
            assert update["stop_reason"] is None
        assert update["stop_reason"] == "confident"
        assert update["status"] == "completed"
    trial = wait_for(client, tid, lambda t: t["status"] == "completed")
    assert trial["reason"] == "confident"
    steps = trial["steps"]
    assert len(steps) < 20  # stopped before T by the rule
    assert steps[-1]["stop_reason"] == "confident"
    assert max(steps[-1]["probabilities"].values()) >= 0.9
    assert all(s["stop_reason"] is None for s in steps[:-1])
    assert all(max(s["probabilities"].values()) < 0.9 for s in steps[:-1])


@pytest.mark.parametrize(
    ("extra", "field"),
    [
        ({"prior_mean": [0.0, 1.0]}, "prior_mean"),
        ({"prior_cov": [[1.0, 0.0]]}, "prior_cov"),
        ({"prior_cov": [[-1.0]]}, "prior_cov"),
        ({"action_bounds": {"lower": [0.0, 0.0], "upper": [1.0, 1.0]}}, "action_bounds.lower"),
        ({"action_bounds": {"lower": [1.0], "upper": [0.0]}}, "action_bounds"),
        ({"policy": "fixed"}, "fixed_action"),
        ({"fixed_action": [0.5]}, "fixed_action"),
    ],
)
def test_bad_trial_settings_name_the_field(
    client: TestClient, model_id: int, extra: dict[str, Any], field: str
) -> None:
    response = client.post(
        f"{API}/trials", json={"model_id": model_id, "mode": "scripted", **extra}
    )
    assert response.status_code == 422, response.text
    assert response.json()["field"] == field


def test_bad_requests(client: TestClient, model_id: int) -> None:
    assert client.post(f"{API}/trials", json={"model_id": 999, "mode": "scripted"}).status_code == (
        404
    )
    no_target = simulated(client, model_id)
    assert no_target.status_code == 422
    assert no_target.json()["field"] == "target"
    unknown = simulated(client, model_id, target="O9")
    assert unknown.status_code == 422
    wrong_world = simulated(client, model_id, target="O1", simulation={"world": "experiment2"})
    assert wrong_world.status_code == 422
    assert "dx=6" in wrong_world.json()["detail"]
    trial = scripted(client, model_id)
    bad = client.post(
        f"{API}/trials/{trial['id']}/observations",
        json={"action": [0.1], "observation": [0.1, 0.2]},
    )
    assert bad.status_code == 422
    assert bad.json()["field"] == "observation"


def test_transitions_and_409s(client: TestClient, model_id: int) -> None:
    rng = np.random.default_rng(2)
    trial = scripted(client, model_id, target="O2", max_steps=20, tolerance=0.0)
    tid = trial["id"]
    assert touch(client, tid, 1, rng).status_code == 200
    assert client.post(f"{API}/trials/{tid}/resume").json()["current_state"] == "running"
    assert client.post(f"{API}/trials/{tid}/pause").json()["status"] == "paused"
    again = client.post(f"{API}/trials/{tid}/pause")
    assert again.status_code == 409
    assert again.json()["current_state"] == "paused"
    blocked = client.get(f"{API}/trials/{tid}/next-action")
    assert blocked.status_code == 409
    assert blocked.json()["current_state"] == "paused"
    assert client.post(f"{API}/trials/{tid}/resume").json()["status"] == "running"
    assert touch(client, tid, 1, rng).status_code == 200
    stopped = client.post(f"{API}/trials/{tid}/stop").json()
    assert stopped["status"] == "stopped"
    assert stopped["result"]["object"] == stopped["steps"][-1]["answer"]
    for action in ("pause", "resume", "stop", "abort"):
        response = client.post(f"{API}/trials/{tid}/{action}")
        assert response.status_code == 409
        assert response.json()["current_state"] == "stopped"
    assert client.post(f"{API}/trials/999/pause").status_code == 404


def test_simulated_trial_pause_resume_abort(client: TestClient, model_id: int) -> None:
    created = simulated(
        client,
        model_id,
        target="O4",
        seed=5,
        max_steps=1000,
        tolerance=0.0,
        simulation={"world": "experiment1", "step_interval_s": 0.01},
    )
    assert created.status_code == 201, created.text
    tid = created.json()["id"]
    wait_for(client, tid, lambda t: t["n_steps"] >= 2)
    paused = client.post(f"{API}/trials/{tid}/pause").json()
    assert paused["status"] == "paused"
    # At most the step in flight is recorded after the pause; then nothing more.
    held = wait_until_steady(client, tid)
    assert held <= paused["n_steps"] + 1
    time.sleep(0.3)
    assert client.get(f"{API}/trials/{tid}").json()["n_steps"] == held
    client.post(f"{API}/trials/{tid}/resume")
    wait_for(client, tid, lambda t: t["n_steps"] >= held + 2)
    aborted = client.post(f"{API}/trials/{tid}/abort").json()
    assert aborted["status"] == "aborted"
    assert aborted["result"] is None
    listing = client.get(f"{API}/trials", params={"model_id": model_id, "status": "aborted"})
    assert [t["id"] for t in listing.json()["data"]] == [tid]
    assert client.get(f"{API}/trials", params={"status": "running"}).json()["count"] == 0


def test_simulated_trial_completes_and_streams_events(client: TestClient, model_id: int) -> None:
    start = client.get(f"{API}/events?follow=false").text  # nothing new yet: empty
    assert start == ""
    created = simulated(client, model_id, target="O1", seed=1, max_steps=6, tolerance=0.0)
    tid = created.json()["id"]
    trial = wait_for(client, tid, lambda t: t["status"] == "completed")
    assert trial["n_steps"] == 6
    assert trial["result"] == {"object": "O1", "correct": True}
    stream = client.get(f"{API}/events?after=0&follow=false")
    assert stream.headers["content-type"].startswith("text/event-stream")
    events = parse_sse(stream.text)
    ids = [int(e["id"]) for e in events]
    assert ids == sorted(ids)
    assert len(set(ids)) == len(ids)
    steps = [e["data"]["data"] for e in events if e["data"]["type"] == "trial.step"]
    assert [s["step"] for s in steps if s["trial_id"] == tid] == list(range(1, 7))
    # Resume: with Last-Event-ID only what came after is sent.
    middle = ids[len(ids) // 2]
    resumed = parse_sse(
        client.get(f"{API}/events?follow=false", headers={"Last-Event-ID": str(middle)}).text
    )
    assert [int(e["id"]) for e in resumed] == [i for i in ids if i > middle]


def test_a_last_step_that_cannot_be_recorded_fails_the_trial(
    client: TestClient, model_id: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    # The last step is written after the touch source is let go: a failure there must still end
    # the trial (failed, saying why), not leave it running.
    from app.services.trials import TrialService

    store = TrialService._store_step

    def refuse_the_last(session: Any, trial: Any, model: Any, step: Any, *rest: Any) -> Any:
        if step.done:
            raise ValueError("disk full while writing the last step")
        return store(session, trial, model, step, *rest)

    monkeypatch.setattr(TrialService, "_store_step", staticmethod(refuse_the_last))
    created = simulated(client, model_id, target="O2", seed=1, max_steps=3, tolerance=0.0)
    assert created.status_code == 201, created.text
    trial = wait_for(client, created.json()["id"], lambda t: t["status"] != "running"
                     and t["status"] != "queued")  # fmt: skip
    assert trial["status"] == "failed"
    assert "disk full while writing the last step" in trial["reason"]
    assert trial["n_steps"] == 2


def parse_sse(text: str) -> list[dict[str, Any]]:
    import json

    events = []
    for block in text.strip().split("\n\n"):
        fields: dict[str, Any] = {}
        for line in block.splitlines():
            if line.startswith(":") or ": " not in line:
                continue
            key, value = line.split(": ", 1)
            fields[key] = json.loads(value) if key == "data" else value
        if "data" in fields:
            events.append(fields)
    return events


def test_restart_fails_running_trials_keeping_steps(tmp_path: Path) -> None:
    settings = make_settings(tmp_path)
    rng = np.random.default_rng(4)
    with TestClient(create_app(settings)) as first:
        model_id = import_model(first)
        trial = scripted(first, model_id, target="O2", max_steps=20, tolerance=0.0)
        for _ in range(3):
            assert touch(first, trial["id"], 1, rng).status_code == 200
        before = first.get(f"{API}/trials/{trial['id']}").json()
        assert before["status"] == "running"
    with TestClient(create_app(settings)) as second:
        after = second.get(f"{API}/trials/{trial['id']}").json()
    assert after["status"] == "failed"
    assert after["reason"] == "interrupted"
    assert after["steps"] == before["steps"]


def test_model_export_import_round_trip(client: TestClient, model_id: int) -> None:
    document = client.get(f"{API}/models/{model_id}/export").json()
    again = client.post(f"{API}/models/import", json=document)
    assert again.status_code == 201
    second = client.get(f"{API}/models/{again.json()['id']}/export").json()
    assert second == document  # arrays are stored exactly
    model = client.get(f"{API}/models/{model_id}").json()
    assert model["status"] == "ready"
    assert len(model["hyperparameters"]) == 3
    assert model["hyperparameters"][0]["action_lengthscales"] == [0.84]
    broken = client.post(f"{API}/models/import", json={"format": "activetouch-model/1"})
    assert broken.status_code == 422
    assert "objects" in broken.json()["detail"]


def test_simulated_worlds_have_the_cli_names_and_the_old_ones_as_aliases(
    client: TestClient, model_id: int
) -> None:
    """``exp1`` as ``activetouch`` and the evaluations say; ``experiment1`` still means it."""
    results = []
    for world in ("exp1", "experiment1"):
        created = simulated(
            client,
            model_id,
            target="O2",
            seed=8,
            max_steps=3,
            tolerance=0.0,
            simulation={"world": world},
        )
        assert created.status_code == 201, created.text
        done = wait_for(client, created.json()["id"], lambda t: t["status"] == "completed")
        results.append([(s["action"], s["observation"]) for s in done["steps"]])
    assert results[0] == results[1]
    unknown = simulated(client, model_id, target="O2", simulation={"world": "experiment3"})
    assert unknown.status_code == 422
    assert "exp1" in unknown.text
    assert "exp2" in unknown.text


def test_the_api_names_the_policies_and_worlds_of_the_registries() -> None:
    """The schemas list them without loading the numerics; they must agree with the registries."""
    from typing import get_args

    from app.schemas import SimulationOptions, TrialCreate
    from core.evaluation.worlds import WORLD_NAMES
    from core.recognition.planning import POLICY_NAMES

    assert get_args(TrialCreate.model_fields["policy"].annotation) == POLICY_NAMES
    worlds = get_args(SimulationOptions.model_fields["world"].annotation)
    assert worlds == (*WORLD_NAMES, "rig")
