"""``activetouch paper exp2``, small and fast: collect on the simulated rig, fit, trials from the
learned GP and from the rig, figures and a valid report."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from rich.console import Console
from typer.testing import CliRunner

from app.cli.main import app
from app.evaluation import runner as evaluation_runner
from app.evaluation.context import TrialContext, TrialKey, rig_tables
from app.evaluation.rig_trial import RigTrial
from app.evaluation.runner import run_evaluation
from app.evaluation.spec import EvaluationSpec
from app.paper.calibration import calibration_text
from app.paper.exp2 import Experiment2Settings, run_experiment2, write_figures
from core.evaluation.summary import wilson_interval
from core.validation import FloatArray
from hardware.errors import ServoHardwareErrorFlags
from hardware.records import TouchRecord

runner = CliRunner()

SMALL = Experiment2Settings(
    touches_per_object=5,
    optimizer="lbfgs",
    restarts=0,
    steps=3,
    trials_per_target=1,
    policies=("active", "passive"),
)


@pytest.fixture(scope="module")
def result():  # type: ignore[no-untyped-def]
    return run_experiment2(SMALL)


def test_training_touches_come_from_the_paper_table(result) -> None:  # type: ignore[no-untyped-def]
    data = result.data
    assert data.object_names == ("paper_cup", "bumpy_glass", "clear_plastic_cup", "stainless_cup")
    assert data.n_touches == 4 * 5
    assert data.actions.shape == (20, 6)
    assert data.observations.shape == (20, 5)
    # A random design: a fresh action per touch, not one shared design.
    assert len({tuple(np.round(x, 9)) for x in data.actions}) == 20
    assert result.model.latent_dim == 2


def test_reports_for_both_sources_summarise_their_trials(result) -> None:  # type: ignore[no-untyped-def]
    assert set(result.reports) == {"model", "rig"}
    for source, report in result.reports.items():
        assert report.spec.world == source
        assert report.spec.prior_variance == 5.0
        assert len(report.records) == 2 * 4 * 1
        summary = report.summary()
        for policy in ("active", "passive"):
            mine = [r for r in report.records if r.policy == policy]
            final_correct = sum(r.correct for r in mine)
            figures = summary[policy]
            assert len(figures["accuracy_by_touch"]) == 3
            # Accuracy at T and its interval, recomputed from the records.
            assert figures["accuracy_by_touch"][-1] == pytest.approx(final_correct / len(mine))
            lo, hi = wilson_interval(final_correct, len(mine))
            assert figures["accuracy_interval"][-1] == pytest.approx([lo, hi])
    # The table gives each policy's calibration per source, as the reports have it.
    console = Console(width=300, record=True)
    console.print(result.table())
    shown = console.export_text()
    for source, report in result.reports.items():
        for policy, figures in report.summary().items():
            assert f"{source}: {policy}, calibration" in shown
            assert calibration_text(figures) in shown
            sure = figures["calibration"]["all_touches"]["sure_and_wrong"]
            assert f"and wrong: {sure['wrong']} of {sure['sure']}" in calibration_text(figures)
    document = json.loads(json.dumps(result.to_dict()))
    assert document["format"] == "activetouch-paper-exp2/1"
    assert document["reports"]["rig"]["format"] == "activetouch-evaluation/2"
    assert document["seconds"] >= document["collect_seconds"] + document["fit_seconds"]


def test_figures_are_pngs(result, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    paths = write_figures(result, tmp_path)
    names = sorted(p.name for p in paths)
    assert names == [
        "exp2-accuracy-model.png",
        "exp2-accuracy-rig.png",
        "exp2-manifold.png",
        "exp2-reliability-model.png",
        "exp2-reliability-rig.png",
        "exp2-trajectories.png",
    ]
    for path in paths:
        with Image.open(path) as image:
            assert image.format == "PNG"
            assert image.size[0] > 300


def test_cli_runs_end_to_end(tmp_path: Path) -> None:
    out = runner.invoke(
        app,
        [
            "paper",
            "exp2",
            "--touches",
            "4",
            "--trials",
            "1",
            "--steps",
            "2",
            "--restarts",
            "0",
            "--optimizer",
            "lbfgs",
            "--sources",
            "model",
            "--figures",
            str(tmp_path),
            "--json",
        ],
    )
    assert out.exit_code == 0, out.output
    document = json.loads(out.stdout)
    assert list(document["reports"]) == ["model"]
    policies = document["reports"]["model"]["policies"]
    assert {"active", "passive"} <= set(policies)
    assert len(document["figures"]) == 4  # manifold, trajectories, accuracy, reliability
    assert all(Path(p).exists() for p in document["figures"])


@pytest.mark.parametrize(
    ("args", "named"),
    [
        (["--table", "no_such_table"], "no_such_table"),
        (["--sources", "model,camera"], "camera"),
        (["--optimizer", "sgd"], "sgd"),
        (["--placement", "shelf"], "shelf"),
    ],
)
def test_bad_input_exits_2_naming_it(args: list[str], named: str) -> None:
    out = runner.invoke(app, ["paper", "exp2", *args])
    assert out.exit_code == 2
    assert named in out.output


def test_a_rig_refusal_is_a_clear_error(monkeypatch: pytest.MonkeyPatch) -> None:
    # The simulated rig refuses a touch (e.g. a servo overload on a deep press): exit 1, the
    # error named, and the hint to make the touches shallower; no traceback.
    import app.paper.exp2 as exp2
    from hardware.errors import HardwareError

    def refuse(*_args: object, **_kwargs: object) -> None:
        raise HardwareError("servo FFJ3 (ID 1) reports a hardware error: OVERLOAD")

    monkeypatch.setattr(exp2, "run_experiment2", refuse)
    out = runner.invoke(app, ["paper", "exp2", "--touches", "4", "--trials", "1"])
    assert out.exit_code == 1
    assert "OVERLOAD" in out.output
    assert "--action-scale" in out.output
    assert "Traceback" not in out.output


class _RefuseFirstTouch(RigTrial):
    """A rig trial whose finger servo (ID 1) latches an overload before its first touch."""

    def _touch(self, action: FloatArray) -> TouchRecord:
        if self.touched == 1:
            self._handle.simulation.devices.bus.inject_hardware_error(  # type: ignore[union-attr]
                1, ServoHardwareErrorFlags.OVERLOAD
            )
        return super()._touch(action)


class _PassiveRefused(TrialContext):
    """Every passive trial's first touch is refused by the (simulated) rig."""

    def open_rig_trial(self, key: TrialKey, seed: int) -> RigTrial:
        if key[0] != "passive":
            return super().open_rig_trial(key, seed)
        return _RefuseFirstTouch(self._rig_actions(), rig_tables()["paper"], key[1], seed)


def test_a_policy_whose_every_trial_was_refused_has_a_row_saying_so(  # type: ignore[no-untyped-def]
    result, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(evaluation_runner, "TrialContext", _PassiveRefused)
    spec = EvaluationSpec(
        world="rig", trials_per_target=1, steps=2, policies=("active", "passive"), table="paper"
    )
    report = run_evaluation(result.model, spec)
    assert report.refused_by_policy() == {"active": 0, "passive": 4}
    assert set(report.summary()) == {"active"}  # no completed passive trial
    console = Console(record=True, width=1000)
    console.print(replace(result, reports={"rig": report}).table())
    rows = [" ".join(line.split()) for line in console.export_text().splitlines()]
    active = [i for i, r in enumerate(rows) if "rig: active, accuracy % by touch" in r]
    passive = [r for r in rows if "rig: passive, accuracy % by touch" in r]
    right = sum(r.correct for r in report.records)
    assert len(active) == 1
    assert f"at T: {100 * right / 4:.1f} %" in rows[active[0] + 1]
    assert len(passive) == 1
    assert "all 4 trials refused by the rig (no accuracy)" in passive[0]
    assert "first: touch 1 of passive/" in passive[0]
    assert "ServoHardwareError" in passive[0]
    assert "OVERLOAD" in passive[0]
    assert not any("rig: passive, per object" in r for r in rows)
