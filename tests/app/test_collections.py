"""Collection designs on the simulated rig: what the stored dataset's actions are.

``random`` draws a fresh action for every touch (the paper's design,
``core.evaluation.designs.random_design``: each object its own actions); ``shared`` touches every
object with the same M actions (``core.evaluation.designs.shared_design``); ``teaching`` repeats x =
0.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from app.documents.training_csv import read_training_csv
from app.main import create_app
from app.schemas import CollectionCreate
from core.evaluation.designs import random_design, shared_design
from core.types import TrainingData
from tests.app.conftest import TestClient, make_settings
from tests.app.waits import finished, wait_until

API = "/api/v1"
CUPS = ["paper_cup", "bumpy_glass", "stainless_cup"]
TOUCHES = 3
SEED = 11
SCALE = 0.5


def collect(client: TestClient, design: str) -> TrainingData:
    """Run a collection of the three cups with ``design``, a placement per touch; the stored
    dataset."""
    return collect_with(client, design, TOUCHES, placements=TOUCHES)


def collect_with(
    client: TestClient, design: str, touches: int, placements: int | None = None
) -> TrainingData:
    """Run a collection of the three cups, ``touches`` each, with ``design`` (and
    ``placements`` per object, ``None``: the default); the dataset."""
    body: dict[str, Any] = {
        "objects": [{"name": n, "slot": i} for i, n in enumerate(CUPS)],
        "samples_per_object": touches,
        "action_design": design,
        "action_scale": SCALE,
        "seed": SEED,
    }
    if placements is not None:
        body["placements"] = placements
    created = client.post(f"{API}/collections", json=body)
    assert created.status_code == 201, created.text
    assert created.json()["total"] == len(CUPS) * touches
    run = wait_until(client, f"{API}/collections/{created.json()['id']}", finished)
    assert run["status"] == "completed", run
    assert client.get(f"{API}/datasets/{run['dataset_id']}").json()["status"] == "ready"
    data = read_training_csv(client.get(f"{API}/datasets/{run['dataset_id']}/export").text)
    assert data.object_names == tuple(CUPS)
    assert np.bincount(data.object_index).tolist() == [touches] * len(CUPS)
    return data


def per_object(data: TrainingData) -> list[np.ndarray]:
    """Each object's actions, in the order it was touched. Shape (TOUCHES, dx) each."""
    return [data.actions[data.object_index == obj] for obj in range(data.n_objects)]


def test_random_design_draws_every_touch_afresh(client: TestClient) -> None:
    data = collect(client, "random")
    actions = per_object(data)
    # Every touch its own action: no two touches (of one object or of two) share one.
    assert np.unique(data.actions, axis=0).shape[0] == len(CUPS) * TOUCHES
    for a in range(len(CUPS)):
        for b in range(a + 1, len(CUPS)):
            assert not np.allclose(actions[a], actions[b])
    # The paper's design of core.evaluation.designs; with a placement per touch it is touched in
    # rounds (each object's next action in turn).
    cov = SCALE**2 * np.eye(data.action_dim)
    expected = random_design(
        len(CUPS), TOUCHES, np.zeros(data.action_dim), cov, np.random.default_rng(SEED)
    )
    np.testing.assert_array_equal(data.object_index, np.tile(np.arange(len(CUPS)), TOUCHES))
    for obj, mine in enumerate(actions):
        np.testing.assert_array_equal(mine, expected.actions[expected.object_index == obj])


@pytest.mark.parametrize("design", ["shared", "teaching"])
def test_shared_designs_give_every_object_the_same_actions(client: TestClient, design: str) -> None:
    data = collect(client, design)
    actions = per_object(data)
    for other in actions[1:]:  # the same actions, each object in its own order
        np.testing.assert_array_equal(np.unique(other, axis=0), np.unique(actions[0], axis=0))
    if design == "teaching":
        np.testing.assert_array_equal(actions[0], np.zeros_like(actions[0]))
        return
    assert np.unique(actions[0], axis=0).shape[0] == TOUCHES
    cov = SCALE**2 * np.eye(data.action_dim)
    expected = shared_design(
        len(CUPS), TOUCHES, np.zeros(data.action_dim), cov, np.random.default_rng(SEED)
    )
    np.testing.assert_array_equal(
        np.unique(actions[0], axis=0),
        np.unique(expected.actions[expected.object_index == 0], axis=0),
    )
    # One action's touches do not follow each other on the turntable (drift, iter_collect).
    assert not all(np.array_equal(other, actions[0]) for other in actions[1:])


def test_the_spread_defaults_to_the_simulated_tables_own(tmp_path: Path) -> None:
    # The mock rig on the cushions (action_std 1.5): no action_scale takes the table's spread,
    # and the run's params record the spread used.
    settings = make_settings(tmp_path, sim_table="cushions")
    names = ["cushion_plain", "cushion_cork"]
    with TestClient(create_app(settings)) as client:
        created = client.post(
            f"{API}/collections",
            json={
                "objects": [{"name": n, "slot": i} for i, n in enumerate(names)],
                "samples_per_object": 2,
                "seed": SEED,
            },
        )
        assert created.status_code == 201, created.text
        assert created.json()["params"]["action_scale"] == 1.5
        run: dict[str, Any] = created.json()
        deadline = time.monotonic() + 120
        while run["status"] in ("queued", "running") and time.monotonic() < deadline:
            time.sleep(0.05)
            run = client.get(f"{API}/collections/{run['id']}").json()
        assert run["status"] == "completed", run
        data = read_training_csv(client.get(f"{API}/datasets/{run['dataset_id']}/export").text)
    dx = data.action_dim
    expected = random_design(2, 2, np.zeros(dx), 2.25 * np.eye(dx), np.random.default_rng(SEED))
    for obj, mine in enumerate(per_object(data)):
        np.testing.assert_array_equal(mine, expected.actions[expected.object_index == obj])


def test_without_action_design_the_run_is_adaptive_or_random_below_three(
    client: TestClient,
) -> None:
    # The default of docs/usage.md: adaptive; random where adaptive cannot run (< 3 touches).
    # The run's params record the design used.
    body = {"objects": [{"name": n, "slot": i} for i, n in enumerate(CUPS)], "seed": SEED}
    for touches, design in ((3, "adaptive"), (2, "random")):
        created = client.post(f"{API}/collections", json={**body, "samples_per_object": touches})
        assert created.status_code == 201, created.text
        assert created.json()["params"]["action_design"] == design
        run = wait_until(client, f"{API}/collections/{created.json()['id']}", finished)
        assert run["status"] == "completed", run
    assert CollectionCreate.model_fields["action_design"].default is None


def test_adaptive_design_spends_the_budget_in_planned_rounds(client: TestClient) -> None:
    data = collect_with(client, "adaptive", touches=6)
    # The first half is the random design's, touched in rounds; then rounds (2 and 1 actions)
    # of planned actions, each on every object: every object touched 6 times.
    dx = data.action_dim
    cov = SCALE**2 * np.eye(dx)
    expected = random_design(len(CUPS), 3, np.zeros(dx), cov, np.random.default_rng(SEED))
    for obj, mine in enumerate(per_object(data)):
        np.testing.assert_array_equal(mine[:3], expected.actions[expected.object_index == obj])
        # Each planned round on every object, each object in its own order.
        for stage in (slice(3, 5), slice(5, 6)):
            np.testing.assert_array_equal(
                np.unique(mine[stage], axis=0), np.unique(per_object(data)[0][stage], axis=0)
            )
    too_few = client.post(
        f"{API}/collections",
        json={
            "objects": [{"name": n, "slot": i} for i, n in enumerate(CUPS)],
            "samples_per_object": 2,
            "action_design": "adaptive",
        },
    )
    assert too_few.status_code == 422
    assert "samples_per_object" in too_few.text
