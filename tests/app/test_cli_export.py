"""``activetouch export``: what the server stored, read back through its services."""

from __future__ import annotations

import csv
import io
import json
import sqlite3
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient
from typer.testing import CliRunner

from app import crud
from app.cli.main import app
from app.db import Database
from app.documents.model import model_from_document
from app.documents.training_csv import read_training_csv
from app.main import create_app
from core.evaluation.worlds import Experiment1World
from core.gp.posterior import predict
from tests.app.conftest import experiment1_csv, experiment1_document, make_settings

API = "/api/v1"
ACTIONS = ([0.1], [0.5], [-0.3])
runner = CliRunner()


def said(result: Any) -> str:
    """What the command printed, with rich's line wrapping undone."""
    return " ".join(result.output.split())


@pytest.fixture(scope="module")
def stored(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """A server database with an uploaded dataset, an imported model, a model still fitting and
    a scripted trial of three steps; plus what the API says of each, for comparison."""
    folder = tmp_path_factory.mktemp("export")
    settings = make_settings(folder)
    facts: dict[str, Any] = {"db": folder / "test.db"}
    with TestClient(create_app(settings)) as client:
        upload = client.post(
            f"{API}/datasets?name=cups",
            content=experiment1_csv(seed=1, touches_per_object=5),
            headers={"content-type": "text/csv"},
        )
        assert upload.status_code == 201, upload.text
        facts["dataset_id"] = upload.json()["id"]
        facts["dataset_csv"] = client.get(
            f"{API}/datasets/{facts['dataset_id']}/export?format=csv"
        ).text
        imported = client.post(f"{API}/models/import", json=experiment1_document())
        assert imported.status_code == 201, imported.text
        facts["model_id"] = imported.json()["id"]
        facts["model_document"] = client.get(f"{API}/models/{facts['model_id']}/export").json()
        trial = client.post(
            f"{API}/trials",
            json={"model_id": facts["model_id"], "mode": "scripted", "max_steps": 5,
                  "tolerance": 0.0, "target": "O2", "seed": 1},
        )  # fmt: skip
        assert trial.status_code == 201, trial.text
        facts["trial_id"] = trial.json()["id"]
        rng = np.random.default_rng(5)
        for action in ACTIONS:
            y = Experiment1World().observe(1, np.asarray([action]), rng)[0]
            posted = client.post(
                f"{API}/trials/{facts['trial_id']}/observations",
                json={"action": action, "observation": y.tolist()},
            )
            assert posted.status_code == 200, posted.text
        facts["trial"] = client.get(f"{API}/trials/{facts['trial_id']}").json()
    database = Database(settings.database_url)
    with database.session() as session:  # a model whose fit has not finished
        row = crud.create_model(
            session, dataset_id=facts["dataset_id"], status="fitting", latent_dim=1,
            optimizer="lbfgs", restarts=0, seed=None,
        )  # fmt: skip
        session.commit()
        facts["fitting_id"] = row.id
    database.dispose()
    return facts


def export(stored: dict[str, Any], *args: str) -> Any:
    return runner.invoke(app, ["export", *args, "--db", str(stored["db"])])


def test_list_shows_what_the_database_holds(stored: dict[str, Any]) -> None:
    result = export(stored, "list", "--json")
    assert result.exit_code == 0, result.output
    listing = json.loads(result.stdout)
    by_id = {d["id"]: d for d in listing["datasets"]}
    assert by_id[stored["dataset_id"]]["name"] == "cups"
    assert by_id[stored["dataset_id"]]["n_samples"] == 20
    assert len(listing["datasets"]) == 2  # the upload and the imported model's data
    assert {m["id"]: m["status"] for m in listing["models"]} == {
        stored["model_id"]: "ready",
        stored["fitting_id"]: "fitting",
    }
    assert [(t["id"], t["n_steps"]) for t in listing["trials"]] == [(stored["trial_id"], 3)]
    table = export(stored, "list")
    assert table.exit_code == 0, table.output
    assert "datasets (2)" in table.stdout
    assert "models (2)" in table.stdout
    assert "trials (1)" in table.stdout


def test_dataset_is_the_training_csv(stored: dict[str, Any], tmp_path: Path) -> None:
    out = tmp_path / "cups.csv"
    result = export(stored, "dataset", str(stored["dataset_id"]), "--out", str(out))
    assert result.exit_code == 0, result.output
    assert out.read_text() == stored["dataset_csv"]
    data = read_training_csv(out.read_text())
    original = read_training_csv(experiment1_csv(seed=1, touches_per_object=5))
    np.testing.assert_array_equal(data.actions, original.actions)
    np.testing.assert_array_equal(data.observations, original.observations)
    to_stdout = export(stored, "dataset", str(stored["dataset_id"]))
    assert to_stdout.stdout == stored["dataset_csv"]


def test_model_is_the_model_document(stored: dict[str, Any], tmp_path: Path) -> None:
    out = tmp_path / "model.json"
    result = export(stored, "model", str(stored["model_id"]), "--out", str(out))
    assert result.exit_code == 0, result.output
    document = json.loads(out.read_text())
    assert document == stored["model_document"]
    assert document["format"] == "activetouch-model/1"
    model = model_from_document(document)
    original = model_from_document(experiment1_document())
    s, x = np.linspace(-1, 1, 5)[:, None], np.linspace(-2, 2, 5)[:, None]
    for a, b in zip(predict(model, s, x), predict(original, s, x), strict=True):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-10)


def test_a_model_still_fitting_cannot_be_exported(stored: dict[str, Any]) -> None:
    result = export(stored, "model", str(stored["fitting_id"]))
    assert result.exit_code == 1
    assert f"Model {stored['fitting_id']} is fitting" in said(result)


def test_trial_steps_as_csv_and_the_trial_as_json(stored: dict[str, Any]) -> None:
    result = export(stored, "trial", str(stored["trial_id"]))
    assert result.exit_code == 0, result.output
    rows = list(csv.DictReader(io.StringIO(result.stdout)))
    steps = stored["trial"]["steps"]
    assert [int(r["step"]) for r in rows] == [1, 2, 3]
    assert [[float(r["x_1"])] for r in rows] == list(ACTIONS)
    for row, step in zip(rows, steps, strict=True):
        assert [float(row[f"y_{i}"]) for i in (1, 2, 3)] == step["observation"]
        assert float(row["mean_1"]) == step["belief"]["mean"][0]
        assert float(row["cov_1_1"]) == step["belief"]["cov"][0][0]
        probabilities = [float(row[f"p_O{i}"]) for i in (1, 2, 3, 4)]
        assert sum(probabilities) == pytest.approx(1.0, abs=1e-12)
        assert row["answer"] == step["answer"]
    as_json = export(stored, "trial", str(stored["trial_id"]), "--json")
    assert as_json.exit_code == 0, as_json.output
    assert json.loads(as_json.stdout) == stored["trial"]


@pytest.mark.parametrize("kind", ["dataset", "model", "trial"])
def test_an_unknown_id_is_a_clear_error(stored: dict[str, Any], kind: str) -> None:
    result = export(stored, kind, "999")
    assert result.exit_code == 2
    assert f"{kind.capitalize()} 999 does not exist" in said(result)


def test_the_database_must_exist_and_be_ours(tmp_path: Path) -> None:
    missing = runner.invoke(app, ["export", "list", "--db", str(tmp_path / "none.db")])
    assert missing.exit_code == 2
    assert "no database at" in said(missing)
    assert not (tmp_path / "none.db").exists()  # nothing was created
    junk = tmp_path / "junk.db"
    junk.write_text("not a database")
    result = runner.invoke(app, ["export", "list", "--db", str(junk)])
    assert result.exit_code == 2
    assert "file is not a database" in said(result)
    other = tmp_path / "other.db"
    sqlite3.connect(other).close()
    result = runner.invoke(app, ["export", "list", "--db", str(other)])
    assert result.exit_code == 2
    assert "not an ActiveTouch database" in said(result)
    result = runner.invoke(app, ["export", "list", "--db", "postgresql://host/db"])
    assert result.exit_code == 2
    assert "only SQLite" in said(result)


def test_an_older_schema_asks_for_an_upgrade(stored: dict[str, Any], tmp_path: Path) -> None:
    copy = tmp_path / "old.db"
    with sqlite3.connect(stored["db"]) as source, sqlite3.connect(copy) as target:
        source.backup(target)
        target.execute("UPDATE alembic_version SET version_num = '0001_old'")
    result = runner.invoke(app, ["export", "list", "--db", str(copy)])
    assert result.exit_code == 2
    assert "schema revision 0001_old" in said(result)
    assert "activetouch serve" in said(result)


def test_without_db_it_reads_the_database_serve_would_use(
    stored: dict[str, Any], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)  # no .env here
    monkeypatch.setenv("ACTIVETOUCH_DATABASE_URL", f"sqlite:///{stored['db']}")
    result = runner.invoke(app, ["export", "list", "--json"])
    assert result.exit_code == 0, result.output
    assert len(json.loads(result.stdout)["trials"]) == 1
    monkeypatch.delenv("ACTIVETOUCH_DATABASE_URL")
    result = runner.invoke(app, ["export", "list"])
    assert result.exit_code == 2
    assert "no database at activetouch.db" in said(result)


def test_raw_export_of_a_dataset_uploaded_as_y_says_it_has_no_series(
    stored: dict[str, Any],
) -> None:
    result = export(stored, "dataset", str(stored["dataset_id"]), "--raw")
    assert result.exit_code == 2
    assert "sample 1 has no raw series" in said(result)
