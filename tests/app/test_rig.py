"""Rig endpoints, collections on the simulated rig, rig trials, one owner at a time."""

from __future__ import annotations

import json
import time
from typing import Any

import numpy as np

from app.documents.model import model_to_document
from app.documents.training_csv import read_training_csv
from core.gp.posterior import condition
from core.types import Hyperparameters
from hardware.frames import CHANNELS
from tests.app.conftest import TestClient
from tests.app.waits import wait_until

API = "/api/v1"
CUPS = ["paper_cup", "bumpy_glass"]


def collect_cups(client: TestClient, samples_per_object: int, seed: int) -> Any:
    """Start a collection of :data:`CUPS` (slots 0, 1, ...); the API's response."""
    return client.post(
        f"{API}/collections",
        json={
            "objects": [{"name": n, "slot": i} for i, n in enumerate(CUPS)],
            "samples_per_object": samples_per_object,
            "seed": seed,
        },
    )


def test_rig_operations_and_estop(client: TestClient) -> None:
    assert client.get(f"{API}/rig").json()["state"] == "disconnected"
    connected = client.post(f"{API}/rig/connect").json()
    assert connected["connected"] is True
    assert connected["state"] == "idle"
    assert connected["detail"]["objects_by_slot"] == [
        "paper_cup", "bumpy_glass", "clear_plastic_cup", "stainless_cup",
        "ceramic_mug", "wooden_block", "foam_sponge",
    ]  # fmt: skip
    known = connected["detail"]["object_properties"]
    assert known["foam_sponge"]["slot"] == 6
    assert known["stainless_cup"]["thermal_effusivity_w_s05_per_m2_k"] == 7600.0
    assert client.post(f"{API}/rig/turntable", json={"slot": 2}).json()["detail"]["slot"] == 2
    bad = client.post(f"{API}/rig/turntable", json={"slot": 99})
    assert bad.status_code == 422
    stopped = client.post(f"{API}/rig/estop").json()
    assert stopped["state"] == "estopped"
    refused = client.post(f"{API}/rig/turntable", json={"slot": 1})
    assert refused.status_code == 503
    assert "emergency" in refused.json()["detail"]
    assert client.post(f"{API}/rig/connect").json()["state"] == "idle"  # recover


def rig_model_document(client: TestClient, dataset_id: int) -> dict[str, Any]:
    """A model of the collected data (fixed latents and hyperparameters: no fit)."""
    data = read_training_csv(client.get(f"{API}/datasets/{dataset_id}/export").text)
    dy, dx = data.observation_dim, data.action_dim
    spread = data.observations.std(axis=0) + 1e-3
    hyper = Hyperparameters(
        signal_variance=spread**2,
        noise_variance=0.05 * spread**2,
        latent_lengthscales=np.ones((dy, 1)),
        action_lengthscales=np.full((dy, dx), 2.0),
    )
    return model_to_document(condition(data, np.array([[-1.0], [1.0]]), hyper))


def test_collection_then_rig_trial_hold_the_rig(client: TestClient) -> None:
    created = collect_cups(client, 2, seed=3)
    assert created.status_code == 201, created.text
    run = created.json()
    assert run["total"] == 4
    # One owner at a time: a second run and operator moves get 409 naming the holder.
    busy = client.post(f"{API}/rig/home")
    if busy.status_code == 409:  # (unless the collection already finished)
        assert busy.json()["held_by"] == f"collection {run['id']}"
    second = client.post(
        f"{API}/collections",
        json={"objects": [{"name": "a", "slot": 5}, {"name": "b", "slot": 6}]},
    )
    assert second.status_code in (201, 409)
    if second.status_code == 409:
        assert second.json()["held_by"] == f"collection {run['id']}"
    else:  # the first was done: stop the second before going on
        client.post(f"{API}/collections/{second.json()['id']}/abort")
        client.post(f"{API}/rig/connect")
    finished = wait_until(
        client, f"{API}/collections/{run['id']}", lambda r: r["status"] == "completed"
    )
    assert finished["done"] == 4
    dataset = client.get(f"{API}/datasets/{finished['dataset_id']}").json()
    assert dataset["status"] == "ready"
    assert (dataset["n_samples"], dataset["action_dim"], dataset["observation_dim"]) == (4, 7, 5)
    assert dataset["objects"] == CUPS
    registry = {o["name"]: o for o in client.get(f"{API}/objects").json()["data"]}
    assert registry["bumpy_glass"]["slot"] == 1
    glass = registry["bumpy_glass"]["properties"]  # what the simulated table knows of it
    assert glass["material"] == "glass, moulded bumps"
    assert glass["stiffness_n_per_mm"] == 60.0
    assert glass["friction"] == 0.70
    assert glass["roughness_um"] == 80.0
    assert glass["thermal_effusivity_w_s05_per_m2_k"] == 1450.0
    assert glass["temperature_c"] == 22.0
    assert "slot" not in glass
    events = [
        json.loads(line.removeprefix("data: "))
        for line in client.get(f"{API}/events?after=0&follow=false").text.splitlines()
        if line.startswith("data: ")
    ]
    progress = [e["data"] for e in events if e["type"] == "collection.progress"]
    assert len(progress) == 4
    for event in progress:  # the live trace of the touch just recorded, thinned
        trace = event["trace"]
        assert trace["channel_names"] == list(CHANNELS)
        times, tactile = np.array(trace["tactile_times_s"]), np.array(trace["tactile"])
        assert trace["n_frames"] > 1000  # a 14.4 s touch at 100 frames/s
        assert tactile.shape == (200, 5)
        assert times.shape == (200,)
        assert np.all(np.diff(times) > 0)
        assert times[0] >= 0.0
        assert times[-1] > 14.0
        # Raw frames, not averages: the trace's per-channel mean is close to the features y.
        np.testing.assert_allclose(tactile.mean(axis=0), event["observation"], rtol=0.2, atol=0.1)

    model = client.post(
        f"{API}/models/import", json=rig_model_document(client, finished["dataset_id"])
    )
    assert model.status_code == 201, model.text
    trial = client.post(
        f"{API}/trials",
        json={"model_id": model.json()["id"], "mode": "rig", "target": "bumpy_glass",
              "max_steps": 2, "tolerance": 0.0, "seed": 1},
    )  # fmt: skip
    assert trial.status_code == 201, trial.text
    assert trial.json()["options"]["target_slot"] == 1
    done = wait_until(
        client, f"{API}/trials/{trial.json()['id']}", lambda t: t["status"] != "queued"
        and t["status"] != "running",
    )  # fmt: skip
    assert done["status"] == "completed", done
    assert done["n_steps"] == 2
    step = done["steps"][0]
    assert len(step["action"]) == 7  # with the press depth
    assert len(step["observation"]) == 5
    assert step["trajectory"]["slot"] == 1
    assert len(step["trajectory"]["commanded_deg"][0]) == 2
    assert done["result"]["object"] in CUPS
    assert client.get(f"{API}/rig").json()["held_by"] is None
    # A simulated trial on the simulated table may touch any object on it, not only the cups.
    sponge = client.post(
        f"{API}/trials",
        json={"model_id": model.json()["id"], "mode": "simulated", "target": "foam_sponge",
              "max_steps": 1, "seed": 2, "simulation": {"world": "rig"}},
    )  # fmt: skip
    assert sponge.status_code == 201, sponge.text
    ended = wait_until(
        client, f"{API}/trials/{sponge.json()['id']}", lambda t: t["status"] not in
        ("queued", "running"),
    )  # fmt: skip
    assert ended["status"] == "completed", ended


def test_rig_trial_needs_matching_model_and_slot(client: TestClient) -> None:
    from tests.app.conftest import import_model

    model_id = import_model(client)  # Experiment 1: dx = 1, not the rig's 6
    response = client.post(
        f"{API}/trials", json={"model_id": model_id, "mode": "rig", "target_slot": 0}
    )
    assert response.status_code == 422
    assert "dx=6" in response.json()["detail"]


def test_estop_aborts_the_collection_keeping_its_samples(client: TestClient) -> None:
    created = collect_cups(client, 50, seed=1).json()
    wait_until(client, f"{API}/collections/{created['id']}", lambda r: r["done"] >= 1)
    assert client.post(f"{API}/rig/estop").json()["state"] == "estopped"
    run = wait_until(
        client, f"{API}/collections/{created['id']}", lambda r: r["status"] != "running"
    )
    assert run["status"] == "aborted"
    assert "operator" in run["reason"]
    dataset = client.get(f"{API}/datasets/{run['dataset_id']}").json()
    assert dataset["n_samples"] == run["done"] >= 1
    assert client.get(f"{API}/rig").json()["held_by"] is None
    again = client.post(f"{API}/rig/turntable", json={"slot": 0})
    assert again.status_code == 503  # stays stopped until recovered
    assert client.post(f"{API}/rig/connect").json()["state"] == "idle"


def test_device_fault_fails_the_run_with_reason_and_keeps_samples(client: TestClient) -> None:
    from hardware.errors import ServoHardwareErrorFlags

    created = collect_cups(client, 50, seed=2).json()
    wait_until(client, f"{API}/collections/{created['id']}", lambda r: r["done"] >= 2)
    simulation = client.app.state.context.rig.handle().simulation  # type: ignore[attr-defined]
    simulation.devices.plant.inject_hardware_error(0, ServoHardwareErrorFlags.OVERLOAD)
    run = wait_until(
        client, f"{API}/collections/{created['id']}", lambda r: r["status"] != "running"
    )
    assert run["status"] == "failed"
    assert "ServoHardwareError" in run["reason"]
    assert "OVERLOAD" in run["reason"]
    dataset = client.get(f"{API}/datasets/{run['dataset_id']}").json()
    assert dataset["n_samples"] == run["done"] >= 2
    assert client.get(f"{API}/rig").json()["state"] == "fault"


def test_a_rig_trial_seen_ended_no_longer_holds_the_rig(
    client: TestClient, monkeypatch: Any
) -> None:
    # Closing the rig's touch source (it gives the lease back) is made slow: the trial must
    # still show as completed only once the rig is free, never completed but held.
    from app.services.worlds import WorldFactory

    opened = WorldFactory.open

    def open_slowly(self: WorldFactory, *args: Any, **kwargs: Any) -> Any:
        source = opened(self, *args, **kwargs)
        close = source.close

        def slow_close() -> None:
            time.sleep(0.5)
            close()

        source.close = slow_close
        return source

    monkeypatch.setattr(WorldFactory, "open", open_slowly)
    rows = ["object," + ",".join(f"x_{i}" for i in range(1, 7)) + ","
            + ",".join(f"y_{i}" for i in range(1, 6))]  # fmt: skip
    rng = np.random.default_rng(5)
    for name in CUPS:
        for _ in range(4):
            values = np.concatenate([0.3 * rng.standard_normal(6), rng.random(5)])
            rows.append(name + "," + ",".join(f"{v:.6f}" for v in values))
    dataset = client.post(
        f"{API}/datasets", content="\n".join(rows) + "\n", headers={"content-type": "text/csv"}
    )
    assert dataset.status_code == 201, dataset.text
    model = client.post(
        f"{API}/models/import", json=rig_model_document(client, dataset.json()["id"])
    )
    assert model.status_code == 201, model.text
    trial = client.post(
        f"{API}/trials",
        json={"model_id": model.json()["id"], "mode": "rig", "target_slot": 0,
              "max_steps": 1, "seed": 1},
    )  # fmt: skip
    assert trial.status_code == 201, trial.text
    path = f"{API}/trials/{trial.json()['id']}"
    done = wait_until(client, path, lambda t: t["status"] not in ("queued", "running"))
    rig = client.get(f"{API}/rig").json()
    assert done["status"] == "completed", done
    assert rig["held_by"] is None, rig


def test_a_collection_seen_ended_no_longer_holds_the_rig(
    client: TestClient, monkeypatch: Any
) -> None:
    # The rig service's lease gives the reservation back as the touching ends, before the
    # run is ended: a guard on that order (the race a trial had, see the test above).
    from app.services.collections import CollectionService

    holders: list[str | None] = []
    finish = CollectionService._finish

    def finish_and_note(self: CollectionService, *args: Any) -> None:
        holders.append(self._rig.holder)  # who holds the rig as the run is ended
        finish(self, *args)

    monkeypatch.setattr(CollectionService, "_finish", finish_and_note)
    created = collect_cups(client, 2, seed=4)
    assert created.status_code == 201, created.text
    path = f"{API}/collections/{created.json()['id']}"
    done = wait_until(client, path, lambda r: r["status"] not in ("queued", "running"))
    assert done["status"] == "completed", done
    assert holders == [None], holders
    assert client.get(f"{API}/rig").json()["held_by"] is None
