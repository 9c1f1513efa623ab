"""A rig evaluation goes on when the rig refuses one touch; other rig errors still end it.

The rig is the simulated one; :class:`RefusingContext` latches a servo fault on the simulated bus
just before one chosen touch of one chosen trial, so the real driver stack raises it.
"""

from __future__ import annotations

import pytest

from app.errors import DeviceUnavailableError
from app.evaluation import runner as evaluation_runner
from app.evaluation.context import TrialContext, TrialKey, rig_table
from app.evaluation.report import EvaluationReport
from app.evaluation.rig_trial import RigTrial
from app.evaluation.runner import run_evaluation
from app.evaluation.spec import EvaluationSpec
from core.evaluation.records import RefusedTrial, TrialRecord
from core.validation import FloatArray
from hardware.errors import DeviceDisconnected, ServoHardwareErrorFlags
from hardware.records import TouchRecord

#: The trial whose touch is refused, and which touch (1-based).
REFUSED_KEYS = (("active", "paper_cup", 1), ("passive", "paper_cup", 1))
REFUSED_TOUCH = 2

SPEC = EvaluationSpec(
    world="rig",
    trials_per_target=2,
    steps=3,
    targets=("paper_cup", "foam_sponge"),
    table="default",
    tolerance=0.0,  # every completed trial has 3 touches
)


class _FaultyTrial(RigTrial):
    """A rig trial whose finger servo (ID 1) latches ``fault`` before touch ``refused_touch``."""

    fault = ServoHardwareErrorFlags.OVERLOAD
    refused_touch = REFUSED_TOUCH

    def _touch(self, action: FloatArray) -> TouchRecord:
        if self.touched == self.refused_touch:
            self._handle.simulation.devices.bus.inject_hardware_error(1, self.fault)  # type: ignore[union-attr]
        return super()._touch(action)


class _VoltageTrial(_FaultyTrial):
    fault = ServoHardwareErrorFlags.INPUT_VOLTAGE


class _DisconnectedTrial(RigTrial):
    def _touch(self, action: FloatArray) -> TouchRecord:
        if self.touched == REFUSED_TOUCH:
            raise DeviceDisconnected("the finger's serial port went away")
        return super()._touch(action)


class RefusingContext(TrialContext):
    """Trials of :data:`REFUSED_KEYS` run on a :class:`_FaultyTrial` (picklable: Dask)."""

    trial_type: type[RigTrial] = _FaultyTrial

    def open_rig_trial(self, key: TrialKey, rig_seed: int) -> RigTrial:
        if key not in REFUSED_KEYS:
            return super().open_rig_trial(key, rig_seed)
        objects = rig_table(self.spec.table).slots
        return self.trial_type(self._rig_actions(), objects, key[1], rig_seed)


class VoltageContext(RefusingContext):
    trial_type = _VoltageTrial


class DisconnectingContext(RefusingContext):
    trial_type = _DisconnectedTrial


@pytest.fixture(scope="module")
def clean(rig_model):
    """The same evaluation on a rig that refuses nothing."""
    return run_evaluation(rig_model, SPEC)


@pytest.fixture
def refusing(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(evaluation_runner, "TrialContext", RefusingContext)


@pytest.fixture(scope="module")
def refused(rig_model) -> tuple[EvaluationReport, list[object]]:
    """The evaluation on a rig that refuses one touch of each of :data:`REFUSED_KEYS`, and what
    ``on_trial`` was called with (read only: several tests look at the one run)."""
    seen: list[object] = []
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(evaluation_runner, "TrialContext", RefusingContext)
        return run_evaluation(rig_model, SPEC, on_trial=seen.append), seen


def test_a_refused_touch_ends_only_its_trial_and_is_recorded(clean, refused):
    report, seen = refused
    assert len(seen) == 8
    assert [r.key for r in report.refused] == list(REFUSED_KEYS)
    # Every other trial ran as on a rig that refuses nothing.
    assert report.records == tuple(r for r in clean.records if r.key not in REFUSED_KEYS)
    for refused in report.refused:
        whole = next(r for r in clean.records if r.key == refused.key)
        assert refused.touch == REFUSED_TOUCH
        assert refused.actions == whole.actions[: REFUSED_TOUCH - 1]
        assert refused.answers == whole.answers[: REFUSED_TOUCH - 1]
        assert refused.action == whole.actions[REFUSED_TOUCH - 1]  # the action refused
        assert refused.error == "ServoHardwareError"
        assert "OVERLOAD" in refused.reason
        assert "FFJ3" in refused.reason


def test_the_report_counts_refused_trials_and_states_the_denominator(refused):
    report, _ = refused
    document = report.to_dict()
    assert document["refused_trials"] == 2
    assert document["refused_by_policy"] == {"active": 1, "passive": 1}
    assert [r["refused"]["touch"] for r in document["refused"]] == [2, 2]
    for policy in ("active", "passive"):
        mine = [r for r in report.records if r.policy == policy]
        right = sum(r.correct for r in mine)
        summary = document["policies"][policy]
        assert summary["trials"] == 3  # the completed ones: the accuracy's denominator
        assert summary["refused"] == 1
        assert summary["accuracy_by_touch"][-1] == pytest.approx(right / 3)
        assert summary["accuracy_if_refused_wrong"] == pytest.approx(right / 4)
        assert sum(o["trials"] for o in summary["per_object"].values()) == 3
        note = next(n for n in document["notes"] if n.startswith(f"{policy}:"))
        assert "refused a touch in 1 of 4 trials" in note
        assert "over the 3 completed trials only" in note
        assert "accuracy and calibration" in note
        # The calibration is over the completed trials too (their touches before the refusal
        # are not scored): 3 trials, T touches each.
        calibration = summary["calibration"]
        assert calibration["final"]["answers"] == 3
        assert calibration["all_touches"]["answers"] == 3 * document["steps"]
        assert calibration["final"]["accuracy"] == pytest.approx(right / 3)
        assert f"{right}/4" in note
    rows = report.csv_rows()
    refused_rows = [row for row in rows if str(row[-1]).startswith("refused: ServoHardwareError")]
    assert [(row[0], row[1], row[2], row[3]) for row in refused_rows] == [
        ("active", "paper_cup", 1, 2),
        ("passive", "paper_cup", 1, 2),
    ]
    # The touches before the refusal are kept too: 3 per completed trial, 1 per refused one.
    assert len(rows) == 1 + 6 * 3 + 2 * (1 + 1)


def test_a_resumed_run_keeps_refused_trials_without_redoing_them(rig_model, refused, refusing):
    first, _ = refused
    seen: list[object] = []
    again = run_evaluation(
        rig_model, SPEC, done=[*first.records, *first.refused], on_trial=seen.append
    )
    assert seen == []
    assert (again.records, again.refused) == (first.records, first.refused)


@pytest.mark.parametrize(
    ("context", "error"),
    [(DisconnectingContext, "DeviceDisconnected"), (VoltageContext, "ServoHardwareError")],
)
def test_an_error_that_is_not_a_refusal_still_fails_the_evaluation(
    rig_model, monkeypatch, context, error
):
    monkeypatch.setattr(evaluation_runner, "TrialContext", context)
    with pytest.raises(DeviceUnavailableError) as failed:
        run_evaluation(rig_model, SPEC)
    message = failed.value.message
    assert f"the rig failed in trial 1 of active/paper_cup at touch 2 of the trial: {error}" in (
        message
    )
    assert "not the refusal of one touch" in message
    assert failed.value.extra["device_error"] == error


def test_a_rig_failure_on_dask_fails_the_evaluation_naming_the_trial(
    rig_model, monkeypatch, dask_cluster
):
    monkeypatch.setattr(evaluation_runner, "TrialContext", DisconnectingContext)
    with pytest.raises(DeviceUnavailableError, match=r"in trial 1 of (active|passive)/paper_cup"):
        run_evaluation(rig_model, SPEC, scheduler=dask_cluster.scheduler_address)


def test_refused_trials_are_the_same_on_dask(rig_model, refused, refusing, dask_cluster):
    serial, _ = refused
    distributed = run_evaluation(rig_model, SPEC, scheduler=dask_cluster.scheduler_address)
    assert distributed.workers == 2
    assert distributed.records == serial.records
    assert distributed.refused == serial.refused
    assert all(isinstance(r, RefusedTrial) for r in distributed.refused)
    assert all(isinstance(r, TrialRecord) for r in distributed.records)
    expected, actual = serial.to_dict(), distributed.to_dict()
    for document in (expected, actual):
        del document["seconds"], document["workers"]
    assert actual == expected


def _api_evaluation(tmp_path, rig_model, body_changes=None):
    """Import the model, run SPEC through the REST API; return (ended evaluation, client calls)."""
    from fastapi.testclient import TestClient

    from app.documents.model import model_to_document
    from app.main import create_app
    from tests.app.conftest import make_settings
    from tests.app.test_evaluations_api import wait_ended

    client = TestClient(create_app(make_settings(tmp_path)))
    with client:
        imported = client.post("/api/v1/models/import", json=model_to_document(rig_model))
        assert imported.status_code == 201, imported.text
        body = {
            "model_id": imported.json()["id"],
            "world": "rig",
            "policies": list(SPEC.policies),
            "trials_per_target": SPEC.trials_per_target,
            "steps": SPEC.steps,
            "targets": list(SPEC.targets or ()),
            "table": SPEC.table,
        }
        created = client.post("/api/v1/evaluations", json=body)
        assert created.status_code == 202, created.text
        evaluation_id = created.json()["id"]
        ended = wait_ended(client, evaluation_id)
        base = f"/api/v1/evaluations/{evaluation_id}"
        trials = client.get(f"{base}/trials").json()["data"]
        details = [client.get(f"{base}/trials/{t['number']}").json() for t in trials]
        exported = client.get(f"{base}/export").json()
        csv_text = client.get(f"{base}/export?format=csv").text
    return ended, trials, details, exported, csv_text


def test_the_api_completes_and_shows_refused_trials(tmp_path, rig_model, refusing):
    # The API's spec has the default tolerance: the engine run to compare with does too.
    spec = EvaluationSpec(**{**SPEC.__dict__, "tolerance": 1e-3})
    engine = run_evaluation(rig_model, spec).to_dict()
    ended, trials, details, exported, csv_text = _api_evaluation(tmp_path, rig_model)
    assert ended["status"] == "completed", ended["reason"]
    assert (ended["done"], ended["total"]) == (8, 8)
    summary = ended["summary"]
    assert summary["refused_trials"] == 2
    assert summary["refused_by_policy"] == {"active": 1, "passive": 1}
    assert summary["policies"] == engine["policies"]
    assert summary["notes"] == engine["notes"]
    refused = [t for t in trials if t["refused"]]
    assert sorted((t["policy"], t["target"], t["trial"]) for t in refused) == list(REFUSED_KEYS)
    for t in refused:
        assert (t["correct"], t["answer"], t["stop_reason"]) == (False, None, "refused")
        assert t["touches"] == REFUSED_TOUCH - 1
        assert t["refusal"]["touch"] == REFUSED_TOUCH
        assert t["refusal"]["error"] == "ServoHardwareError"
        assert "OVERLOAD" in t["refusal"]["reason"]
        assert len(t["refusal"]["action"]) == 6
    assert all(t["refusal"] is None for t in trials if not t["refused"])
    assert sum(d["record"].get("refused") is not None for d in details) == 2
    assert exported["refused"] == engine["refused"]
    assert exported["trials"] == engine["trials"]
    assert csv_text.count("refused: ServoHardwareError") == 2


def test_the_api_fails_an_evaluation_the_rig_fails_keeping_finished_trials(
    tmp_path, rig_model, monkeypatch
):
    monkeypatch.setattr(evaluation_runner, "TrialContext", DisconnectingContext)
    ended, trials, _, _, _ = _api_evaluation(tmp_path, rig_model)
    assert ended["status"] == "failed"
    assert ended["reason"].startswith(
        "DeviceUnavailableError: the rig failed in trial 1 of active/paper_cup at touch 2 of "
        "the trial: DeviceDisconnected: the finger's serial port went away."
    )
    # The trial before it (policy-major, then the model's object order, then index) is kept.
    assert [(t["policy"], t["target"], t["trial"]) for t in trials] == [("active", "paper_cup", 0)]
    assert ended["summary"]["partial"] is True
    assert ended["summary"]["policies"]["active"]["trials"] == 1


def test_the_migration_adds_refused_and_earlier_trials_stay_completed(tmp_path) -> None:
    from sqlalchemy import create_engine, inspect, text

    from app.db import Database, upgrade_to_head
    from tests.app.conftest import make_settings
    from tests.app.test_migrations import migrate

    settings = make_settings(tmp_path)
    database = Database(settings.database_url)

    def columns() -> set[str]:
        return {c["name"] for c in inspect(database.engine).get_columns("evaluation_trials")}

    try:
        upgrade_to_head(database.engine, settings.migrations_dir)
        assert "refused" in columns()
        migrate(database, settings.migrations_dir, "0004_request_audit", down=True)
        assert "refused" not in columns()
        raw = create_engine(settings.database_url)  # no foreign keys: a trial without a model
        with raw.begin() as connection:
            connection.execute(
                text(
                    "INSERT INTO evaluations (id, model_id, spec, status, done, total, steps, "
                    "created_at, updated_at) VALUES (1, 1, '{}', 'completed', 1, 1, 2, "
                    "'2026-11-24 12:00:00', '2026-11-24 12:00:00')"
                )
            )
            connection.execute(
                text(
                    "INSERT INTO evaluation_trials (id, evaluation_id, number, policy, target, "
                    "trial, correct, touches, record, created_at) VALUES (1, 1, 1, 'active', "
                    "'paper_cup', 0, 1, 2, '{}', '2026-11-24 12:00:00')"
                )
            )
        raw.dispose()
        migrate(database, settings.migrations_dir, "head")
        assert "refused" in columns()
        with database.engine.connect() as connection:
            rows = connection.execute(text("SELECT id, refused FROM evaluation_trials")).all()
        assert [tuple(r) for r in rows] == [(1, 0)]  # a trial from before was completed
    finally:
        database.dispose()


@pytest.fixture(scope="module")
def model_path(rig_model, tmp_path_factory: pytest.TempPathFactory):
    import json

    from app.documents.model import model_to_document

    path = tmp_path_factory.mktemp("refused") / "rig.json"
    path.write_text(json.dumps(model_to_document(rig_model)))
    return path


def _evaluate(model_path, *args: str):
    from typer.testing import CliRunner

    from app.cli.main import app

    return CliRunner().invoke(
        app,
        [
            *("evaluate", "--model", str(model_path), "--world", "rig", "--table", "default"),
            *("--targets", "paper_cup,foam_sponge", "--trials", "2", "--steps", "3", *args),
        ],
    )


def test_the_cli_counts_refused_trials(model_path, refusing, tmp_path):
    import json

    out = tmp_path / "report.json"
    table = _evaluate(model_path, "--out", str(out))  # the table, and the JSON report (--json's)
    assert table.exit_code == 0, table.output
    assert "refused" in table.stdout
    assert "completed" in table.stdout
    assert "the rig refused a touch in 1 of 4 trials" in " ".join(table.stdout.split())
    document = json.loads(out.read_text())
    assert document["refused_by_policy"] == {"active": 1, "passive": 1}
    assert [(r["policy"], r["refused"]["touch"]) for r in document["refused"]] == [
        ("active", REFUSED_TOUCH),
        ("passive", REFUSED_TOUCH),
    ]


def test_the_cli_exits_1_when_the_rig_fails(model_path, monkeypatch):
    monkeypatch.setattr(evaluation_runner, "TrialContext", DisconnectingContext)
    result = _evaluate(model_path, "--json")
    assert result.exit_code == 1
    assert result.stdout == ""
    assert "the rig failed in trial 1 of active/paper_cup" in " ".join(result.stderr.split())
