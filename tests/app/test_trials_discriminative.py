"""The API's discriminative policy: a scripted trial asks for actions aimed at the object."""

from __future__ import annotations

import numpy as np
from fastapi.testclient import TestClient

from tests.app.test_trials import API, model_id, scripted, touch

__all__ = ["model_id"]  # the fixture


def test_a_discriminative_trial_recognises_the_object(client: TestClient, model_id: int) -> None:
    rng = np.random.default_rng(11)
    trial = scripted(
        client, model_id, target="O3", max_steps=6, tolerance=0.0, policy="discriminative"
    )
    assert trial["policy"] == "discriminative"
    for _ in range(6):
        update = touch(client, trial["id"], 2, rng)
        assert update.status_code == 200, update.text
    body = update.json()
    assert body["done"] is True
    assert body["result"] == {"object": "O3", "correct": True}
    bad = client.post(
        f"{API}/trials", json={"model_id": model_id, "mode": "scripted", "policy": "greedy"}
    )
    assert bad.status_code == 422
