"""The model document's ``noise_model`` and ``latent_selection`` fields."""

from __future__ import annotations

import json
from typing import Any

import numpy as np
import pytest

from app.documents.errors import DocumentError
from app.documents.model import model_from_document, model_to_document
from core.gp.noise_model import attach_transform, transform_data, whitening_transform
from core.gp.noise_model import standardising_transform as standardise
from core.gp.posterior import condition, predict
from core.recognition.object_posterior import object_log_likelihoods
from core.types import ManifoldModel
from tests.app.posterior_cases import HYPER, LATENTS, QUERY_S, QUERY_X, random_data, shared_data

CORRELATION = np.array([[1.0, 0.7, 0.2], [0.7, 1.0, 0.4], [0.2, 0.4, 1.0]])


def correlated_model(shared: bool = False) -> ManifoldModel:
    data = shared_data() if shared else random_data()
    scaled = type(data)(
        data.object_names,
        data.object_index,
        data.actions,
        data.observations * np.array([100.0, 1.0, 0.05]),
    )
    transform = whitening_transform(standardise(scaled), 0.04 * CORRELATION, "test")
    model = condition(transform_data(scaled, transform), LATENTS, HYPER)
    return attach_transform(model, transform, scaled)


def round_trip(model: ManifoldModel, **kwargs: Any) -> tuple[dict[str, Any], ManifoldModel]:
    document = json.loads(json.dumps(model_to_document(model, **kwargs)))
    return document, model_from_document(document)


@pytest.mark.parametrize("shared", [False, True])
def test_a_correlated_model_round_trips(shared: bool) -> None:
    original = correlated_model(shared)
    document, loaded = round_trip(original)
    assert document["noise_model"]["kind"] == "correlated"
    np.testing.assert_allclose(document["noise_model"]["correlation"], CORRELATION, atol=1e-12)
    # The document keeps the raw observations (what was recorded), not the transformed ones.
    np.testing.assert_array_equal(
        document["training_data"]["observations"], original.raw_data.observations
    )
    assert loaded.transform is not None
    np.testing.assert_array_equal(loaded.transform.matrix, original.observation_transform.matrix)
    assert loaded.log_likelihood == pytest.approx(original.log_likelihood, rel=1e-12)
    for got, want in zip(
        predict(loaded, QUERY_S, QUERY_X), predict(original, QUERY_S, QUERY_X), strict=True
    ):
        np.testing.assert_allclose(got, want, rtol=1e-10, atol=1e-12)
    y = original.raw_data.observations[:4]
    x = original.raw_data.actions[:4]
    np.testing.assert_allclose(
        object_log_likelihoods(loaded, x, y), object_log_likelihoods(original, x, y), rtol=1e-10
    )
    assert model_to_document(loaded) == model_to_document(original)


def test_an_old_document_without_noise_model_loads_as_identity() -> None:
    original = condition(random_data(), LATENTS, HYPER)
    document, loaded = round_trip(original)
    assert "noise_model" not in document
    assert loaded.transform is None
    assert loaded.log_likelihood == original.log_likelihood
    np.testing.assert_array_equal(loaded.data.observations, original.data.observations)


def test_latent_selection_is_written_as_given() -> None:
    selection = {"chosen": 1, "best": 1, "n_folds": 3, "candidates": [], "explanation": "x"}
    document, _ = round_trip(condition(random_data(), LATENTS, HYPER), latent_selection=selection)
    assert document["latent_selection"] == selection


@pytest.mark.parametrize(
    ("change", "column"),
    [
        ({"kind": "sideways"}, "noise_model.kind"),
        ({"scale": [1.0, 2.0]}, "noise_model.scale"),
        ({"offset": [0.0, float("nan"), 1.0]}, "noise_model.offset[1]"),
        ({"whitening": [[1.0, 0, 0], [1.0, 0, 0], [0, 0, 1.0]]}, "noise_model"),
        ({"scale": [1.0, -1.0, 1.0]}, "noise_model"),
    ],
)
def test_malformed_noise_model_says_which_field(change: dict[str, Any], column: str) -> None:
    document = json.loads(json.dumps(model_to_document(correlated_model())))
    document["noise_model"].update(change)
    with pytest.raises(DocumentError) as info:
        model_from_document(document)
    assert info.value.column == column


def test_noise_model_must_be_an_object() -> None:
    document = json.loads(json.dumps(model_to_document(correlated_model())))
    document["noise_model"] = "correlated"
    with pytest.raises(DocumentError, match="'noise_model' must be an object"):
        model_from_document(document)
