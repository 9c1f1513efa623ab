"""Fixtures of the app tests: settings on a temporary SQLite file, an app and a TestClient.

The app applies its Alembic migrations to the empty file at start-up, as in production.
"""

from __future__ import annotations

import warnings
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

with warnings.catch_warnings():
    warnings.simplefilter("ignore")
    from fastapi.testclient import TestClient

from app.config import Settings
from app.documents.model import model_to_document
from app.main import create_app
from core.evaluation.reference_model import experiment1_at_true_latents
from core.evaluation.worlds import sample_experiment1


def make_settings(tmp_path: Path, **overrides: object) -> Settings:
    """Settings for a test app: temp DB file, mock hardware, no .env, no frontend."""
    values: dict[str, object] = {
        "database_url": f"sqlite:///{tmp_path / 'test.db'}",
        "hardware": "mock",
        "frontend_dir": tmp_path / "no-frontend",
    }
    values.update(overrides)
    return Settings(_env_file=None, **values)  # type: ignore[call-arg]


@pytest.fixture
def settings(tmp_path: Path) -> Settings:
    """Test settings (temporary database)."""
    return make_settings(tmp_path)


@pytest.fixture
def client(settings: Settings) -> Iterator[TestClient]:
    """A client of a freshly built app (lifespan run: migrations from empty)."""
    with TestClient(create_app(settings)) as test_client:
        yield test_client


def experiment1_csv(seed: int = 0, touches_per_object: int = 12) -> str:
    """An Experiment 1 training CSV (objects O1..O4, dx=1, dy=3)."""
    data = sample_experiment1(np.random.default_rng(seed), touches_per_object=touches_per_object)
    lines = ["object,x_1,y_1,y_2,y_3"]
    for obj, x, y in zip(data.object_index, data.actions, data.observations, strict=True):
        values = [repr(float(v)) for v in (*x, *y)]
        lines.append(",".join([data.object_names[obj], *values]))
    return "\n".join(lines) + "\n"


def experiment1_document(seed: int = 0, touches_per_object: int = 25) -> dict[str, object]:
    """The document of :func:`core.evaluation.reference_model.experiment1_at_true_latents`
    (no fit)."""
    return model_to_document(experiment1_at_true_latents(seed, touches_per_object))


def import_model(client: TestClient, seed: int = 0) -> int:
    """Import an Experiment 1 model through the API; return its id."""
    response = client.post("/api/v1/models/import", json=experiment1_document(seed))
    assert response.status_code == 201, response.text
    model_id: int = response.json()["id"]
    return model_id
