"""bench/trust_acceptance.py's verdicts on hand-made reports: every criterion is there, each
can fail, and the per-touch table reads what the report holds."""

from __future__ import annotations

import copy
from typing import Any

import pytest

from bench.trust_acceptance import (
    POLICIES,
    assess,
    confidence_gaps,
    pooled_report,
    session_lines,
    touch_table,
)
from core.evaluation.calibration import calibration
from core.evaluation.records import TrialRecord
from core.evaluation.summary import summarise


def policy(
    curve: list[float], ece: float = 0.02, sure: int = 100, wrong: int = 2
) -> dict[str, Any]:
    """A policy's summary as activetouch-evaluation/2 gives it (the fields the bench reads)."""
    scored = {"ece": ece, "sure_and_wrong": {"threshold": 0.95, "sure": sure, "wrong": wrong}}
    return {
        "trials": 200,
        "accuracy_by_touch": curve,
        "accuracy_interval": [[max(0.0, a - 0.05), min(1.0, a + 0.05)] for a in curve],
        "calibration": {"all_touches": scored, "by_touch": [scored] * len(curve)},
    }


def report(world: str, **curves: list[float]) -> dict[str, Any]:
    return {
        "world": world,
        "trials_per_target": 50,
        "steps": 6,
        "seconds": 1.0,
        "workers": 2,
        "policies": {name: policy(list(curve)) for name, curve in curves.items()},
    }


GOOD = {"active": [0.7, 0.9, 0.95, 0.97, 0.98, 0.98],
        "discriminative": [0.75, 0.92, 0.96, 0.97, 0.98, 0.99],
        "passive": [0.5, 0.6, 0.7, 0.75, 0.8, 0.85]}  # fmt: skip


def documents() -> dict[str, dict[str, Any]]:
    return {world: report(world, **GOOD) for world in ("rig", "model", "replay")}


def test_a_run_that_meets_every_criterion_passes_them_all() -> None:
    criteria = assess(documents(), cushions=True)
    assert all(c.passed for c in criteria), [c.line() for c in criteria if not c.passed]
    names = " | ".join(c.name for c in criteria)
    for asked in (
        "rig: of the answers with p ≥ 0.95, ≥ 95 % right",
        "rig: ECE ≤ 0.05",
        "rig: active and discriminative never below passive",
        "≥ 90 % right at T",
        "≥ 15 points ahead of passive at some touch ≤ 5",
        "model vs rig within 10 points at T",
        "replay: active never below passive",
        "replay: of the answers with p ≥ 0.95",
        "replay: ECE ≤ 0.05",
    ):
        assert asked in names
    # Not the cushions: their two criteria are left out.
    assert len(assess(documents(), cushions=False)) == len(criteria) - 2


def failed(changed: dict[str, dict[str, Any]], cushions: bool = True) -> list[str]:
    return [c.name for c in assess(changed, cushions) if not c.passed]


def test_each_criterion_fails_when_its_figure_is_violated() -> None:
    # 6 of 100 sure answers wrong on the rig (the limit is 5 %).
    sure = documents()
    sure["rig"]["policies"]["passive"]["calibration"]["all_touches"]["sure_and_wrong"]["wrong"] = 6
    assert failed(sure) == ["rig: of the answers with p ≥ 0.95, ≥ 95 % right, every policy"]
    # ECE 0.051 on replay.
    ece = documents()
    ece["replay"]["policies"]["active"]["calibration"]["all_touches"]["ece"] = 0.051
    assert failed(ece) == ["replay: ECE ≤ 0.05, every policy"]
    # Discriminative's interval below passive's at touch 1 on the rig.
    below = documents()
    below["rig"]["policies"]["discriminative"]["accuracy_interval"][0] = [0.2, 0.3]
    assert failed(below) == [
        "rig: active and discriminative never below passive beyond the 95 % intervals"
    ]
    # Active 87 % at T on the cushions (also 11 points from the model world's 98 %).
    low = documents()
    low["rig"]["policies"]["active"]["accuracy_by_touch"][-1] = 0.87
    assert failed(low) == [
        "rig (cushions): active and discriminative ≥ 90 % right at T",
        "model vs rig within 10 points at T, every policy",
    ]
    assert failed(low, cushions=False) == ["model vs rig within 10 points at T, every policy"]
    # Passive close behind: the lead is 14 points at best.
    close = documents()
    close["rig"]["policies"]["passive"]["accuracy_by_touch"] = [
        a - 0.14 for a in GOOD["discriminative"]
    ]
    close["rig"]["policies"]["active"]["accuracy_by_touch"] = list(GOOD["discriminative"])
    assert failed(close) == [
        "rig (cushions): active and discriminative ≥ 15 points ahead of passive at some touch ≤ 5"
    ]
    # Active below passive on replay, beyond the intervals.
    replay = documents()
    replay["replay"]["policies"]["active"]["accuracy_interval"][3] = [0.4, 0.6]
    assert failed(replay) == ["replay: active never below passive beyond the 95 % intervals"]


def test_a_missing_world_or_policy_is_named() -> None:
    partial = documents()
    del partial["replay"]
    with pytest.raises(ValueError, match="replay"):
        assess(partial, cushions=False)
    no_passive = copy.deepcopy(documents())
    del no_passive["rig"]["policies"]["passive"]
    with pytest.raises(ValueError, match="no policy 'passive'"):
        assess(no_passive, cushions=False)


def test_the_touch_table_shows_every_policy_and_touch() -> None:
    lines = touch_table(report("rig", **GOOD))
    assert sum(line.strip().startswith("touch ") for line in lines) == 6 * len(POLICIES)
    assert "    touch 1:  70.0 % ( 65.0– 75.0)  ECE 0.020  sure & wrong 2/100" in lines


OBJECTS = ["cup", "mug"]


def trial(policy: str, target: str, trial: int, sure_of: list[str], p: float) -> dict[str, Any]:
    """A two-touch replay trial whose answer after each touch is ``sure_of[t]`` with
    probability ``p`` (the other object gets 1 - p)."""
    probabilities = [[p, 1 - p] if a == "cup" else [1 - p, p] for a in sure_of]
    return TrialRecord(
        policy=policy,
        target=target,
        trial=trial,
        seed=(0, trial),
        answers=tuple(sure_of),
        probabilities=tuple(tuple(row) for row in probabilities),
        actions=((0.1 * trial, float(len(policy))), (0.2 * trial, 1.0)),
        mutual_information=(0.1, 0.1),
        touches=2,
        stop_reason="max_steps",
        correct=sure_of[-1] == target,
    ).to_dict()


def session(trials: list[dict[str, Any]], seconds: float = 2.0) -> dict[str, Any]:
    """A replay report as activetouch evaluate writes it: its trials and their summary."""
    records = [TrialRecord.from_dict(t) for t in trials]
    return {
        "policies": summarise(records, OBJECTS, 2, 0.95),
        "world": "replay",
        "objects": OBJECTS,
        "steps": 2,
        "confidence": 0.95,
        "trials_per_target": 1,
        "seconds": seconds,
        "workers": 2,
        "trials": trials,
    }


def test_sessions_pool_into_one_replay_report() -> None:
    # Session 1: every policy right on the cup at p = 0.99 after both touches. Session 2: every
    # policy wrong on the mug (sure of the cup at p = 0.99 after both touches).
    first = session([trial(pol, "cup", 0, ["cup", "cup"], 0.99) for pol in POLICIES])
    second = session([trial(pol, "mug", 1, ["cup", "cup"], 0.99) for pol in POLICIES], seconds=3.0)
    pooled = pooled_report([first, second])
    assert (pooled["sessions"], pooled["trials_per_target"]) == (2, 2)
    assert (pooled["seconds"], pooled["steps"]) == (5.0, 2)
    for policy in POLICIES:
        summary = pooled["policies"][policy]
        assert summary["trials"] == 2
        assert summary["accuracy_by_touch"] == [0.5, 0.5]
        scored = summary["calibration"]["all_touches"]
        # Four answers at p = 0.99, two right: sure and wrong 2 of 4; ECE |0.5 - 0.99|.
        assert (scored["sure_and_wrong"]["sure"], scored["sure_and_wrong"]["wrong"]) == (4, 2)
        assert scored["ece"] == pytest.approx(0.49)
    # The pooled report is judged and printed like one session's.
    lines = touch_table(pooled)
    assert lines[0].startswith("world replay (2 sessions pooled): 2 trials per target")
    assert assess({"rig": pooled, "model": pooled, "replay": pooled}, cushions=False)
    assert session_lines([first, second])[1].startswith(
        "  session 2: active 0 → 0.0 %, ECE 0.990, 2/2"
    )


def test_sessions_of_different_models_do_not_pool() -> None:
    first = session([trial("active", "cup", 0, ["cup", "cup"], 0.9)])
    other = session([trial("active", "cup", 0, ["cup", "cup"], 0.9)])
    other["objects"] = ["cup", "bowl"]
    with pytest.raises(ValueError, match="differ in 'objects'"):
        pooled_report([first, other])
    with pytest.raises(ValueError, match="at least one"):
        pooled_report([])
    without_trials = {**first, "trials": []}
    with pytest.raises(ValueError, match="hold no trials"):
        pooled_report([without_trials])


def test_the_ece_splits_into_over_and_under_confidence() -> None:
    # Bin 0.7-0.8: stated 0.75, right 3 of 4 (0.75); bin 0.9-1.0: stated 0.95, right 1 of 2;
    # bin 0.5-0.6: stated 0.55, right 2 of 2. Over: 2/8 · 0.45; under: 2/8 · 0.45.
    p = [0.75, 0.75, 0.75, 0.75, 0.95, 0.95, 0.55, 0.55]
    right = [1, 1, 1, 0, 1, 0, 1, 1]
    probabilities = [[q, 1 - q] for q in p]
    labels = [0 if r else 1 for r in right]
    scored = calibration(probabilities, labels, 0.95).to_dict()
    gaps = confidence_gaps(scored)
    assert gaps is not None
    assert gaps == pytest.approx((2 / 8 * 0.45, 2 / 8 * 0.45))
    assert sum(gaps) == pytest.approx(scored["ece"])
    assert confidence_gaps({"ece": 0.02}) is None  # a summary without bins
