"""``activetouch fit`` with ``--noise-model`` and ``--latent-dim auto``."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from app.cli.main import app
from app.documents.model import model_from_document
from app.documents.training_csv import write_training_csv
from core.evaluation.worlds import correlated_noise_world, sample_dataset, sample_experiment1
from core.types import TrainingData

runner = CliRunner()


@pytest.fixture(scope="module")
def small_csv(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("cli-noise") / "exp1.csv"
    path.write_text(write_training_csv(sample_experiment1(np.random.default_rng(0), 8)))
    return path


def test_latent_dim_auto_reports_the_candidates(small_csv: Path) -> None:
    result = runner.invoke(
        app,
        ["fit", str(small_csv), "--latent-dim", "auto", "--restarts", "0",
         "--noise-model", "independent"],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    assert "ds=1" in result.stdout
    assert "ds=3" in result.stdout  # L = 4: candidates 1..3
    assert "<- chosen" in result.stdout
    assert "noise model: independent (as asked)" in result.stdout


def test_latent_dim_auto_json_carries_the_selection(small_csv: Path) -> None:
    result = runner.invoke(
        app,
        ["fit", str(small_csv), "--latent-dim", "auto", "--restarts", "0",
         "--noise-model", "independent", "--json"],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    document = json.loads(result.stdout)
    selection = document["latent_selection"]
    assert document["latent_dim"] == selection["chosen"]
    assert [c["latent_dim"] for c in selection["candidates"]] == [1, 2, 3]
    assert document["noise_model"]["kind"] == "independent"


def test_bad_latent_dim_is_rejected(small_csv: Path) -> None:
    result = runner.invoke(app, ["fit", str(small_csv), "--latent-dim", "two"])
    assert result.exit_code == 2
    assert "'auto'" in result.output


def test_correlated_noise_model_on_scaled_correlated_channels(tmp_path: Path) -> None:
    world = correlated_noise_world(np.random.default_rng(1), n_objects=4)
    path = tmp_path / "tactile.csv"
    path.write_text(write_training_csv(sample_dataset(world, np.random.default_rng(2), 15)))
    result = runner.invoke(
        app,
        ["fit", str(path), "--latent-dim", "2", "--restarts", "0", "--noise-model", "correlated",
         "--json"],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    document = json.loads(result.stdout)
    assert document["noise_model"]["kind"] == "correlated"
    assert max(abs(document["noise_model"]["correlation"][0][1]), 0.0) > 0.5  # true 0.8
    assert model_from_document(document).transform is not None


def test_constant_channel_is_named(tmp_path: Path) -> None:
    data = sample_experiment1(np.random.default_rng(3), 6)
    y = data.observations.copy()
    y[:, 2] = 1.25
    constant = TrainingData(data.object_names, data.object_index, data.actions, y)
    path = tmp_path / "constant.csv"
    path.write_text(write_training_csv(constant))
    result = runner.invoke(app, ["fit", str(path), "--latent-dim", "1"])
    assert result.exit_code == 2
    assert "y_3" in result.output
    assert "constant" in result.output
