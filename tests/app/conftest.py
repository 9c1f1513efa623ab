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
from core.types import ManifoldModel, TrainingData
from tests.conftest import SETTLE_S


def make_settings(tmp_path: Path, **overrides: object) -> Settings:
    """Settings for a test app: temp DB file, mock hardware resting
    :data:`tests.conftest.SETTLE_S` before each touch, no .env, no frontend."""
    values: dict[str, object] = {
        "database_url": f"sqlite:///{tmp_path / 'test.db'}",
        "hardware": "mock",
        "settle_s": SETTLE_S,
        "frontend_dir": tmp_path / "no-frontend",
    }
    values.update(overrides)
    return Settings(_env_file=None, **values)  # type: ignore[call-arg]


@pytest.fixture
def settings(tmp_path: Path) -> Settings:
    """Test settings (temporary database)."""
    return make_settings(tmp_path)


@pytest.fixture
def cli_rig_rest(monkeypatch: pytest.MonkeyPatch) -> None:
    """The CLI's simulated rig (``--sim``) rests :data:`tests.conftest.SETTLE_S` before each
    touch, as the test servers' does (``ACTIVETOUCH_SETTLE_S``, the default of ``--settle``)."""
    monkeypatch.setenv("ACTIVETOUCH_SETTLE_S", str(SETTLE_S))


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


RIG_OBJECTS = ("paper_cup", "ceramic_mug", "foam_sponge")
"""The objects of :func:`rig_model` (of the simulated rig's ``default`` table)."""


def fitted_on_the_rig(
    table: str,
    objects: tuple[str, ...],
    touches: int,
    latent_dim: int,
    seed: int,
    press_depth: bool = False,
) -> ManifoldModel:
    """A model fitted on ``touches`` random touches of each of ``objects`` on a simulated table
    (with the press-depth action component if ``press_depth``)."""
    from app.evaluation.context import rig_tables
    from app.rig.actions import TouchActions
    from app.rig.build import SimulationMode, open_rig
    from app.rig.collection import iter_collect
    from core.gp.manifold import FitOptions, fit_manifold

    slots_of = rig_tables()[table]
    handle = open_rig(simulate=SimulationMode.in_process, table=table, seed=seed)
    try:
        lease = handle.rig.acquire("test")
        lease.connect()
        actions = TouchActions.from_teaching(press_depth=press_depth)
        design = np.random.default_rng(seed).standard_normal((touches, actions.action_dim))
        slots = {name: slots_of.index(name) for name in objects}
        collected = list(iter_collect(lease, actions, slots, design))
        lease.release()
    finally:
        handle.close()
    data = TrainingData(
        object_names=objects,
        object_index=np.array([objects.index(t.object_name) for t in collected]),
        actions=np.array([t.action for t in collected]),
        observations=np.array([t.record.observation for t in collected]),
    )
    return fit_manifold(data, latent_dim, np.random.default_rng(0), FitOptions(restarts=0))


@pytest.fixture(scope="session")
def rig_model() -> ManifoldModel:
    """A ds=2 model fitted on 6 touches of :data:`RIG_OBJECTS` of the default simulated table.

    Collecting and fitting it takes seconds, so the rig evaluation tests share one (read only).
    """
    return fitted_on_the_rig("default", RIG_OBJECTS, touches=6, latent_dim=2, seed=3)
