"""Collections that record placements: ``collect --placements``, the CSV column, the document."""

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
from app.documents.training_csv import read_training_csv, write_training_csv
from app.errors import BadInputError
from app.services import collections
from app.services.collections import (
    default_placements,
    placement_runs,
    stage_placements,
    stage_sizes,
)
from core.evaluation.reference_model import experiment1_at_true_latents
from core.gp.posterior import condition
from core.types import TrainingData
from tests.app.test_placements_api import placed_data

runner = CliRunner()
pytestmark = pytest.mark.usefixtures("cli_rig_rest")  # 5 s before each touch, not 20 s
OBJECTS = ["--object", "paper_cup", "--object", "stainless_cup"]


def test_collect_with_placements_touches_each_placement_in_a_row(tmp_path: Path) -> None:
    out = tmp_path / "placed.csv"
    result = runner.invoke(
        app,
        [
            "collect",
            "--sim",
            "--duration",
            "5",
            *OBJECTS,
            "--touches",
            "4",
            "--design",
            "random",
            "--placements",
            "2",
            "--seed",
            "3",
            "--out",
            str(out),
            "--json",
        ],
    )
    assert result.exit_code == 0, result.output
    assert json.loads(result.stdout)["placements"] == 2
    assert out.read_text().splitlines()[0].startswith("object,placement,time_s,duration_s,x_1")
    data = read_training_csv(out.read_text())
    assert data.placement_index is not None
    # Placement by placement in rounds over the objects, two touches in a row at each.
    np.testing.assert_array_equal(data.object_index, [0, 0, 1, 1, 0, 0, 1, 1])
    np.testing.assert_array_equal(data.placement_index, [0, 0, 0, 0, 1, 1, 1, 1])


def test_the_default_collection_has_three_placements_for_every_four_touches_and_records_them(
    tmp_path: Path,
) -> None:
    out = tmp_path / "adaptive.csv"
    result = runner.invoke(
        app,
        ["collect", "--sim", "--duration", "5", *OBJECTS, "--touches", "8", "--seed", "1",
         "--out", str(out), "--json"],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    summary = json.loads(result.stdout)
    # Adaptive: 4 random touches, then rounds of 2 and 2; 8 - 8 // 4 = 6 placements, split
    # 3, 2, 1 over the stages (a pair and two singles, two singles, a pair), numbered on
    # through the stages.
    assert summary["design"] == "adaptive"
    assert summary["placements"] == 6
    data = read_training_csv(out.read_text())
    assert data.placement_index is not None
    for obj in range(2):
        placement = data.placement_index[data.object_index == obj]
        np.testing.assert_array_equal(placement, [0, 0, 1, 2, 3, 4, 5, 5])
    # The table turns between placements only: a pair's touches follow each other.
    np.testing.assert_array_equal(
        data.object_index, [0, 0, 1, 1, 0, 1, 0, 1, 0, 1, 0, 1, 0, 0, 1, 1]
    )


def test_runs_of_placements_in_every_stage_of_the_adaptive_design(tmp_path: Path) -> None:
    out = tmp_path / "runs.csv"
    result = runner.invoke(
        app,
        ["collect", "--sim", "--duration", "5", *OBJECTS, "--touches", "6", "--placements",
         "3", "--seed", "1", "--out", str(out), "--json"],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    data = read_training_csv(out.read_text())
    assert data.placement_index is not None
    for obj in range(2):
        placement = data.placement_index[data.object_index == obj]
        np.testing.assert_array_equal(placement, [0, 0, 0, 1, 1, 2])
    # A placement's touches follow each other: the table turns only between placements.
    runs = [(o, p) for o, p in zip(data.object_index, data.placement_index, strict=True)]
    changes = [k for k in range(1, len(runs)) if runs[k] != runs[k - 1]]
    assert len(changes) == 2 * 3 - 1


def test_placements_are_split_over_the_stages() -> None:
    assert stage_sizes("adaptive", 100) == [50, 25, 25]
    assert stage_sizes("random", 100) == [100]
    assert default_placements([50, 25, 25]) == 75  # three placements for every four touches
    assert default_placements([4, 2, 2]) == 6
    assert default_placements([3]) == 2  # at least one pair
    assert default_placements([2]) == 1
    assert default_placements([1]) == 1
    assert default_placements([1, 1, 1]) == 3  # at least one per stage
    assert stage_placements(20, [50, 25, 25]) == [10, 5, 5]
    assert stage_placements(3, [50, 25, 25]) == [1, 1, 1]
    assert stage_placements(100, [50, 25, 25]) == [50, 25, 25]
    for placements in range(3, 101):
        split = stage_placements(placements, [50, 30, 20])
        assert sum(split) == placements
        assert all(1 <= k <= n for k, n in zip(split, [50, 30, 20], strict=True))
    with pytest.raises(BadInputError, match=r"3\.\.100.*3 stages"):
        stage_placements(2, [50, 25, 25])
    with pytest.raises(BadInputError, match=r"1\.\.4"):
        stage_placements(5, [4])


def test_more_placements_than_touches_is_bad_usage(tmp_path: Path) -> None:
    out = tmp_path / "x.csv"
    result = runner.invoke(
        app,
        ["collect", "--sim", *OBJECTS, "--touches", "3", "--placements", "4", "--out", str(out)],
    )
    assert result.exit_code == 2
    assert "--placements" in " ".join(result.output.split())
    assert not out.exists()


def test_csv_placement_column_round_trips_and_is_checked() -> None:
    model = experiment1_at_true_latents(seed=0, touches_per_object=4)
    base = model.data
    placed = dataclasses.replace(base, placement_index=np.arange(base.n_touches) % 2)
    text = write_training_csv(placed)
    back = read_training_csv(text)
    np.testing.assert_array_equal(back.placement_index, placed.placement_index)
    assert read_training_csv(write_training_csv(base)).placement_index is None
    broken = text.replace("\nO1,0,", "\nO1,-1,", 1)
    with pytest.raises(DocumentError, match="placement"):
        read_training_csv(broken)


def test_model_document_keeps_the_placement_effect() -> None:
    model = experiment1_at_true_latents(seed=0, touches_per_object=6)
    data = model.data
    placed_data = TrainingData(
        data.object_names,
        data.object_index,
        data.actions,
        data.observations,
        np.arange(data.n_touches) // 3,
    )
    variance = 0.3 * model.hyperparameters.noise_variance
    placed = dataclasses.replace(model, data=placed_data, placement_variance=variance)
    document = json.loads(json.dumps(model_to_document(placed)))
    loaded = model_from_document(document)
    np.testing.assert_array_equal(loaded.placement_variance, variance)
    np.testing.assert_array_equal(loaded.raw_data.placement_index, placed_data.placement_index)
    # An older document (no field) means no placement effect.
    assert model_from_document(model_to_document(model)).placement_variance is None
    document["placement_effect"]["variance"] = [-1.0, 0.0, 0.0]
    with pytest.raises(DocumentError, match="placement_variance"):
        model_from_document(document)


def test_model_document_rebuilds_a_placement_effect_in_the_training_covariance() -> None:
    model = experiment1_at_true_latents(seed=0, touches_per_object=6)
    data = dataclasses.replace(model.data, placement_index=np.arange(24) // 3)
    variance = 0.3 * model.hyperparameters.noise_variance
    in_fit = condition(data, model.latents, model.hyperparameters, placement_variance=variance)
    document = json.loads(json.dumps(model_to_document(in_fit)))
    assert document["placement_effect"]["in_training_covariance"] is True
    loaded = model_from_document(document)
    assert loaded.placement_in_fit
    np.testing.assert_array_equal(loaded.placement_variance, variance)
    assert loaded.log_likelihood == pytest.approx(in_fit.log_likelihood, rel=1e-12)
    np.testing.assert_allclose(loaded.posterior.beta, in_fit.posterior.beta, rtol=1e-10)
    # σ_b² for scoring only (a document of an earlier fit) leaves the posterior as fitted.
    document["placement_effect"]["in_training_covariance"] = False
    scored = model_from_document(document)
    assert not scored.placement_in_fit
    assert scored.log_likelihood != pytest.approx(in_fit.log_likelihood, rel=1e-6)
    document["placement_effect"]["in_training_covariance"] = "yes"
    with pytest.raises(DocumentError, match="in_training_covariance"):
        model_from_document(document)


def test_fit_estimates_the_placement_effect_into_the_document(tmp_path: Path) -> None:
    data = placed_data(seed=1)
    placement = data.placement_index
    assert placement is not None
    csv_path, out = tmp_path / "placed.csv", tmp_path / "model.json"
    csv_path.write_text(write_training_csv(data))
    result = runner.invoke(
        app,
        [
            "fit",
            str(csv_path),
            "--latent-dim",
            "1",
            "--restarts",
            "0",
            "--noise-model",
            "independent",
            "--out",
            str(out),
        ],
    )
    assert result.exit_code == 0, result.output
    assert "placement effect from 16 placements" in " ".join(result.output.split())
    assert "input shift from 16 placements" in " ".join(result.output.split())
    document = json.loads(out.read_text())
    assert len(document["input_shift"]["variance"]) == 1  # one action dimension
    assert document["training_data"]["placements"] == placement.tolist()
    variance = np.asarray(document["placement_effect"]["variance"])
    assert variance.shape == (3,)
    assert np.any(variance > 0)
    assert document["placement_effect"]["in_training_covariance"] is True
    loaded = model_from_document(document)
    assert loaded.placement_in_fit
    np.testing.assert_array_equal(loaded.placement_variance, variance)


def test_placement_runs_split_unevenly_and_refuse_empty_placements() -> None:
    assert placement_runs(7, 3) == [range(0, 3), range(3, 5), range(5, 7)]
    assert placement_runs(4, 4) == [range(k, k + 1) for k in range(4)]
    # Fewer than two touches per placement: pairs first, then single touches.
    assert [len(r) for r in placement_runs(100, 75)] == [2] * 25 + [1] * 50


def test_placement_runs_of_three_leave_the_rest_single(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(collections, "RUN_LENGTH", 3)
    lengths = [len(r) for r in placement_runs(100, 75)]
    assert lengths == [3] * 12 + [2] + [1] * 62
    assert [len(r) for r in placement_runs(7, 4)] == [3, 2, 1, 1]
    assert [len(r) for r in placement_runs(8, 4)] == [2, 2, 2, 2]  # two per placement: even
    assert [len(r) for r in placement_runs(5, 4)] == [2, 1, 1, 1]
    for n, p in ((100, 75), (8, 4), (5, 4), (9, 5), (3, 2)):
        runs = placement_runs(n, p)
        assert len(runs) == p
        assert [k for r in runs for k in r] == list(range(n))  # every touch once, in order
    with pytest.raises(BadInputError, match="placements"):
        placement_runs(2, 3)
