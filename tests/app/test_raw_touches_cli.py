"""``fit`` and ``evaluate --world replay`` on raw-touch files."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from typer.testing import CliRunner

from app.cli.main import app
from tests.app.test_raw_touches import raw_file, touch_line

runner = CliRunner()
FAST = ("--latent-dim", "2", "--restarts", "0", "--noise-model", "independent")


def test_fit_on_raw_touches_keeps_the_pipeline_and_replay_applies_it(tmp_path: Path) -> None:
    train, held_out, model = tmp_path / "train.jsonl", tmp_path / "held.jsonl", tmp_path / "m.json"
    text = raw_file(12).splitlines()
    train.write_text("\n".join(text[:27]) + "\n")
    held_out.write_text("\n".join(text[27:]) + "\n")
    result = runner.invoke(
        app, ["fit", str(train), *FAST, "--features", "whole", "--out", str(model)]
    )
    assert result.exit_code == 0, result.output
    assert "features: whole touch" in result.stdout
    document = json.loads(model.read_text())
    assert document["features"]["kind"] == "whole"
    assert document["observation_dim"] == document["features"]["selection"]["chosen"]
    result = runner.invoke(
        app,
        [
            *("evaluate", "--model", str(model), "--world", "replay", "--data", str(held_out)),
            *("--trials", "1", "--steps", "1", "--policies", "passive", "--json"),
        ],
    )
    assert result.exit_code == 0, result.output
    report = json.loads(result.stdout)
    assert report["policies"]["passive"]["accuracy_by_touch"] == [1.0]


def test_fit_with_channel_means_and_bad_raw_input_exits_2(tmp_path: Path) -> None:
    train, model = tmp_path / "train.jsonl", tmp_path / "m.json"
    train.write_text(raw_file(6))
    result = runner.invoke(
        app, ["fit", str(train), *FAST, "--features", "means", "--out", str(model)]
    )
    assert result.exit_code == 0, result.output
    document = json.loads(model.read_text())
    assert document["features"]["output_names"] == [
        "pressure_kpa", "electrode[0]", "electrode[1]", "electrode[2]", "vibration"
    ]  # fmt: skip
    short = tmp_path / "short.jsonl"
    short.write_text(raw_file(3) + touch_line(np.random.default_rng(1), "fine", 200.0, 50) + "\n")
    result = runner.invoke(app, ["fit", str(short), *FAST])
    assert result.exit_code == 2
    assert "line 10" in result.output
    assert "'vibration': 50 samples" in result.output
    csv = tmp_path / "data.csv"
    csv.write_text("object,x_1,y_1\na,0,1\na,1,2\nb,0,3\nb,1,4\n")
    result = runner.invoke(app, ["fit", str(csv), *FAST, "--features", "whole"])
    assert result.exit_code == 2
    assert "need a raw-touch file" in result.output
