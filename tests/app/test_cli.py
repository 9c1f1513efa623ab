"""The ``activetouch`` CLI: fit, recognize, dataset and paper, through typer's runner."""

from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from app.cli.main import app
from app.documents.training_csv import write_training_csv
from core.evaluation.worlds import sample_experiment1

runner = CliRunner()


@pytest.fixture(scope="module")
def csv_path(tmp_path_factory):
    path = tmp_path_factory.mktemp("cli") / "exp1.csv"
    path.write_text(write_training_csv(sample_experiment1(np.random.default_rng(0), 40)))
    return path


@pytest.fixture(scope="module")
def model_path(csv_path):
    out = csv_path.with_name("model.json")
    result = runner.invoke(
        app,
        ["fit", str(csv_path), "--latent-dim", "1", "--restarts", "1", "--out", str(out)],
    )
    assert result.exit_code == 0, result.output
    return out


def test_fit_json_prints_only_the_model_document(csv_path):
    result = runner.invoke(
        app, ["fit", str(csv_path), "--latent-dim", "1", "--restarts", "0", "--json"]
    )
    assert result.exit_code == 0, result.output
    document = json.loads(result.stdout)
    assert document["format"] == "activetouch-model/1"
    assert document["latent_dim"] == 1
    assert document["action_dim"] == 1
    assert document["observation_dim"] == 3
    assert [o["name"] for o in document["objects"]] == ["O1", "O2", "O3", "O4"]
    assert len(document["hyperparameters"]) == 3
    assert document["fit_seconds"] > 0
    assert len(document["training_data"]["actions"]) == 160


def test_fit_without_latent_dim_fits_ds_2(csv_path):
    # The documented default (docs/usage.md): ds = 2, as the adaptive design's own fits.
    result = runner.invoke(app, ["fit", str(csv_path), "--restarts", "0", "--json"])
    assert result.exit_code == 0, result.output
    assert json.loads(result.stdout)["latent_dim"] == 2


def test_fit_writes_a_model_that_recognize_uses(model_path):
    result = runner.invoke(
        app,
        [
            "recognize", "--model", str(model_path), "--world", "exp1", "--target", "O3",
            "--policy", "active", "--steps", "6", "--seed", "1", "--json",
        ],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    trial = json.loads(result.stdout)
    assert trial["target"] == "O3"
    assert 1 <= len(trial["steps"]) <= 6
    assert trial["steps"][-1]["done"] is True
    assert set(trial["steps"][0]["probabilities"]) == {"O1", "O2", "O3", "O4"}
    assert trial["answer"] == trial["steps"][-1]["answer"]


def test_recognize_fixed_policy_uses_the_given_action(model_path):
    result = runner.invoke(
        app,
        [
            "recognize", "--model", str(model_path), "--target", "O1", "--policy", "fixed",
            "--action", "0.25", "--steps", "3", "--json",
        ],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    steps = json.loads(result.stdout)["steps"]
    assert all(step["action"] == [0.25] for step in steps)


@pytest.mark.parametrize(
    ("args", "fragment"),
    [
        (["--target", "O9"], "is not an object of the model"),
        (["--target", "O1", "--policy", "fixed"], "dx"),
    ],
)
def test_recognize_bad_input_is_a_clear_error(model_path, args, fragment):
    result = runner.invoke(app, ["recognize", "--model", str(model_path), *args])
    assert result.exit_code == 2
    assert fragment in result.output


def test_fit_rejects_a_bad_csv_naming_the_column(tmp_path):
    path = tmp_path / "bad.csv"
    path.write_text("object,x_1,y_1,colour\na,1,2,3\n")
    result = runner.invoke(app, ["fit", str(path), "--latent-dim", "1"])
    assert result.exit_code == 2
    assert "colour" in result.output


def test_fit_reports_a_missing_file(tmp_path):
    result = runner.invoke(app, ["fit", str(tmp_path / "nope.csv"), "--latent-dim", "1"])
    assert result.exit_code == 2
    assert "cannot read" in result.output


def test_dataset_writes_a_csv_fit_can_read(tmp_path):
    out = tmp_path / "exp2.csv"
    result = runner.invoke(app, ["dataset", "exp2", "--out", str(out), "--touches", "5"])
    assert result.exit_code == 0, result.output
    header = out.read_text().splitlines()[0]
    assert header == "object,x_1,x_2,x_3,x_4,x_5,x_6,y_1,y_2,y_3,y_4,y_5"
    assert len(out.read_text().splitlines()) == 1 + 4 * 5


def test_paper_exp1_small_run_reports_figures():
    result = runner.invoke(
        app, ["paper", "exp1", "--seeds", "1", "--trials", "1", "--steps", "3", "--json"]
    )
    assert result.exit_code == 0, result.output
    figures = json.loads(result.stdout)
    assert figures["paper"]["correlation"] == 0.9995
    assert 0.0 <= figures["median_correlation"] <= 1.0
    assert set(figures["policies"]) == {"active", "passive", "random-latent active"}
    assert len(figures["policies"]["active"]["accuracy_by_touch"]) == 3
    assert figures["policies"]["active"]["trials"] == 4
    # Each policy's calibration over every trial and touch: 4 trials x 3 touches.
    calibration = figures["policies"]["active"]["calibration"]
    assert calibration["all_touches"]["answers"] == 4 * 3
    assert calibration["all_touches"]["sure_and_wrong"]["threshold"] == 0.95
    table = runner.invoke(app, ["paper", "exp1", "--seeds", "1", "--trials", "1", "--steps", "3"])
    assert table.exit_code == 0, table.output
    text = " ".join(table.stdout.split())
    assert "calibration, active" in text
    assert "ECE" in text


def test_fit_with_a_sparse_structure_records_it_in_the_document(csv_path):
    from app.documents.model import model_from_document

    result = runner.invoke(
        app,
        [
            "fit", str(csv_path), "--latent-dim", "1", "--restarts", "0", "--structure", "sparse",
            "--inducing", "12", "--json",
        ],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    document = json.loads(result.stdout)
    assert document["posterior"]["structure"] == "sparse"
    assert document["posterior"]["n_inducing"] == 12
    model = model_from_document(document)
    assert model.posterior.structure == "sparse"
    assert model.posterior.inducing is not None
    assert (
        model.posterior.inducing.touch_index.tolist() == document["posterior"]["inducing_touches"]
    )


def test_fit_with_tied_kernels_records_them_and_the_document_round_trips(csv_path):
    from app.documents.model import model_from_document, model_to_document

    result = runner.invoke(
        app,
        ["fit", str(csv_path), "--latent-dim", "1", "--restarts", "0", "--kernels", "tied",
         "--json"],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    document = json.loads(result.stdout)
    assert document["diagnostics"]["kernels"] == "tied"
    rows = {(tuple(h["latent_lengthscales"]), tuple(h["action_lengthscales"]))
            for h in document["hyperparameters"]}  # fmt: skip
    assert len(rows) == 1  # every feature's length-scales are the shared ones
    model = model_from_document(document)
    assert model.diagnostics is not None
    assert model.diagnostics.kernels == "tied"
    assert model_to_document(model)["diagnostics"] == document["diagnostics"]
    older = {**document, "diagnostics": {k: v for k, v in document["diagnostics"].items()
                                         if k != "kernels"}}  # fmt: skip
    assert model_from_document(older).diagnostics.kernels == "per_feature"  # type: ignore[union-attr]


@pytest.mark.parametrize(
    ("args", "fragment"),
    [
        (["--kernels", "shared"], "--kernels"),
        (["--kernels", "tied", "--structure", "kronecker"], "kernels: 'tied'"),
    ],
)
def test_fit_refuses_kernels_it_cannot_use(csv_path, args, fragment):
    result = runner.invoke(app, ["fit", str(csv_path), "--latent-dim", "1", *args])
    assert result.exit_code == 2
    assert fragment in result.output


def test_results_without_json_go_to_stdout_and_lines_are_not_folded(csv_path, model_path):
    fitted = runner.invoke(app, ["fit", str(csv_path), "--latent-dim", "1", "--restarts", "0"])
    assert fitted.exit_code == 0, fitted.output
    assert "fitted 4 objects" in fitted.stdout
    assert "fitted" not in fitted.stderr
    result = runner.invoke(
        app,
        [
            "recognize", "--model", str(model_path), "--world", "exp1", "--target", "O2",
            "--policy", "active", "--steps", "3", "--seed", "2",
        ],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    lines = result.stdout.splitlines()
    steps = [line for line in lines if line.startswith("step ")]
    assert 1 <= len(steps) <= 3
    assert all("answer" in line for line in steps)
    assert lines[-1].startswith("recognised ")
    # The last step says why the trial stopped; no line is folded at the runner's 80 columns.
    assert steps[-1].endswith(")")
    assert "(stopped: " in steps[-1]
    assert len(lines) == len(steps) + 1
    assert "step" not in result.stderr


def test_messages_show_bracketed_names_verbatim(tmp_path, csv_path):
    # Rich reads "[...]" as markup: a path or an object name with brackets must be escaped,
    # neither swallowed ("[final]") nor crashing the error printer ("[/b]").
    missing = tmp_path / "run[final]" / "[/b].csv"
    result = runner.invoke(app, ["fit", str(missing), "--latent-dim", "1"])
    assert result.exit_code == 2
    assert str(missing) in result.stderr
    renamed = tmp_path / "renamed.csv"
    renamed.write_text(csv_path.read_text().replace("O3,", "cup[red],"))
    fitted = runner.invoke(app, ["fit", str(renamed), "--latent-dim", "1", "--restarts", "0"])
    assert fitted.exit_code == 0, fitted.output
    assert "cup[red]  s = " in fitted.stdout


def test_the_cli_names_the_policies_and_worlds_of_the_registries() -> None:
    """The command line lists them itself (``--help`` loads no numerics); they must agree."""
    from app.cli.main import Policy, WorldName
    from core.evaluation.worlds import WORLD_NAMES
    from core.recognition.planning import POLICY_NAMES

    assert tuple(p.value for p in Policy) == POLICY_NAMES
    assert tuple(w.value for w in WorldName) == WORLD_NAMES
