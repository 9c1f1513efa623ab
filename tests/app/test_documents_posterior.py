"""The model document records how the GP was conditioned, and reloads it exactly.

Dense, Kronecker and sparse models reload with the same posterior structure (and, for a sparse
one, the same inducing points), so their predictions equal the original's to 1e-10. Documents
written before the ``posterior`` field existed still load as before.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from app.documents.errors import DocumentError
from app.documents.model import model_from_document, model_to_document
from core.gp.posterior import condition, predict
from core.gp.sparse import condition_sparse, select_inducing_points
from core.types import InducingPoints, ManifoldModel, TrainingData
from tests.app import posterior_cases as cases
from tests.app.posterior_cases import HYPER, LATENTS, QUERY_S, QUERY_X, TOLERANCE


@pytest.fixture(scope="module", name="random_data")
def random_data_fixture() -> TrainingData:
    return cases.random_data()


@pytest.fixture(scope="module", name="shared_data")
def shared_data_fixture() -> TrainingData:
    return cases.shared_data()


def reload(model: ManifoldModel) -> ManifoldModel:
    """Through JSON text, as a file would."""
    return model_from_document(json.loads(json.dumps(model_to_document(model))))


def assert_same_predictions(a: ManifoldModel, b: ManifoldModel) -> None:
    for left, right in zip(predict(a, QUERY_S, QUERY_X), predict(b, QUERY_S, QUERY_X), strict=True):
        np.testing.assert_allclose(left, right, rtol=0.0, atol=TOLERANCE)


@pytest.mark.parametrize(
    ("which", "structure", "n_inducing"),
    [
        ("random", "dense", None),
        # Dense on a shared design, where condition()'s default would choose Kronecker.
        ("shared", "dense", None),
        ("shared", "kronecker", None),
        ("random", "sparse", 9),  # m < N: the inducing points are a selection
    ],
)
def test_reloaded_model_has_the_same_posterior_and_predictions(
    request: pytest.FixtureRequest, which: str, structure: str, n_inducing: int | None
) -> None:
    data = request.getfixturevalue(f"{which}_data")
    kwargs = {} if n_inducing is None else {"n_inducing": n_inducing}
    model = condition(data, LATENTS, HYPER, structure=structure, **kwargs)  # type: ignore[arg-type]
    assert model.posterior.structure == structure
    document = model_to_document(model)
    assert document["posterior"]["structure"] == structure
    again = reload(model)
    assert again.posterior.structure == structure
    assert again.log_likelihood == pytest.approx(model.log_likelihood, rel=1e-12)
    assert_same_predictions(model, again)
    if structure == "sparse":
        assert document["posterior"]["n_inducing"] == n_inducing
        assert again.posterior.inducing is not None
        assert model.posterior.inducing is not None
        np.testing.assert_array_equal(
            again.posterior.inducing.touch_index, model.posterior.inducing.touch_index
        )


def test_sparse_model_with_its_own_inducing_points_reloads_them(random_data: TrainingData) -> None:
    """Inducing points that the default selection would not pick are stored, not re-selected."""
    chosen = np.array([0, 5, 16, 17, 30, 44, 59], dtype=np.int64)
    inducing = InducingPoints(
        object_index=random_data.object_index[chosen],
        actions=random_data.actions[chosen],
        touch_index=chosen,
    )
    model = condition_sparse(random_data, LATENTS, HYPER, inducing=inducing)
    default = select_inducing_points(random_data, chosen.shape[0])
    assert not np.array_equal(default.touch_index, chosen)
    document = json.loads(json.dumps(model_to_document(model)))
    assert document["posterior"]["inducing_touches"] == chosen.tolist()
    again = model_from_document(document)
    assert_same_predictions(model, again)
    # Without the stored indices, the same m re-selects other points: the predictions move.
    del document["posterior"]["inducing_touches"]
    reselected = model_from_document(document)
    assert reselected.posterior.structure == "sparse"
    mean_a, _ = predict(model, QUERY_S, QUERY_X)
    mean_b, _ = predict(reselected, QUERY_S, QUERY_X)
    assert np.max(np.abs(mean_a - mean_b)) > 1e-6


def test_a_document_without_the_posterior_field_loads_as_before(
    random_data: TrainingData, shared_data: TrainingData
) -> None:
    """Old documents: the posterior is chosen as condition() does by default (auto)."""
    for data, expected in ((random_data, "dense"), (shared_data, "kronecker")):
        document = json.loads(json.dumps(model_to_document(condition(data, LATENTS, HYPER))))
        del document["posterior"]
        again = model_from_document(document)
        assert again.posterior.structure == expected
        assert_same_predictions(condition(data, LATENTS, HYPER), again)
    # A sparse model saved without the field comes back dense (N = 60 is small): that was the
    # defect; with the field it comes back sparse (above).
    sparse = condition(random_data, LATENTS, HYPER, structure="sparse", n_inducing=9)
    document = json.loads(json.dumps(model_to_document(sparse)))
    del document["posterior"]
    assert model_from_document(document).posterior.structure == "dense"


@pytest.mark.parametrize(
    ("posterior", "fragment", "column"),
    [
        ([], "'posterior' must be an object", "posterior"),
        ({"structure": "diagonal"}, "posterior.structure must be one of", "posterior.structure"),
        ({"structure": "sparse"}, "needs 'inducing_touches' or an integer", "posterior.n_inducing"),
        ({"structure": "sparse", "n_inducing": 0}, "n_inducing", "posterior.n_inducing"),
        (
            {"structure": "sparse", "inducing_touches": [0, 1, 60]},
            "[60] outside 0..59",
            "posterior.inducing_touches",
        ),
        (
            {"structure": "sparse", "inducing_touches": [0, 1, 1]},
            "repeats a touch",
            "posterior.inducing_touches",
        ),
        (
            {"structure": "sparse", "inducing_touches": [0, 1.5]},
            "list of touch indices",
            "posterior.inducing_touches",
        ),
        (
            {"structure": "sparse", "n_inducing": 3, "inducing_touches": [0, 1]},
            "lists 2 touches",
            "posterior.n_inducing",
        ),
    ],
)
def test_a_malformed_posterior_field_names_itself(
    random_data: TrainingData, posterior: object, fragment: str, column: str
) -> None:
    document = model_to_document(condition(random_data, LATENTS, HYPER))
    document["posterior"] = posterior
    with pytest.raises(
        DocumentError, match=fragment.replace("[", r"\[").replace("]", r"\]")
    ) as info:
        model_from_document(document)
    assert info.value.column == column


def test_kronecker_on_data_without_a_shared_design_is_a_document_error(
    random_data: TrainingData,
) -> None:
    document = model_to_document(condition(random_data, LATENTS, HYPER))
    document["posterior"] = {"structure": "kronecker"}
    with pytest.raises(DocumentError, match="model document: "):
        model_from_document(document)
