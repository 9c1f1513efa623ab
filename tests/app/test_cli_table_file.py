"""``--table-file`` end to end: your own objects through ``rig status``, ``collect``, ``fit``,
``evaluate``, and the server's setting."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
from typer.testing import CliRunner

from app.cli.main import app
from app.config import ConfigurationError
from app.main import create_app
from tests.app.conftest import TestClient, make_settings
from tests.app.test_evaluations_api import wait_ended
from tests.app.waits import finished, wait_until
from tests.hardware.test_table_file import CERAMIC

runner = CliRunner()
pytestmark = pytest.mark.usefixtures("cli_rig_rest")  # 5 s before each touch, not 20 s

#: Two objects, the mug of the hardware tests' ceramic; the cork asks for slot 0.
CORK = {
    "stiffness_n_per_mm": 2.0,
    "friction": 0.6,
    "stick_slip": 0.15,
    "roughness_um": 30.0,
    "texture_period_mm": 0.6,
    "effusivity": 140.0,
}
KITCHEN = {
    "name": "kitchen",
    "action_std": 0.8,
    "objects": [
        {"name": "mug", "material": CERAMIC},
        {"name": "cork", "slot": 0, "material": CORK},
    ],
}


def said(result: Any) -> str:
    """What the command printed, with rich's line wrapping undone."""
    return " ".join(result.output.split())


@pytest.fixture
def kitchen(tmp_path: Path) -> Path:
    path = tmp_path / "table.json"  # named by its "name"
    path.write_text(json.dumps(KITCHEN))
    return path


def test_rig_status_collect_fit_and_evaluate_on_a_table_file(kitchen: Path, tmp_path: Path) -> None:
    status = runner.invoke(app, ["rig", "status", "--sim", "--table-file", str(kitchen), "--json"])
    assert status.exit_code == 0, status.output
    document = json.loads(status.stdout)
    assert document["simulated_table"] == "kitchen"
    assert document["simulated_table_action_std"] == 0.8
    assert document["simulated_objects"] == ["cork", "mug"]  # cork asked for slot 0
    assert document["simulated_materials"] == {"cork": "cork", "mug": "glazed ceramic"}

    data = tmp_path / "kitchen.csv"
    collected = runner.invoke(
        app,
        [
            *("collect", "--sim", "--table-file", str(kitchen), "--duration", "5"),
            *("--touches", "4", "--design", "random", "--out", str(data), "--json"),
        ],
    )
    assert collected.exit_code == 0, collected.output
    summary = json.loads(collected.stdout)
    assert summary["objects"] == [
        {"name": "cork", "slot": 0, "touches": 4},
        {"name": "mug", "slot": 1, "touches": 4},
    ]
    assert summary["complete"] is True

    model = tmp_path / "kitchen.json"
    fitted = runner.invoke(
        app, ["fit", str(data), "--latent-dim", "1", "--restarts", "0", "--out", str(model)]
    )
    assert fitted.exit_code == 0, fitted.output
    evaluated = runner.invoke(
        app,
        [
            *("evaluate", "--model", str(model), "--world", "rig"),
            *("--table-file", str(kitchen), "--trials", "1", "--steps", "1", "--json"),
        ],
    )
    assert evaluated.exit_code == 0, evaluated.output
    report = json.loads(evaluated.stdout)
    assert report["table"] == "kitchen"
    assert {t["target"] for t in report["trials"]} == {"cork", "mug"}

    # The server with the same file: a rig evaluation naming no table, or naming the file's.
    with TestClient(create_app(make_settings(tmp_path, sim_table_file=kitchen))) as client:
        imported = client.post("/api/v1/models/import", json=json.loads(model.read_text()))
        assert imported.status_code == 201, imported.text
        body = {"model_id": imported.json()["id"], "world": "rig", "trials_per_target": 1}
        for named in ({}, {"table": "kitchen"}):
            created = client.post("/api/v1/evaluations", json={**body, **named, "steps": 1})
            assert created.status_code == 202, created.text
            ended = wait_ended(client, created.json()["id"])
            assert ended["status"] == "completed", ended["reason"]
            assert ended["summary"]["table"] == "kitchen"
        trial = client.post(
            "/api/v1/trials",
            json={"model_id": body["model_id"], "mode": "simulated", "target": "mug",
                  "max_steps": 1, "seed": 2, "simulation": {"world": "rig"}},
        )  # fmt: skip
        assert trial.status_code == 201, trial.text
        touched = wait_until(client, f"/api/v1/trials/{trial.json()['id']}", finished)
        assert touched["status"] == "completed", touched
        unknown = client.post("/api/v1/evaluations", json={**body, "steps": 1, "table": "cushions"})
        assert unknown.status_code == 422  # a built-in table does not hold cork and mug
        assert "targets" in unknown.text


@pytest.mark.parametrize(
    "command",
    [
        ["rig", "status", "--sim"],
        ["collect", "--sim", "--out", "never.csv"],
        ["evaluate", "--model", "never.json", "--world", "rig"],
        ["paper", "exp2"],
    ],
)
def test_a_bad_table_file_exits_2_naming_the_object_and_the_field(
    command: list[str], tmp_path: Path
) -> None:
    bad = tmp_path / "bad.json"
    bad.write_text(
        json.dumps(
            {
                "objects": [
                    {
                        "name": "brick",
                        "material": {
                            "stiffness_n_per_mm": -5.0,
                            "friction": 0.6,
                            "stick_slip": 0.1,
                            "roughness_um": 10.0,
                            "texture_period_mm": 1.0,
                            "effusivity": 1000.0,
                        },
                    }
                ]
            }
        )
    )
    result = runner.invoke(app, [*command, "--table-file", str(bad)])
    assert result.exit_code == 2, result.output
    assert "object 'brick', material.stiffness_n_per_mm: must be > 0" in said(result)
    assert not (tmp_path / "never.csv").exists()


def test_table_and_table_file_together_or_without_sim_exit_2(kitchen: Path) -> None:
    both = runner.invoke(
        app, ["rig", "status", "--sim", "--table", "paper", "--table-file", str(kitchen)]
    )
    assert both.exit_code == 2
    assert "give --table or --table-file, not both" in said(both)
    real = runner.invoke(app, ["rig", "status", "--table-file", str(kitchen)])
    assert real.exit_code == 2
    assert "add --sim" in said(real)


def test_the_server_simulates_its_table_file_and_refuses_a_bad_one(
    kitchen: Path, tmp_path: Path
) -> None:
    settings = make_settings(tmp_path, sim_table_file=kitchen)
    settings.check_safe_to_serve()
    with TestClient(create_app(settings)) as client:
        assert client.post("/api/v1/rig/connect").status_code == 200
        detail = client.get("/api/v1/rig").json()["detail"]
    assert detail["objects_by_slot"] == ["cork", "mug"]
    assert detail["object_properties"]["mug"]["material"] == "glazed ceramic"
    bad = tmp_path / "bad.json"
    cork = {"name": "cork", "slot": 0, "material": {**CORK, "hardness": 2}}
    bad.write_text(json.dumps({**KITCHEN, "objects": [KITCHEN["objects"][0], cork]}))
    with pytest.raises(ConfigurationError, match=r"object 'cork', material\.hardness: unknown"):
        make_settings(tmp_path, sim_table_file=bad).check_safe_to_serve()
