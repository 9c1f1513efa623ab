"""``GET /evaluations/{id}/trials/{n}`` of a refused trial: what the Trials view opens.

Two trials of a rig evaluation are refused by a latched servo overload, one at its first touch
(no touch made) and one at its second (one touch made). Their views carry the refusal and the
touches made before it, exactly as the engine recorded them, and no answer.
"""

from __future__ import annotations

import pytest

from app.evaluation import runner as evaluation_runner
from app.evaluation.context import TrialKey, rig_tables
from app.evaluation.rig_trial import RigTrial
from app.evaluation.runner import run_evaluation
from app.evaluation.spec import EvaluationSpec
from core.evaluation.records import RefusedTrial
from tests.app.test_evaluation_refused import (
    REFUSED_KEYS,
    SPEC,
    RefusingContext,
    _api_evaluation,
    _FaultyTrial,
)

#: Refused touch of each trial of :data:`REFUSED_KEYS`: the first, then the second.
TOUCH_OF = dict(zip(REFUSED_KEYS, (1, 2), strict=True))


class _FirstTouchTrial(_FaultyTrial):
    refused_touch = 1


class FirstOrSecondTouchContext(RefusingContext):
    """Active's refused trial is refused at its first touch, passive's at its second."""

    def open_rig_trial(self, key: TrialKey, rig_seed: int) -> RigTrial:
        if key not in REFUSED_KEYS:
            return super().open_rig_trial(key, rig_seed)
        kind = _FirstTouchTrial if TOUCH_OF[key] == 1 else _FaultyTrial
        return kind(self._rig_actions(), rig_tables()["default"], key[1], rig_seed)


def test_the_view_of_a_refused_trial_has_its_touches_before_the_refusal_and_no_answer(
    tmp_path,
    rig_model,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(evaluation_runner, "TrialContext", FirstOrSecondTouchContext)
    # The API's spec has the default tolerance: the engine run to compare with does too.
    engine = run_evaluation(rig_model, EvaluationSpec(**{**SPEC.__dict__, "tolerance": 1e-3}))
    assert [(r.key, r.touch) for r in engine.refused] == list(TOUCH_OF.items())
    ended, trials, details, _, _ = _api_evaluation(tmp_path, rig_model)
    assert ended["status"] == "completed", ended["reason"]
    views = {(d["policy"], d["target"], d["trial"]): d for d in details if d["refused"]}
    assert set(views) == set(REFUSED_KEYS)
    for expected in engine.refused:
        view = views[expected.key]
        touch = TOUCH_OF[expected.key]
        assert (view["correct"], view["answer"], view["stop_reason"]) == (False, None, "refused")
        assert view["touches"] == touch - 1
        assert view["refusal"] == {
            "touch": touch,
            "action": list(expected.action),
            "error": "ServoHardwareError",
            "reason": expected.reason,
        }
        assert "OVERLOAD" in view["refusal"]["reason"]
        # The record the page draws: the engine's refused trial, its touches before the refusal.
        record = view["record"]
        assert RefusedTrial.from_dict(record) == expected
        assert record["refused"] == view["refusal"]
        for field in ("answers", "probabilities", "actions", "mutual_information"):
            assert len(record[field]) == touch - 1, field
        assert view["objects"] == list(rig_model.object_names)
        for probabilities in record["probabilities"]:
            assert len(probabilities) == len(view["objects"])
            assert sum(probabilities) == pytest.approx(1.0, abs=1e-9)
        # The list row and the view agree.
        row = next(t for t in trials if t["number"] == view["number"])
        assert row["refusal"] == view["refusal"]
    # Completed trials' views are unchanged: an answer, no refusal.
    for view in details:
        if not view["refused"]:
            assert view["refusal"] is None
            assert view["answer"] == view["record"]["answers"][-1]
            assert view["touches"] == len(view["record"]["answers"]) >= 1
