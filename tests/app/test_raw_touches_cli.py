"""``fit``, ``evaluate --world replay`` and ``dataset import-raw`` on raw-touch files."""

from __future__ import annotations

import json
import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from typer.testing import CliRunner

from app.cli.main import app
from app.documents.raw_touches import read_raw_touches
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


def said(result: Any) -> str:
    """What the command printed, with rich's line wrapping undone."""
    return " ".join(result.output.split())


def test_import_raw_stores_the_touches_in_the_database_to_be_featurised_again(
    tmp_path: Path,
) -> None:
    db, data = tmp_path / "lab.db", tmp_path / "lab.jsonl"
    data.write_text(raw_file(3))
    result = runner.invoke(
        app, ["dataset", "import-raw", str(data), "--db", str(db), "--name", "lab", "--json"]
    )
    assert result.exit_code == 0, result.output
    stored = json.loads(result.stdout)
    assert (stored["name"], stored["source"], stored["n_samples"]) == ("lab", "import", 9)
    assert stored["objects"] == ["fine", "coarse", "medium"]
    assert stored["observation_dim"] == 5  # the channel means
    back = tmp_path / "back.jsonl"
    result = runner.invoke(
        app, ["export", "dataset", str(stored["id"]), "--raw", "--db", str(db), "--out", str(back)]
    )
    assert result.exit_code == 0, result.output
    again, original = read_raw_touches(back.read_text()), read_raw_touches(data.read_text())
    np.testing.assert_array_equal(again.actions, original.actions)
    for a, b in zip(again.touches, original.touches, strict=True):
        for ca, cb in zip(a.channels, b.channels, strict=True):
            assert (ca.name, ca.rate_hz) == (cb.name, cb.rate_hz)
            np.testing.assert_array_equal(ca.samples, cb.samples)
    # A second import into the same database: a second dataset, named after the file.
    result = runner.invoke(app, ["dataset", "import-raw", str(data), "--db", str(db)])
    assert result.exit_code == 0, result.output
    assert "imported 9 touches of 3 objects" in said(result)
    listing = runner.invoke(app, ["export", "list", "--db", str(db), "--json"])
    assert [d["name"] for d in json.loads(listing.stdout)["datasets"]] == ["lab.jsonl", "lab"]


def _with_line(lines: list[str], k: int, change: Callable[[dict[str, Any]], None]) -> str:
    item = json.loads(lines[k])
    change(item)
    return "\n".join([*lines[:k], json.dumps(item), *lines[k + 1 :]]) + "\n"


def _drop_channel(item: dict[str, Any]) -> None:
    del item["channels"]["electrode"]


def _drop_rate(item: dict[str, Any]) -> None:
    del item["channels"]["pressure_kpa"]["rate_hz"]


def _nan(item: dict[str, Any]) -> None:
    item["channels"]["vibration"]["samples"][17] = float("nan")


def _short(item: dict[str, Any]) -> None:
    item["channels"]["vibration"]["samples"] = item["channels"]["vibration"]["samples"][:200]


@pytest.mark.parametrize(
    ("change", "expected"),
    [
        (_drop_channel, r"line 5: .*channel set differs.*missing \['electrode'\]"),
        (_drop_rate, r"line 5: channel 'pressure_kpa': the sample rate \(rate_hz\) is missing"),
        (_nan, r"line 5: channel 'vibration': a NaN or inf sample at index \[17\]"),
        (_short, r"line 5: channel 'vibration': 200 samples, shorter than the pipeline's window"),
    ],
)
def test_import_raw_refuses_bad_touches_naming_line_and_channel_and_stores_nothing(
    tmp_path: Path, change: Callable[[dict[str, Any]], None], expected: str
) -> None:
    db, data = tmp_path / "lab.db", tmp_path / "bad.jsonl"
    data.write_text(_with_line(raw_file(3).splitlines(), 4, change))
    result = runner.invoke(app, ["dataset", "import-raw", str(data), "--db", str(db)])
    assert result.exit_code == 2, result.output
    assert re.search(expected, said(result)), said(result)
    assert not db.exists()  # refused before the database was opened


def test_import_raw_with_channel_means_takes_short_series(tmp_path: Path) -> None:
    db, data = tmp_path / "lab.db", tmp_path / "short.jsonl"
    data.write_text(_with_line(raw_file(3).splitlines(), 4, _short))
    result = runner.invoke(
        app, ["dataset", "import-raw", str(data), "--db", str(db), "--features", "means"]
    )
    assert result.exit_code == 0, result.output
    result = runner.invoke(app, ["dataset", "import-raw", str(tmp_path / "none.jsonl")])
    assert result.exit_code == 2
    assert "cannot read" in said(result)
