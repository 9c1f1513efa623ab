"""The model document keeps the drift effect (σ_d²) and the training touches' times."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from app.documents.errors import DocumentError
from app.documents.model import model_from_document, model_to_document
from core.evaluation.reference_model import experiment1_at_true_latents


def test_model_document_keeps_the_drift_effect_and_the_times() -> None:
    model = experiment1_at_true_latents(seed=0, touches_per_object=6)
    noise = model.hyperparameters.noise_variance
    times = 12.5 * np.arange(model.data.n_touches)
    timed = dataclasses.replace(
        model,
        data=dataclasses.replace(model.data, touch_times_s=times),
        placement_variance=0.3 * noise,
        drift_variance=0.4 * noise,
    )
    document = json.loads(json.dumps(model_to_document(timed)))
    assert document["training_data"]["times_s"] == times.tolist()
    loaded = model_from_document(document)
    np.testing.assert_array_equal(loaded.drift_variance, 0.4 * noise)
    np.testing.assert_array_equal(loaded.raw_data.touch_times_s, times)
    # An older document (neither field) means no drift effect and no times.
    older = model_from_document(model_to_document(model))
    assert older.drift_variance is None
    assert older.raw_data.touch_times_s is None
    # σ_b² + σ_d² must leave each touch a noise of its own.
    document["drift_effect"]["variance"] = (0.7 * noise).tolist()
    with pytest.raises(DocumentError, match="drift_variance") as refused:
        model_from_document(document)
    assert refused.value.column == "drift_effect"
    document["drift_effect"]["variance"] = 0.1 * noise[0]
    with pytest.raises(DocumentError, match="drift"):
        model_from_document(document)
    document["drift_effect"]["variance"] = (0.1 * noise).tolist()
    document["training_data"]["times_s"] = ["soon"] * model.data.n_touches
    with pytest.raises(DocumentError, match="times_s"):
        model_from_document(document)
