"""The press-depth action component: its envelope, the trajectories it makes, and every place
that picks it from a collection's or a model's dx (collect, the API, evaluations, trials)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient
from typer.testing import CliRunner

from app.cli.main import app
from app.documents.model import model_to_document
from app.documents.training_csv import read_training_csv
from app.errors import BadInputError
from app.evaluation.runner import run_evaluation
from app.evaluation.spec import EvaluationSpec
from app.rig.action_layout import DMP_ACTION_DIM, has_press_depth, shift_dimensions
from app.rig.actions import TouchActions
from app.rig.press_depth import PressDepth, rig_action_dim
from core.errors import InvalidInputError
from core.types import ManifoldModel
from tests.app.conftest import RIG_OBJECTS, fitted_on_the_rig
from tests.app.waits import completed_collection, completed_rig_trial

API = "/api/v1"
runner = CliRunner()


@pytest.fixture(scope="module")
def press_model() -> ManifoldModel:
    """A ds=1 model fitted on 6 touches of :data:`RIG_OBJECTS`, actions with the press depth."""
    return fitted_on_the_rig(
        "default", RIG_OBJECTS, touches=6, latent_dim=1, seed=5, press_depth=True
    )


def test_the_envelope_is_off_while_approaching_and_whole_while_pressing() -> None:
    press = PressDepth(deg_per_unit=0.5, start_deg=10.0, full_deg=14.0)
    np.testing.assert_array_equal(
        press.envelope(np.array([0.0, 10.0, 11.0, 12.0, 14.0, 30.0])),
        [0.0, 0.0, 0.25, 0.5, 1.0, 1.0],
    )
    trajectory = np.array([[5.0, 1.0], [12.0, 2.0], [20.0, 3.0]])
    pressed = press.apply(trajectory, 2.0)  # 1° at full depth
    np.testing.assert_array_equal(pressed, [[5.0, 1.0], [12.5, 2.0], [21.0, 3.0]])
    np.testing.assert_array_equal(trajectory[1], [12.0, 2.0])  # not changed in place


def test_the_envelope_comes_from_the_teaching_peak() -> None:
    teaching = np.array([[0.0, 0.0], [20.0, 1.0], [10.0, -1.0]])
    press = PressDepth.for_teaching(teaching, deg_per_unit=0.3)
    assert (press.start_deg, press.full_deg, press.deg_per_unit) == pytest.approx((9.4, 14.0, 0.3))


@pytest.mark.parametrize(
    ("changes", "fragment"),
    [
        ({"deg_per_unit": 0.0}, "deg_per_unit must be > 0"),
        ({"deg_per_unit": float("nan")}, "deg_per_unit must be > 0"),
        ({"full_deg": 10.0}, "start_deg < full_deg"),
    ],
)
def test_a_bad_component_says_what_is_wrong(changes: dict[str, float], fragment: str) -> None:
    values = {"deg_per_unit": 0.25, "start_deg": 10.0, "full_deg": 14.0} | changes
    with pytest.raises(BadInputError, match=fragment):
        PressDepth(values["deg_per_unit"], values["start_deg"], values["full_deg"])


def test_the_press_depth_moves_only_the_pressing_flexion() -> None:
    plain = TouchActions.from_teaching()
    pressed = TouchActions.from_teaching(press_depth=True)
    assert (plain.action_dim, pressed.action_dim) == (6, 7)
    assert pressed.press is not None
    x = np.array([0.3, -0.2, 0.1, 0.0, 0.5, -0.4])
    base = plain.trajectory(x)
    # x_7 = 0 is the plain action.
    np.testing.assert_array_equal(pressed.trajectory(np.append(x, 0.0)), base)
    deeper = pressed.trajectory(np.append(x, 2.0))
    change = deeper - base
    np.testing.assert_array_equal(change[:, 1], 0.0)  # the abduction is not touched
    flexion = base[:, 0]
    pressing = flexion >= pressed.press.full_deg
    approaching = flexion <= pressed.press.start_deg
    assert pressing.sum() > 100
    assert approaching.sum() > 50
    np.testing.assert_allclose(change[pressing, 0], 2.0 * 0.25)
    np.testing.assert_array_equal(change[approaching, 0], 0.0)


def test_a_models_dx_picks_the_actions() -> None:
    assert TouchActions.from_teaching().action_dim == DMP_ACTION_DIM
    assert TouchActions.from_teaching(press_depth=True).action_dim == DMP_ACTION_DIM + 1
    assert [has_press_depth(dx) for dx in (5, 6, 7, 8)] == [None, False, True, None]
    assert [rig_action_dim(dx) for dx in (5, 6, 7, 8)] == [6, 6, 7, 6]
    assert TouchActions.for_action_dim(6).press is None
    assert TouchActions.for_action_dim(7).press is not None
    with pytest.raises(BadInputError, match=r"dx=6 \(or 7 with the press depth\).*dx=8"):
        TouchActions.for_action_dim(8)
    with pytest.raises(InvalidInputError, match="action"):
        TouchActions.from_teaching(press_depth=True).trajectory(np.zeros(6))


@pytest.mark.usefixtures("cli_rig_rest")
@pytest.mark.parametrize(("option", "dx"), [([], 7), (["--no-press-depth"], 6)])
def test_collect_has_the_press_depth_unless_told(
    tmp_path: Path, option: list[str], dx: int
) -> None:
    out = tmp_path / "data.csv"
    result = runner.invoke(
        app,
        ["collect", "--sim", "--duration", "5", "--object", "paper_cup", "--object",
         "foam_sponge", "--design", "random", "--touches", "2", "--placements", "2",
         *option, "--out", str(out), "--json"],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    assert json.loads(result.stdout)["action_dim"] == dx
    data = read_training_csv(out.read_text())
    assert data.action_dim == dx
    assert np.all(data.actions[:, dx - 1] != 0.0)  # drawn like the other components


def test_a_rig_evaluation_touches_with_the_models_press_depth(press_model: ManifoldModel) -> None:
    spec = EvaluationSpec(
        world="rig",
        policies=("active", "passive"),
        trials_per_target=1,
        steps=2,
        targets=("paper_cup",),
        table="default",
    )
    report = run_evaluation(press_model, spec)
    assert all(len(a) == 7 for record in report.records for a in record.actions)
    # The active planner chooses the depth too.
    active = next(r for r in report.records if r.key[0] == "active")
    assert any(a[6] != 0.0 for a in active.actions)


def test_the_server_collects_and_touches_with_the_press_depth(
    client: TestClient, press_model: ManifoldModel
) -> None:
    body: dict[str, Any] = {
        "objects": [{"name": "paper_cup", "slot": 0}, {"name": "foam_sponge", "slot": 6}],
        "samples_per_object": 2,
        "action_design": "random",
        "placements": 2,
    }
    run = completed_collection(client, body)
    assert run["params"]["press_depth"] is True  # the default
    assert client.get(f"{API}/datasets/{run['dataset_id']}").json()["action_dim"] == 7
    run = completed_collection(client, {**body, "press_depth": False})
    assert client.get(f"{API}/datasets/{run['dataset_id']}").json()["action_dim"] == 6

    done = completed_rig_trial(
        client, model_to_document(press_model), target="paper_cup", max_steps=2
    )
    actions = TouchActions.from_teaching(press_depth=True)
    for step in done["steps"]:
        assert len(step["action"]) == 7
        np.testing.assert_allclose(
            step["trajectory"]["commanded_deg"], actions.trajectory(step["action"]), atol=1e-9
        )


def test_the_shift_is_estimated_along_the_press_depth_of_the_rigs_actions() -> None:
    np.testing.assert_array_equal(shift_dimensions(DMP_ACTION_DIM + 1), [DMP_ACTION_DIM])
    assert shift_dimensions(DMP_ACTION_DIM) is None  # the DMP components alone: every one
    assert shift_dimensions(3) is None  # not the rig's actions
    assert shift_dimensions(DMP_ACTION_DIM + 1, "all") is None
    with pytest.raises(InvalidInputError, match="shift_along"):
        shift_dimensions(DMP_ACTION_DIM + 1, "depth")
