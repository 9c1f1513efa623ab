"""``activetouch evaluate``: the report on stdout, the files, and bad input exiting with 2."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from app.cli.evaluate import calibration_cells, sampling_noise_line
from app.cli.main import app
from core.evaluation.worlds import random_experiment2_world, sample_dataset
from tests.app.conftest import experiment1_csv, experiment1_document
from tests.app.test_cli_lazy import probe

runner = CliRunner()


@pytest.fixture(scope="module")
def model_path(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("evaluate") / "exp1.json"
    path.write_text(json.dumps(experiment1_document()))
    return path


def evaluate(model_path: Path, *args: str):
    return runner.invoke(app, ["evaluate", "--model", str(model_path), *args])


def test_json_prints_only_the_report_and_files_are_written(model_path, tmp_path):
    out, plot = tmp_path / "report.json", tmp_path / "curves.png"
    result = evaluate(
        model_path,
        *("--world", "exp1", "--trials", "2", "--steps", "3", "--targets", "O1,O4"),
        *("--json", "--out", str(out), "--plot", str(plot)),
    )
    assert result.exit_code == 0, result.output
    document = json.loads(result.stdout)
    assert document["format"] == "activetouch-evaluation/2"
    assert document["steps"] == 3
    assert document["trials_per_target"] == 2
    assert len(document["trials"]) == 2 * 2 * 2
    assert set(document["policies"]["passive"]["per_object"]) == {"O1", "O4"}
    assert json.loads(out.read_text()) == document
    assert plot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["curves.png", "report.json"]


def test_the_active_policy_plans_under_the_belief_asked_for(model_path):
    def first_actions(plan_under: str) -> list[list[float]]:
        result = evaluate(
            model_path,
            *("--world", "exp1", "--trials", "1", "--steps", "1", "--policies", "active"),
            *("--plan-under", plan_under, "--json"),
        )
        assert result.exit_code == 0, result.output
        return [trial["actions"][0] for trial in json.loads(result.stdout)["trials"]]

    objects, gaussian = first_actions("objects"), first_actions("gaussian")
    assert objects == first_actions("objects")  # deterministic
    assert objects != gaussian


def test_table_output_names_the_policies(model_path):
    result = evaluate(model_path, "--world", "model", "--trials", "1", "--steps", "2")
    assert result.exit_code == 0, result.output
    assert "active" in result.stdout
    assert "passive" in result.stdout
    assert "median" in result.stdout  # "median touches to p ≥ 0.95", folded in its column
    assert "touches to p" in result.stdout


def test_table_shows_each_policys_ece_and_sure_and_wrong(model_path, tmp_path):
    out = tmp_path / "report.json"
    result = evaluate(
        model_path, *("--world", "model", "--trials", "3", "--steps", "3", "--out", str(out))
    )
    assert result.exit_code == 0, result.output
    assert "ECE" in result.stdout
    assert "sure and wrong" in result.stdout
    assert "of the answers given with p ≥ 0.95, the wrong ones" in result.stdout
    document = json.loads(out.read_text())
    for summary in document["policies"].values():
        ece, _ = calibration_cells(summary)
        assert ece == f"{summary['calibration']['all_touches']['ece']:.3f}"
        assert ece in result.stdout
    assert sampling_noise_line(document) in " ".join(result.stdout.split())
    for name, summary in document["policies"].items():
        null = summary["calibration"]["all_touches"]["ece_if_calibrated"]
        assert f"{name} {null['mean']:.3f}, {null['p95']:.3f}" in sampling_noise_line(document)


def test_calibration_cells_count_the_sure_answers_and_say_when_there_are_none():
    def summary(sure: int, wrong: int, ece: float | None) -> dict[str, object]:
        share = wrong / sure if sure else None
        scored = {
            "ece": ece,
            "sure_and_wrong": {
                "threshold": 0.95,
                "sure": sure,
                "wrong": wrong,
                "share_wrong": share,
            },
        }
        return {"calibration": {"all_touches": scored}}

    assert calibration_cells(summary(120, 3, 0.0312)) == ("0.031", "3 of 120 (2.5 %)")
    assert calibration_cells(summary(0, 0, None)) == ("—", "0 of 0")
    assert calibration_cells({"accuracy_by_touch": [1.0]}) == ("—", "—")  # an /1 summary


def test_replay_from_a_csv_says_t_is_capped(model_path, tmp_path):
    data = tmp_path / "held_out.csv"
    data.write_text(experiment1_csv(seed=4, touches_per_object=3))
    result = evaluate(
        model_path,
        *("--world", "replay", "--data", str(data), "--trials", "1", "--steps", "5", "--json"),
    )
    assert result.exit_code == 0, result.output
    document = json.loads(result.stdout)
    assert document["steps"] == 3
    assert "capped at 3" in document["notes"][0]


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (("--world", "moon"), "'exp1', 'exp2', 'rig', 'model', 'replay'"),
        (("--world", "exp1", "--policies", "active,greedy"), "greedy"),
        (("--world", "exp1", "--targets", "O1,mug"), "mug"),
        (("--world", "exp1", "--trials", "0"), "trials_per_target"),
        (("--world", "replay"), "needs held-out touches"),
        (("--world", "exp1", "--workers", "2", "--scheduler", "tcp://x:1"), "give one"),
        (("--world", "exp1", "--out", "/nonexistent/dir/r.json"), "does not exist"),
        (("--world", "exp1", "--placement", "shelf"), "placement: 'shelf'"),
        (("--world", "exp1", "--placement", "touch"), "only the rig world"),
        (("--world", "exp1", "--plan-under", "mixture"), "plan_under: 'mixture'"),
    ],
)
def test_bad_input_exits_2_naming_it(model_path, args, message):
    result = evaluate(model_path, *args)
    assert result.exit_code == 2
    assert message in " ".join(result.stderr.split())


def test_replay_data_of_another_world_is_named(model_path, tmp_path):
    other = sample_dataset(
        random_experiment2_world(np.random.default_rng(0)), np.random.default_rng(0), 3
    )
    lines = ["object,x_1,x_2,x_3,x_4,x_5,x_6,y_1,y_2,y_3,y_4,y_5"]
    for obj, x, y in zip(other.object_index, other.actions, other.observations, strict=True):
        lines.append(",".join([other.object_names[obj], *(repr(float(v)) for v in (*x, *y))]))
    data = tmp_path / "exp2.csv"
    data.write_text("\n".join(lines) + "\n")
    result = evaluate(model_path, "--world", "replay", "--data", str(data))
    assert result.exit_code == 2
    assert "held-out data has dx=6, dy=5 but the model has dx=1, dy=3" in result.stderr


def test_an_unreachable_scheduler_exits_2_and_writes_nothing(model_path, tmp_path):
    out = tmp_path / "report.json"
    result = evaluate(
        model_path,
        *("--world", "exp1", "--trials", "1", "--scheduler", "tcp://127.0.0.1:9"),
        *("--out", str(out)),
    )
    assert result.exit_code == 2
    assert "cannot reach a Dask scheduler" in " ".join(result.stderr.split())
    assert list(tmp_path.iterdir()) == []


def test_evaluate_help_starts_light():
    loaded = probe([["evaluate", "--help"]])
    assert loaded["after"] == []


def test_table_is_checked_and_only_for_the_rig(model_path):
    unknown = evaluate(model_path, "--world", "rig", "--table", "no_such_table")
    assert unknown.exit_code == 2
    assert "no_such_table" in unknown.output
    assert "default" in unknown.output  # the message lists the tables
    misplaced = evaluate(model_path, "--world", "exp1", "--table", "default")
    assert misplaced.exit_code == 2
    assert "only the rig world has a table" in misplaced.output


def test_stop_at_confidence_stops_trials_and_is_recorded_and_shown(model_path, tmp_path):
    out = tmp_path / "report.json"
    base = ("--world", "exp1", "--trials", "2", "--steps", "6", "--confidence", "0.6")
    stopped = evaluate(model_path, *base, "--stop-at-confidence", "--out", str(out))
    assert stopped.exit_code == 0, stopped.output
    document = json.loads(out.read_text())
    assert document["stop_at_confidence"] is True
    reasons = {trial["stop_reason"] for trial in document["trials"]}
    assert "confident" in reasons  # Experiment 1 reaches p ≥ 0.6 well before touch 6
    assert all(
        trial["touches"] < 6 for trial in document["trials"] if trial["stop_reason"] == "confident"
    )
    assert "Trials stop once the answer reaches p ≥ 0.6" in " ".join(stopped.stdout.split())
    plain = evaluate(model_path, *base, "--json")
    assert plain.exit_code == 0, plain.output
    document = json.loads(plain.stdout)
    assert document["stop_at_confidence"] is False
    assert "confident" not in {trial["stop_reason"] for trial in document["trials"]}
