"""The model document keeps the latent covariance and the tempering exponent, and refuses bad ones
naming the field."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from app.documents.errors import DocumentError
from app.documents.model import model_from_document, model_to_document
from core.reference_model import experiment1_at_true_latents


def test_latent_covariance_and_tempering_round_trip() -> None:
    model = experiment1_at_true_latents(seed=0, touches_per_object=6)
    covariance = np.array([[[0.01]], [[0.02]], [[0.03]], [[0.04]]])
    richer = dataclasses.replace(model, latent_covariance=covariance, tempering=0.6)
    document = json.loads(json.dumps(model_to_document(richer)))
    loaded = model_from_document(document)
    np.testing.assert_array_equal(loaded.latent_covariance, covariance)
    assert loaded.tempering == 0.6
    # A document without the fields: latents taken as known, no tempering.
    plain = model_from_document(model_to_document(model))
    assert plain.latent_covariance is None
    assert plain.tempering is None


@pytest.mark.parametrize(
    ("field", "value", "fragment"),
    [
        (
            "latent_uncertainty",
            {"covariance": [[[0.01]], [[-0.02]], [[0.03]], [[0.04]]]},
            "object 1",
        ),
        ("latent_uncertainty", {"covariance": [[0.01]]}, "latent_covariance"),
        ("latent_uncertainty", {}, "missing field 'covariance'"),
        ("tempering", {"exponent": 1.5}, "tempering"),
        ("tempering", {"exponent": "high"}, "tempering"),
    ],
)
def test_bad_fields_are_refused(field: str, value: object, fragment: str) -> None:
    model = experiment1_at_true_latents(seed=0, touches_per_object=6)
    document = json.loads(json.dumps(model_to_document(model)))
    document[field] = value
    with pytest.raises(DocumentError, match=fragment):
        model_from_document(document)
