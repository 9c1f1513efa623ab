"""The model document keeps the drift effect (σ_d²) and the training touches' times."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from app.cli.main import app
from app.documents.errors import DocumentError
from app.documents.model import model_from_document, model_to_document
from app.documents.training_csv import write_training_csv
from core.evaluation.reference_model import experiment1_at_true_latents
from tests.core.test_drift_effect import drifting_model

runner = CliRunner()


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


def test_fit_estimates_the_drift_effect_into_the_document(tmp_path: Path) -> None:
    """`fit` on a CSV whose touches record their times splits the drift off each touch's noise;
    without the column it has no drift effect."""
    data = drifting_model(0.1, 1).data
    timed, untimed = tmp_path / "timed.csv", tmp_path / "untimed.csv"
    timed.write_text(write_training_csv(data))
    untimed.write_text(write_training_csv(dataclasses.replace(data, touch_times_s=None)))
    options = ["--latent-dim", "1", "--restarts", "0", "--noise-model", "independent"]
    out = tmp_path / "model.json"
    result = runner.invoke(app, ["fit", str(timed), *options, "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert "drift effect from" in " ".join(result.output.split())
    document = json.loads(out.read_text())
    variance = np.asarray(document["drift_effect"]["variance"])
    assert variance.shape == (3,)
    assert np.all(variance > 0)
    assert document["training_data"]["times_s"] == data.touch_times_s.tolist()
    np.testing.assert_array_equal(model_from_document(document).drift_variance, variance)
    result = runner.invoke(app, ["fit", str(untimed), *options, "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert "drift effect" not in result.output
    assert "drift_effect" not in json.loads(out.read_text())
