"""The model document keeps the latent covariance, the tempering exponent, the input shift and
each object's placement variance, and refuses bad ones naming the field."""

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

runner = CliRunner()


def test_latent_covariance_and_tempering_round_trip() -> None:
    model = experiment1_at_true_latents(seed=0, touches_per_object=6)
    covariance = np.array([[[0.01]], [[0.02]], [[0.03]], [[0.04]]])
    richer = dataclasses.replace(
        model,
        latent_covariance=covariance,
        tempering=0.6,
        shift_variance=np.array([0.04]),
        shift_creep_variance=np.array([0.01]),
    )
    document = json.loads(json.dumps(model_to_document(richer)))
    loaded = model_from_document(document)
    np.testing.assert_array_equal(loaded.latent_covariance, covariance)
    assert loaded.tempering == 0.6
    np.testing.assert_array_equal(loaded.shift_variance, [0.04])
    np.testing.assert_array_equal(loaded.shift_creep_variance, [0.01])
    # A shift without creep (as documents written before the creep have it).
    del document["input_shift"]["creep"]
    older = model_from_document(document)
    np.testing.assert_array_equal(older.shift_variance, [0.04])
    assert older.shift_creep_variance is None
    # A document without the fields: latents taken as known, no tempering, no shift.
    plain = model_from_document(model_to_document(model))
    assert plain.latent_covariance is None
    assert plain.tempering is None
    assert plain.shift_variance is None


def test_each_objects_placement_variance_round_trips_and_bad_rows_are_refused() -> None:
    model = experiment1_at_true_latents(seed=0, touches_per_object=6)
    noise = model.hyperparameters.noise_variance
    pooled = 0.3 * noise
    rows = np.outer([0.1, 0.2, 0.5, 0.8], noise)
    placed = dataclasses.replace(model, placement_variance=pooled, object_placement_variance=rows)
    document = json.loads(json.dumps(model_to_document(placed)))
    assert np.array(document["placement_effect"]["by_object"]).shape == (4, 3)
    loaded = model_from_document(document)
    np.testing.assert_array_equal(loaded.object_placement_variance, rows)
    np.testing.assert_array_equal(loaded.placement_variance, pooled)
    # Documents written before it have the pooled value only.
    del document["placement_effect"]["by_object"]
    assert model_from_document(document).object_placement_variance is None
    for bad, fragment in (
        ((rows * -1).tolist(), "σ_b,l,a²"),
        (np.tile(noise, (4, 1)).tolist(), "σ_b,l,a²"),
        (rows[:3].tolist(), "object_placement_variance"),
        ("large", "object_placement_variance: could not be read"),
    ):
        document["placement_effect"]["by_object"] = bad
        with pytest.raises(DocumentError, match=fragment) as caught:
            model_from_document(document)
        assert caught.value.column == "placement_effect"


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
        ("input_shift", {"variance": [-0.1]}, "shift_variance"),
        ("input_shift", {"variance": [0.1, 0.2]}, "shift_variance"),
        ("input_shift", {"variance": [0.1], "creep": [-0.1]}, "shift_creep_variance"),
        ("input_shift", {"variance": [0.1], "creep": "slow"}, "shift_creep_variance"),
    ],
)
def test_bad_fields_are_refused(field: str, value: object, fragment: str) -> None:
    model = experiment1_at_true_latents(seed=0, touches_per_object=6)
    document = json.loads(json.dumps(model_to_document(model)))
    document[field] = value
    with pytest.raises(DocumentError, match=fragment):
        model_from_document(document)


def test_fit_computes_the_latent_uncertainty_by_default_and_tempering_when_asked(
    tmp_path: Path,
) -> None:
    data = experiment1_at_true_latents(seed=1, touches_per_object=10).data
    csv_path = tmp_path / "train.csv"
    csv_path.write_text(write_training_csv(data))
    common = ["fit", str(csv_path), "--latent-dim", "1", "--restarts", "0"]
    common += ["--noise-model", "independent"]
    plain, default, rich = (tmp_path / f"{name}.json" for name in ("plain", "default", "rich"))
    result = runner.invoke(app, [*common, "--placement-pooling", "mode"])
    assert result.exit_code == 2
    assert "--placement-pooling" in result.output
    result = runner.invoke(app, [*common, "--shift-along", "depth"])
    assert result.exit_code == 2
    assert "--shift-along" in result.output
    result = runner.invoke(app, [*common, "--no-latent-uncertainty", "--out", str(plain)])
    assert result.exit_code == 0, result.output
    document = json.loads(plain.read_text())
    assert "latent_uncertainty" not in document
    assert "tempering" not in document
    result = runner.invoke(app, [*common, "--out", str(default)])
    assert result.exit_code == 0, result.output
    assert "latent uncertainty (Laplace)" in result.output
    document = json.loads(default.read_text())
    assert "tempering" not in document
    assert model_from_document(document).latent_covariance is not None
    # The input shift needs touches that share a placement; these record none.
    assert "input_shift" not in document
    assert "input shift" not in result.output
    options = ["--tempering", "--out", str(rich)]
    result = runner.invoke(app, [*common, *options])
    assert result.exit_code == 0, result.output
    assert "latent uncertainty (Laplace)" in result.output
    assert "tempering β =" in result.output
    model = model_from_document(json.loads(rich.read_text()))
    assert model.latent_covariance is not None
    assert model.latent_covariance.shape == (4, 1, 1)
    assert model.tempering is not None
    assert 0 < model.tempering <= 1


def test_the_server_keeps_them_through_an_import_and_a_restart(tmp_path: Path) -> None:
    """An imported document's latent covariance and tempering are stored with the model row,
    served by the export, and rebuilt by a new server from the row."""
    from app.main import create_app
    from tests.app.conftest import TestClient, make_settings

    model = experiment1_at_true_latents(seed=0, touches_per_object=6)
    covariance = np.array([[[0.01]], [[0.02]], [[0.03]], [[0.04]]])
    richer = dataclasses.replace(
        model, latent_covariance=covariance, tempering=0.6, shift_variance=np.array([0.04])
    )
    document = json.loads(json.dumps(model_to_document(richer)))
    settings = make_settings(tmp_path)
    with TestClient(create_app(settings)) as client:
        imported = client.post("/api/v1/models/import", json=document)
        assert imported.status_code == 201, imported.text
        model_id = imported.json()["id"]
        exported = client.get(f"/api/v1/models/{model_id}/export").json()
    assert exported["latent_uncertainty"]["covariance"] == covariance.tolist()
    assert exported["tempering"]["exponent"] == 0.6
    with TestClient(create_app(settings)) as client:  # rebuilt from the row
        again = client.get(f"/api/v1/models/{model_id}/export").json()
    rebuilt = model_from_document(again)
    np.testing.assert_array_equal(rebuilt.latent_covariance, covariance)
    assert rebuilt.tempering == 0.6
    np.testing.assert_array_equal(rebuilt.shift_variance, [0.04])


def test_fit_reports_the_creep_from_runs_of_four_and_keeps_it(tmp_path: Path) -> None:
    from tests.core.test_input_shift import experiment1_with_creep

    data = experiment1_with_creep(0, reverse_rows=False).data
    csv_path, out = tmp_path / "runs.csv", tmp_path / "model.json"
    csv_path.write_text(write_training_csv(data))
    result = runner.invoke(
        app,
        ["fit", str(csv_path), "--latent-dim", "1", "--restarts", "0", "--noise-model",
         "independent", "--out", str(out)],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    said = " ".join(result.output.split())
    assert "its creep from 160 placements of three touches or more: σ_c = [" in said
    shift = json.loads(out.read_text())["input_shift"]
    assert shift["creep"][0] > 0.0
    model = model_from_document(json.loads(out.read_text()))
    assert model.shift_creep_variance is not None
