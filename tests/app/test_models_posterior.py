"""A stored model is rebuilt with the posterior it was conditioned with, not ``"auto"``.

Models imported with a non-default structure (dense on a shared design, sparse with a chosen
number of inducing points, sparse with inducing points of their own) predict the same to 1e-10
once they have left the in-memory cache (a small cache, or a fresh app on the same database
file), and export the same ``posterior`` document.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest

from app.config import Settings
from app.db.tables import ModelRecord
from app.documents.errors import DocumentError
from app.documents.model import model_to_document
from app.documents.posterior import condition_as_recorded, posterior_field
from app.main import create_app
from app.services.events import EventBus
from app.services.models import ReadyModels, StoredModelError
from core.gp.posterior import condition, predict
from core.gp.sparse import condition_sparse, select_inducing_points
from core.types import InducingPoints, ManifoldModel
from tests.app.conftest import TestClient
from tests.app.posterior_cases import (
    HYPER,
    LATENTS,
    QUERY_S,
    QUERY_X,
    TOLERANCE,
    random_data,
    shared_data,
)

API = "/api/v1"
OWN_INDUCING = np.array([0, 5, 16, 17, 30, 44, 59], dtype=np.int64)


def dense_on_shared() -> ManifoldModel:
    """Dense, where ``"auto"`` would choose Kronecker."""
    return condition(shared_data(), LATENTS, HYPER, structure="dense")


def sparse_selected() -> ManifoldModel:
    """Sparse with m = 9 < N = 60, where ``"auto"`` would choose dense."""
    return condition(random_data(), LATENTS, HYPER, structure="sparse", n_inducing=9)


def sparse_own_points() -> ManifoldModel:
    """Sparse with inducing points the default selection would not pick."""
    data = random_data()
    inducing = InducingPoints(
        object_index=data.object_index[OWN_INDUCING],
        actions=data.actions[OWN_INDUCING],
        touch_index=OWN_INDUCING,
    )
    assert not np.array_equal(select_inducing_points(data, 7).touch_index, OWN_INDUCING)
    return condition_sparse(data, LATENTS, HYPER, inducing=inducing)


MODELS: dict[str, Callable[[], ManifoldModel]] = {
    "dense_on_shared": dense_on_shared,
    "sparse_selected": sparse_selected,
    "sparse_own_points": sparse_own_points,
}


def max_prediction_gap(a: ManifoldModel, b: ManifoldModel) -> float:
    return max(
        float(np.max(np.abs(left - right)))
        for left, right in zip(
            predict(a, QUERY_S, QUERY_X), predict(b, QUERY_S, QUERY_X), strict=True
        )
    )


def import_document(client: TestClient, model: ManifoldModel) -> int:
    response = client.post(
        f"{API}/models/import", json=json.loads(json.dumps(model_to_document(model)))
    )
    assert response.status_code == 201, response.text
    model_id: int = response.json()["id"]
    return model_id


@pytest.mark.parametrize("which", sorted(MODELS))
def test_evicted_model_predicts_as_imported(client: TestClient, which: str) -> None:
    original = MODELS[which]()
    model_id = import_document(client, original)
    context = client.app.state.context  # type: ignore[attr-defined]
    # A store with an empty cache of one model: the second load evicts the first.
    store = ReadyModels(context.database, EventBus(context.database), cache_size=1)
    other_id = import_document(client, condition(random_data(), LATENTS, HYPER))
    with context.database.session() as session:
        row = session.get(ModelRecord, model_id)
        assert row is not None
        assert row.posterior == posterior_field(original.posterior)
        first = store.load(session, model_id)
        store.load(session, other_id)  # evicts model_id
        rebuilt = store.load(session, model_id)
        exported = store.export_document(session, model_id)
    assert rebuilt is not first  # really rebuilt from the row
    for model in (first, rebuilt):
        assert model.posterior.structure == original.posterior.structure
        assert max_prediction_gap(original, model) <= TOLERANCE
    assert exported["posterior"] == model_to_document(original)["posterior"]
    if original.posterior.inducing is not None:
        assert rebuilt.posterior.inducing is not None
        np.testing.assert_array_equal(
            rebuilt.posterior.inducing.touch_index, original.posterior.inducing.touch_index
        )


def test_a_fresh_app_on_the_same_database_exports_the_same_documents(settings: Settings) -> None:
    originals = {which: make() for which, make in MODELS.items()}
    with TestClient(create_app(settings)) as client:
        ids = {which: import_document(client, model) for which, model in originals.items()}
        before = {which: client.get(f"{API}/models/{i}/export").json() for which, i in ids.items()}
    with TestClient(create_app(settings)) as client:  # empty cache: every model rebuilt
        after = {which: client.get(f"{API}/models/{i}/export").json() for which, i in ids.items()}
        context = client.app.state.context  # type: ignore[attr-defined]
        with context.database.session() as session:
            rebuilt = {which: context.models.load(session, i) for which, i in ids.items()}
    for which, original in originals.items():
        assert after[which] == before[which]
        assert after[which]["posterior"] == model_to_document(original)["posterior"]
        assert max_prediction_gap(original, rebuilt[which]) <= TOLERANCE


def test_without_the_record_a_sparse_model_would_come_back_otherwise() -> None:
    """The defect this guards against: ``"auto"`` rebuilds these sparse models dense, and their
    predictions move (the tests above could fail)."""
    for make in (sparse_selected, sparse_own_points):
        original = make()
        auto = condition(original.data, original.latents, HYPER)
        assert auto.posterior.structure == "dense"
        assert max_prediction_gap(original, auto) > 1e-6
        assert (
            condition_as_recorded(
                original.data, original.latents, HYPER, None, None
            ).posterior.structure
            == "dense"
        )


@pytest.mark.parametrize(
    ("record", "fragment"),
    [
        ({"structure": "diagonal"}, "model row: posterior.structure"),
        ({"structure": "sparse", "inducing_touches": [0, 60]}, "outside 0..59"),
        ({"structure": "sparse", "inducing_touches": [3, 3]}, "distinct"),
        ({"structure": "sparse", "inducing_touches": []}, "distinct"),
        ({"structure": "sparse"}, "needs 'inducing_touches' or an integer 'n_inducing'"),
    ],
)
def test_a_malformed_record_says_what_is_wrong(record: dict[str, Any], fragment: str) -> None:
    with pytest.raises(DocumentError, match=fragment):
        condition_as_recorded(random_data(), LATENTS, HYPER, None, record, where="model row")


def test_a_corrupted_row_is_a_server_error_naming_the_model(client: TestClient) -> None:
    model_id = import_document(client, sparse_selected())
    context = client.app.state.context  # type: ignore[attr-defined]
    with context.database.session() as session:
        row = session.get(ModelRecord, model_id)
        assert row is not None
        row.posterior = {"structure": "kronecker"}  # random data: not a shared design
        session.commit()
    store = ReadyModels(context.database, EventBus(context.database))
    with (
        context.database.session() as session,
        pytest.raises(StoredModelError, match=f"Model {model_id} cannot be rebuilt") as info,
    ):
        store.load(session, model_id)
    assert "model row: " in str(info.value)  # the recorded structure does not fit the data


def test_get_model_shows_how_it_was_conditioned(client: TestClient) -> None:
    expected: dict[int, dict[str, Any]] = {}
    for make in (*MODELS.values(), lambda: condition(shared_data(), LATENTS, HYPER)):
        original = make()
        expected[import_document(client, original)] = {
            "structure": original.posterior.structure,
            "n_inducing": None,
            "inducing_touches": None,
            **posterior_field(original.posterior),
        }
    shown = {i: client.get(f"{API}/models/{i}").json()["posterior"] for i in expected}
    assert shown == expected
    assert sorted(record["structure"] for record in shown.values()) == [
        "dense",
        "kronecker",
        "sparse",
        "sparse",
    ]
    own = next(r for r in shown.values() if r["n_inducing"] == OWN_INDUCING.size)
    assert own["inducing_touches"] == OWN_INDUCING.tolist()
    listed = client.get(f"{API}/models").json()["data"]
    assert {m["id"]: m["posterior"] for m in listed} == expected


def test_a_model_without_a_usable_record_shows_no_posterior(client: TestClient) -> None:
    """Rows from before the record (NULL), and a record changed behind the server's back: the
    model still reads (posterior null); only using it fails."""
    old_id = import_document(client, dense_on_shared())
    broken_id = import_document(client, sparse_selected())
    context = client.app.state.context  # type: ignore[attr-defined]
    with context.database.session() as session:
        for model_id, record in ((old_id, None), (broken_id, {"structure": "diagonal"})):
            row = session.get(ModelRecord, model_id)
            assert row is not None
            row.posterior = record
        session.commit()
    for model_id in (old_id, broken_id):
        response = client.get(f"{API}/models/{model_id}")
        assert response.status_code == 200, response.text
        assert response.json()["status"] == "ready"
        assert response.json()["posterior"] is None


def test_the_posterior_is_documented_in_the_openapi_schema(client: TestClient) -> None:
    schemas = client.get(f"{API}/openapi.json").json()["components"]["schemas"]
    field = schemas["ModelPublic"]["properties"]["posterior"]
    assert "How the GP was conditioned" in field["description"]
    assert {"$ref": "#/components/schemas/ModelPosterior"} in field["anyOf"]
    posterior = schemas["ModelPosterior"]
    assert posterior["required"] == ["structure"]
    assert posterior["properties"]["structure"]["enum"] == ["dense", "kronecker", "sparse"]
    for name in ("structure", "n_inducing", "inducing_touches"):
        assert posterior["properties"][name]["description"]
    assert "inducing points" in " ".join(posterior["description"].split())
