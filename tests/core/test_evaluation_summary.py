"""Evaluation summaries against hand-computed values, and trial records round-tripping."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from core.errors import InvalidInputError
from core.evaluation.calibration import ece_if_calibrated
from core.evaluation.records import TrialRecord, trial_seed
from core.evaluation.summary import (
    calibration_summary,
    comparison_sentence,
    effective_trials,
    median_touches,
    summarise,
    touches_to_confidence,
    wilson_interval,
)

NAMES = ("A", "B", "C")


def record(
    target: str,
    answers: tuple[str, ...],
    top: tuple[float, ...],
    policy: str = "active",
    trial: int = 0,
) -> TrialRecord:
    """A record whose answer after each touch has probability ``top`` (rest split evenly)."""
    probabilities = []
    for answer, p in zip(answers, top, strict=True):
        rest = (1.0 - p) / 2
        probabilities.append(tuple(p if n == answer else rest for n in NAMES))
    n = len(answers)
    return TrialRecord(
        policy=policy,
        target=target,
        trial=trial,
        seed=trial_seed(0, target, trial),
        answers=answers,
        probabilities=tuple(probabilities),
        actions=tuple((0.1 * i,) for i in range(n)),
        mutual_information=tuple(0.5 for _ in range(n)),
        touches=n,
        stop_reason="max_steps" if n == 3 else "confident",
        correct=answers[-1] == target,
    )


@pytest.mark.parametrize(
    ("k", "n", "expected"),
    [
        # By hand: p̂ = 0.8, z² = 3.84146; centre 0.99207/1.38415 = 0.71674,
        # half-width 1.41600 · sqrt(0.016 + 0.0096037) = 0.22658.
        (8, 10, (0.49016, 0.94332)),
        # k = 0: [0, z²/(n + z²)] = [0, 3.84146/13.84146].
        (0, 10, (0.0, 0.27753)),
        (10, 10, (0.72247, 1.0)),
        (1, 1, (0.20654, 1.0)),
    ],
)
def test_wilson_interval_matches_hand_computed_values(k, n, expected):
    lo, hi = wilson_interval(k, n)
    assert lo == pytest.approx(expected[0], abs=5e-5)
    assert hi == pytest.approx(expected[1], abs=5e-5)


def test_wilson_interval_contains_the_proportion_and_rejects_bad_counts():
    for k in range(0, 21):
        lo, hi = wilson_interval(k, 20)
        assert 0.0 <= lo <= k / 20 <= hi <= 1.0
    with pytest.raises(InvalidInputError, match="successes=5, trials=4"):
        wilson_interval(5, 4)
    with pytest.raises(InvalidInputError):
        wilson_interval(0, 0)


def test_summary_carries_answers_forward_and_counts_confusion():
    records = [
        # Stops after 2 touches on the right answer: carried forward to touch 3.
        record("A", ("B", "A"), (0.6, 0.97), trial=0),
        record("A", ("A", "A", "A"), (0.5, 0.9, 0.96), trial=1),
        # Wrong at the end.
        record("B", ("B", "B", "C"), (0.7, 0.8, 0.6), trial=0),
        record("C", ("C",), (0.99,), trial=0),
    ]
    summary = summarise(records, NAMES, steps=3, confidence=0.95)["active"]
    # Touch 1: trial A1 wrong (B), A2 right, B right, C right → 3/4.
    # Touch 2: A1 right, A2 right, B right, C right (carried) → 4/4.
    # Touch 3: A1 right (carried), A2 right, B wrong, C right → 3/4.
    assert summary["accuracy_by_touch"] == [0.75, 1.0, 0.75]
    assert summary["accuracy_interval"][1] == pytest.approx(list(wilson_interval(4, 4)))
    assert summary["per_object"] == {
        "A": {"accuracy": 1.0, "trials": 2},
        "B": {"accuracy": 0.0, "trials": 1},
        "C": {"accuracy": 1.0, "trials": 1},
    }
    assert summary["confusion"] == {
        "A": {"A": 2, "B": 0, "C": 0},
        "B": {"A": 0, "B": 0, "C": 1},
        "C": {"A": 0, "B": 0, "C": 1},
    }
    # Touches to 0.95: A1 → 2, A2 → 3, B → never, C → 1; sorted 1, 2, 3, ∞ → median 2.5.
    assert summary["median_touches_to_confidence"] == 2.5
    assert summary["touches_to_accuracy"] == 2
    assert summary["trials"] == 4


def test_touches_to_confidence_uses_the_answers_probability():
    trial = record("A", ("B", "A", "A"), (0.96, 0.5, 0.97))
    # The answer B already has 0.96 after touch 1 (a confident wrong answer counts).
    assert touches_to_confidence(trial, NAMES, 0.95) == 1
    assert touches_to_confidence(trial, NAMES, 0.965) == 3
    assert touches_to_confidence(trial, NAMES, 0.99) is None


def test_median_touches_is_none_when_half_never_reach():
    assert median_touches([1, None]) is None
    assert median_touches([1, 3, None]) == 3.0
    assert median_touches([]) is None


def test_policies_are_summarised_apart_and_compared():
    records = [
        record("A", ("A", "A", "A"), (0.9, 0.9, 0.9), policy="active"),
        record("A", ("B", "B", "A"), (0.9, 0.9, 0.9), policy="passive"),
    ]
    summary = summarise(records, NAMES, steps=3, confidence=0.95)
    assert list(summary) == ["active", "passive"]
    assert summary["passive"]["accuracy_by_touch"] == [0.0, 0.0, 1.0]
    assert comparison_sentence(summary, 0.95) == (
        "active reaches 95 % accuracy after 1 touch, passive after 3 touches"
    )
    summary["passive"]["accuracy_by_touch"] = [0.0, 0.0, 0.5]
    assert comparison_sentence(summary, 0.95).endswith("passive does not within 3 touches")
    assert comparison_sentence({"passive": summary["passive"]}, 0.95) == (
        "passive does not reach 95 % accuracy within 3 touches"
    )


def test_summary_rejects_foreign_objects_and_long_trials():
    with pytest.raises(InvalidInputError, match=r"\['B'\] are not among"):
        summarise([record("B", ("A",), (0.9,))], ("A", "Z", "C"), 3, 0.95)
    with pytest.raises(InvalidInputError, match="fewer than the 3 touches"):
        summarise([record("A", ("A", "A", "A"), (0.9, 0.9, 0.9))], NAMES, 2, 0.95)
    with pytest.raises(InvalidInputError, match="at least one trial"):
        summarise([], NAMES, 3, 0.95)


def test_record_round_trips_through_json_exactly():
    original = record("B", ("A", "B", "B"), (0.4, 0.6, 0.9999999999999999))
    again = TrialRecord.from_dict(json.loads(json.dumps(original.to_dict())))
    assert again == original
    with pytest.raises(InvalidInputError, match="touches=2"):
        TrialRecord(**{**original.__dict__, "touches": 2})


def test_trial_seed_does_not_depend_on_the_policy_or_other_targets():
    assert trial_seed(7, "A", 3) == trial_seed(7, "A", 3)
    assert trial_seed(7, "A", 3) != trial_seed(7, "B", 3)
    assert trial_seed(7, "A", 3)[0] == 7


def test_calibration_by_hand_carries_an_early_stop_forward_like_accuracy():
    records = [
        # Sure and wrong at touch 1, stopped there: carried forward to touch 2.
        record("A", ("B",), (0.96,), trial=0),
        record("A", ("A", "A"), (0.5, 0.9), trial=1),
        record("B", ("B", "B"), (0.8, 0.99), trial=0),
    ]
    summary = summarise(records, NAMES, steps=2, confidence=0.95)["active"]
    calibration = summary["calibration"]
    everything = calibration["all_touches"]
    # Six answers: 0.96 ✗, 0.96 ✗ (carried), 0.5 ✓, 0.9 ✓, 0.8 ✓, 0.99 ✓.
    assert everything["answers"] == 6
    assert everything["accuracy"] == pytest.approx(4 / 6)
    assert everything["sure_and_wrong"] == {
        "threshold": 0.95,
        "sure": 3,
        "wrong": 2,
        "share_wrong": pytest.approx(2 / 3),
    }
    bins = {round(b["lower"], 1): b for b in everything["reliability"] if b["count"]}
    assert {k: b["count"] for k, b in bins.items()} == {0.5: 1, 0.8: 1, 0.9: 4}
    assert bins[0.9]["mean_confidence"] == pytest.approx(3.81 / 4)
    assert bins[0.9]["accuracy"] == 0.5
    # ECE = (1·|1 − 0.5| + 1·|1 − 0.8| + 4·|0.5 − 0.9525|) / 6.
    assert everything["ece"] == pytest.approx(2.51 / 6)
    # Brier per answer: 1.8824 twice, 0.375, 0.015, 0.06, 0.00015.
    assert everything["brier"] == pytest.approx(4.21495 / 6)
    # −log p(true): −log 0.02 twice, −log 0.5, −log 0.9, −log 0.8, −log 0.99.
    expected = -(2 * math.log(0.02) + math.log(0.5 * 0.9 * 0.8 * 0.99)) / 6
    assert everything["log_loss"] == pytest.approx(expected)
    # At T: 0.96 ✗ (carried), 0.9 ✓, 0.99 ✓.
    final = calibration["final"]
    assert final["answers"] == 3
    assert final["sure_and_wrong"]["sure"] == 2
    assert final["sure_and_wrong"]["wrong"] == 1
    # By touch: the accuracy is accuracy by touch; touch 1 is 0.96 ✗, 0.5 ✓, 0.8 ✓.
    by_touch = calibration["by_touch"]
    assert [t["accuracy"] for t in by_touch] == pytest.approx(summary["accuracy_by_touch"])
    assert by_touch[0]["ece"] == pytest.approx((0.5 + 0.2 + 0.96) / 3)
    assert by_touch[0]["sure_and_wrong"]["sure"] == 1
    assert by_touch[0]["sure_and_wrong"]["wrong"] == 1
    assert "reliability" not in by_touch[0]


def test_calibration_scores_the_answer_given_not_the_most_probable():
    # The answer after the touch is A (the nearest-latent rule) at p = 0.3, while B has 0.4.
    trial = TrialRecord(
        policy="active",
        target="A",
        trial=0,
        seed=trial_seed(0, "A", 0),
        answers=("A",),
        probabilities=((0.3, 0.4, 0.3),),
        actions=((0.0,),),
        mutual_information=(0.1,),
        touches=1,
        stop_reason="max_steps",
        correct=True,
    )
    final = calibration_summary([trial], NAMES, 1, 0.95)["final"]
    assert final["accuracy"] == 1.0
    [used] = [b for b in final["reliability"] if b["count"]]
    assert used["mean_confidence"] == pytest.approx(0.3)


def test_calibration_summary_rejects_what_it_cannot_score():
    with pytest.raises(InvalidInputError, match="at least one trial"):
        calibration_summary([], NAMES, 3, 0.95)
    with pytest.raises(InvalidInputError, match="fewer than the 3 touches"):
        calibration_summary([record("A", ("A", "A", "A"), (0.9, 0.9, 0.9))], NAMES, 2, 0.95)
    with pytest.raises(InvalidInputError, match=r"\['B'\] are not among"):
        calibration_summary([record("B", ("A",), (0.9,))], ("A", "Z", "C"), 3, 0.95)
    with pytest.raises(InvalidInputError, match="threshold"):
        calibration_summary([record("A", ("A",), (0.9,))], NAMES, 1, 1.5)


def test_effective_trials_is_kish_for_shared_evidence():
    # (Σ n_c)² / Σ n_c²: three trials on one key and one alone → 16 / (9 + 1).
    assert effective_trials(["a", "a", "a", "b"]) == pytest.approx(1.6)
    assert effective_trials(["a", "b", "c"]) == 3.0
    assert effective_trials(["a"] * 5) == 1.0
    with pytest.raises(InvalidInputError, match="at least one"):
        effective_trials([])


def test_wilson_interval_on_an_effective_sample_size():
    # By hand: p̂ = 1.2/1.6 = 0.75, 1 + z²/n = 3.40091, centre (0.75 + 1.20046)/3.40091 = 0.57351,
    # half-width 0.57630 · sqrt(0.117188 + 0.375143) = 0.40437.
    assert wilson_interval(1.2, 1.6) == pytest.approx((0.16914, 0.97788), abs=1e-5)


def _replayed(first: tuple[float, ...], top: float, answer: str, trial: int) -> TrialRecord:
    """A two-touch trial of A whose first touch is the recorded touch at ``first``."""
    second = (0.5 + 0.01 * trial,)
    probabilities = tuple(
        tuple(p if n == a else (1.0 - p) / 2 for n in NAMES)
        for a, p in ((answer, top), ("A", 0.9 + 0.001 * trial))
    )
    return TrialRecord(
        policy="active",
        target="A",
        trial=trial,
        seed=trial_seed(0, "A", trial),
        answers=(answer, "A"),
        probabilities=probabilities,
        actions=(first, second),
        mutual_information=(0.5, 0.5),
        touches=2,
        stop_reason="max_steps",
        correct=True,
    )


def test_trials_sharing_recorded_touches_count_once_in_the_interval():
    # Replay: three trials start with the same recorded touch (same action, same posterior:
    # all answer B), one with another (answers A); their second touches all differ.
    records = [_replayed((0.3,), 0.7, "B", t) for t in range(3)]
    records.append(_replayed((0.8,), 0.8, "A", 3))
    summary = summarise(records, NAMES, steps=2, confidence=0.95)["active"]
    assert summary["accuracy_by_touch"] == [0.25, 1.0]
    assert summary["effective_trials"] == pytest.approx([1.6, 4.0])
    assert summary["accuracy_interval"][0] == pytest.approx(list(wilson_interval(0.4, 1.6)))
    assert summary["accuracy_interval"][1] == pytest.approx(list(wilson_interval(4, 4)))
    # Four trials with the same first action but fresh observations (other posteriors), as
    # on the rig: four observations.
    fresh = [_replayed((0.3,), 0.6 + 0.01 * t, "B" if t else "A", t) for t in range(4)]
    summary = summarise(fresh, NAMES, steps=2, confidence=0.95)["active"]
    assert summary["effective_trials"] == [4.0, 4.0]
    assert summary["accuracy_interval"][0] == pytest.approx(list(wilson_interval(1, 4)))


def test_trials_sharing_recorded_touches_are_one_event_in_the_ece_null():
    """The ECE a calibrated recogniser would show draws one outcome per evidence: the three
    replay trials that took the same first touch share it, the fourth has its own; the second
    touches all differ. A trial stopped early carries one answer forward: one event too."""
    records = [_replayed((0.3,), 0.7, "B", t) for t in range(3)]
    records.append(_replayed((0.8,), 0.8, "A", 3))
    scored = summarise(records, NAMES, steps=2, confidence=0.95)["active"]["calibration"]
    first = [0.7, 0.7, 0.7, 0.8]
    grouped = ece_if_calibrated(np.array(first), groups=[0, 0, 0, 1])
    assert grouped != ece_if_calibrated(np.array(first))
    assert scored["by_touch"][0]["ece_if_calibrated"] == {"mean": grouped[0], "p95": grouped[1]}
    second = [0.9 + 0.001 * t for t in range(4)]
    apart = ece_if_calibrated(np.array(second))
    assert scored["by_touch"][1]["ece_if_calibrated"] == {"mean": apart[0], "p95": apart[1]}
    every = ece_if_calibrated(
        np.array([0.7, 0.9, 0.7, 0.901, 0.7, 0.902, 0.8, 0.903]), groups=[0, 1, 0, 2, 0, 3, 4, 5]
    )
    assert scored["all_touches"]["ece_if_calibrated"] == {"mean": every[0], "p95": every[1]}
    stopped = summarise([record("A", ("B",), (0.96,))], NAMES, steps=3, confidence=0.95)
    carried = ece_if_calibrated(np.full(3, 0.96), groups=[0, 0, 0])
    assert stopped["active"]["calibration"]["all_touches"]["ece_if_calibrated"] == {
        "mean": carried[0],
        "p95": carried[1],
    }
