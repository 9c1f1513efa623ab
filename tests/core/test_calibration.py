"""Calibration measures against values computed by hand."""

from __future__ import annotations

import math

import numpy as np
import pytest

from core.errors import InvalidInputError
from core.evaluation.calibration import (
    answer_confidence,
    brier_score,
    calibration,
    ece_if_calibrated,
    expected_calibration_error,
    log_loss,
    reliability_table,
    sure_and_wrong,
)

# Four answers over three objects (truth: 0, 1, 2, 0).
P = np.array(
    [
        [0.7, 0.2, 0.1],  # answer 0, right, confidence 0.7
        [0.5, 0.4, 0.1],  # answer 0, wrong (truth 1), confidence 0.5
        [0.05, 0.0, 0.95],  # answer 2, right, confidence 0.95
        [0.02, 0.96, 0.02],  # answer 1, wrong (truth 0), confidence 0.96
    ]
)
Y = np.array([0, 1, 2, 0])


def test_answer_confidence_is_the_probability_of_the_answer() -> None:
    confidence, correct = answer_confidence(P, Y)
    np.testing.assert_allclose(confidence, [0.7, 0.5, 0.95, 0.96])
    assert correct.tolist() == [True, False, True, False]
    # A given answer (the second row answered 1) takes its own probability.
    confidence, correct = answer_confidence(P, Y, answers=np.array([0, 1, 2, 1]))
    np.testing.assert_allclose(confidence, [0.7, 0.4, 0.95, 0.96])
    assert correct.tolist() == [True, True, True, False]


def test_reliability_table_by_hand() -> None:
    confidence, correct = answer_confidence(P, Y)
    table = reliability_table(confidence, correct, n_bins=10)
    assert len(table) == 10
    counts = [b.count for b in table]
    # 0.5 → bin [0.5, 0.6); 0.7 → [0.7, 0.8); 0.95 and 0.96 → [0.9, 1.0].
    assert counts == [0, 0, 0, 0, 0, 1, 0, 1, 0, 2]
    last = table[9]
    assert last.mean_confidence == pytest.approx(0.955)
    assert last.accuracy == pytest.approx(0.5)
    assert table[5].accuracy == 0.0
    assert table[0].accuracy is None
    assert table[0].mean_confidence is None


def test_bin_edges_are_half_open_and_one_is_in_the_last_bin() -> None:
    confidence = np.array([0.3, 0.7, 1.0, 0.0, 0.1 * 3])
    table = reliability_table(confidence, np.ones(5, dtype=bool), n_bins=10)
    counts = [b.count for b in table]
    assert counts == [1, 0, 0, 2, 0, 0, 0, 1, 0, 1]


def test_ece_by_hand() -> None:
    confidence, correct = answer_confidence(P, Y)
    # Bins: {0.5: wrong} |0 - 0.5| = 0.5; {0.7: right} |1 - 0.7| = 0.3;
    # {0.95 right, 0.96 wrong} |0.5 - 0.955| = 0.455.  ECE = (0.5 + 0.3 + 2 * 0.455) / 4.
    expected = (0.5 + 0.3 + 2 * 0.455) / 4
    assert expected_calibration_error(confidence, correct) == pytest.approx(expected)


def test_ece_is_zero_when_stated_equals_observed() -> None:
    # Ten answers at 0.8, eight of them right: perfectly calibrated.
    confidence = np.full(10, 0.8)
    correct = np.array([True] * 8 + [False] * 2)
    assert expected_calibration_error(confidence, correct) == pytest.approx(0.0)


def test_brier_by_hand() -> None:
    rows = [
        (0.3**2 + 0.2**2 + 0.1**2),
        (0.5**2 + 0.6**2 + 0.1**2),
        (0.05**2 + 0.0 + 0.05**2),
        (0.98**2 + 0.96**2 + 0.02**2),
    ]
    assert brier_score(P, Y) == pytest.approx(sum(rows) / 4)


def test_brier_of_a_uniform_posterior_is_one_minus_one_over_l() -> None:
    uniform = np.full((5, 4), 0.25)
    assert brier_score(uniform, np.array([0, 1, 2, 3, 0])) == pytest.approx(0.75)


def test_log_loss_by_hand_and_its_floor() -> None:
    expected = -(math.log(0.7) + math.log(0.4) + math.log(0.95) + math.log(0.02)) / 4
    assert log_loss(P, Y) == pytest.approx(expected)
    ruled_out = np.array([[1.0, 0.0]])
    assert log_loss(ruled_out, np.array([1]), floor=1e-15) == pytest.approx(-math.log(1e-15))


def test_sure_and_wrong_by_hand() -> None:
    confidence, correct = answer_confidence(P, Y)
    result = sure_and_wrong(confidence, correct, threshold=0.95)
    assert (result.sure, result.wrong) == (2, 1)
    assert result.share_wrong == pytest.approx(0.5)
    none = sure_and_wrong(confidence, correct, threshold=0.99)
    assert none.sure == 0
    assert none.share_wrong is None


def test_calibration_collects_every_measure_and_is_json_ready() -> None:
    result = calibration(P, Y, threshold=0.95)
    assert result.answers == 4
    assert result.accuracy == pytest.approx(0.5)
    assert result.ece == pytest.approx((0.5 + 0.3 + 2 * 0.455) / 4)
    assert result.brier == pytest.approx(brier_score(P, Y))
    assert result.log_loss == pytest.approx(log_loss(P, Y))
    d = result.to_dict()
    assert d["sure_and_wrong"] == {"threshold": 0.95, "sure": 2, "wrong": 1, "share_wrong": 0.5}
    assert len(d["reliability"]) == 10
    mean, p95 = ece_if_calibrated(np.array([0.7, 0.5, 0.95, 0.96]))
    assert d["ece_if_calibrated"] == {"mean": mean, "p95": p95}


def test_calibration_of_no_answers_has_no_measures() -> None:
    result = calibration(np.zeros((0, 3)), np.zeros(0, dtype=int), threshold=0.9)
    assert result.answers == 0
    assert result.accuracy is None
    assert result.ece is None
    assert result.brier is None
    assert result.log_loss is None
    assert result.ece_if_calibrated is None
    assert result.to_dict()["ece_if_calibrated"] is None


def _labels_from_own_posterior(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """n random posteriors over 4 objects (softmax of N(0, 2²) logits) and a label drawn from
    each: answers whose stated probabilities are calibrated by construction."""
    rng = np.random.default_rng(seed)
    logits = rng.normal(scale=2.0, size=(n, 4))
    p = np.exp(logits - logits.max(axis=1, keepdims=True))
    p /= p.sum(axis=1, keepdims=True)
    return p, np.array([rng.choice(4, p=row) for row in p])


def test_sampled_from_its_own_probabilities_a_posterior_is_calibrated() -> None:
    # Labels drawn from the stated posterior: the ECE must shrink to binning error.
    p, labels = _labels_from_own_posterior(20000, seed=0)
    result = calibration(p, labels, threshold=0.95)
    assert result.ece is not None
    assert result.ece < 0.02
    overconfident = p**3 / np.sum(p**3, axis=1, keepdims=True)
    assert calibration(overconfident, labels, threshold=0.95).ece > 0.1  # type: ignore[operator]


@pytest.mark.parametrize(
    ("probabilities", "labels", "message"),
    [
        (np.array([0.5, 0.5]), np.array([0]), "shape"),
        (np.array([[0.5, 0.6]]), np.array([0]), "sums to"),
        (np.array([[np.nan, 1.0]]), np.array([0]), "finite"),
        (np.array([[0.5, 0.5]]), np.array([2]), "0..1"),
        (np.array([[0.5, 0.5]]), np.array([0.0]), "integers"),
        (np.array([[0.5, 0.5]]), np.array([0, 1]), "shape"),
    ],
)
def test_bad_input_names_what_is_wrong(
    probabilities: np.ndarray, labels: np.ndarray, message: str
) -> None:
    with pytest.raises(InvalidInputError, match=message):
        calibration(probabilities, labels, threshold=0.95)


def test_bad_threshold_and_bins() -> None:
    with pytest.raises(InvalidInputError, match="threshold"):
        sure_and_wrong(np.array([0.5]), np.array([True]), threshold=0.0)
    with pytest.raises(InvalidInputError, match="n_bins"):
        reliability_table(np.array([0.5]), np.array([True]), n_bins=0)
    with pytest.raises(InvalidInputError, match=r"\[0, 1\]"):
        reliability_table(np.array([1.5]), np.array([True]))


def test_ece_if_calibrated_by_hand() -> None:
    """Certain answers have no sampling noise; n answers at p = ½ in one bin have
    E|S − n/2| / n with S ~ Binomial(n, ½), computed exactly here."""
    assert ece_if_calibrated(np.ones(7)) == (0.0, 0.0)
    assert ece_if_calibrated(np.zeros(7)) == (0.0, 0.0)
    n = 20
    exact = sum(math.comb(n, k) * abs(k - n / 2) for k in range(n + 1)) / 2**n / n
    mean, p95 = ece_if_calibrated(np.full(n, 0.5), draws=40000)
    assert mean == pytest.approx(exact, abs=0.003)  # the draws' standard error is ~0.0004
    assert exact < p95 <= 0.25
    # Two bins add their noises: answers at 0.45 and 0.55 (bins 4 and 5) separately.
    split, _ = ece_if_calibrated(np.repeat([0.45, 0.55], n // 2), draws=40000)
    assert split > mean


def test_ece_if_calibrated_is_deterministic_and_shrinks_with_more_answers() -> None:
    rng = np.random.default_rng(1)
    few = rng.uniform(0.3, 1.0, 240)
    assert ece_if_calibrated(few) == ece_if_calibrated(few)
    assert ece_if_calibrated(few, seed=1) != ece_if_calibrated(few)
    many = np.tile(few, 25)
    assert ece_if_calibrated(many)[0] < 0.4 * ece_if_calibrated(few)[0]
    with pytest.raises(InvalidInputError, match="draws"):
        ece_if_calibrated(few, draws=0)
    with pytest.raises(InvalidInputError, match="confidence"):
        ece_if_calibrated(np.array([1.5]))


def test_answers_on_the_same_evidence_are_one_event_in_the_null() -> None:
    """Two answers at p = ½ in one bin: drawn apart, the bin's excess is ±1 with probability ¼
    each and 0 with ½ (ECE ½ or 0, mean ¼); as one event both are right or both wrong, every
    draw's ECE is exactly ½. k copies of a set of answers weigh like one copy, draw for draw."""
    half = np.full(2, 0.5)
    assert ece_if_calibrated(half, groups=["a", "a"]) == (0.5, 0.5)
    apart, _ = ece_if_calibrated(half, draws=40000)
    assert apart == pytest.approx(0.25, abs=0.01)
    # Distinct labels in any order are the ungrouped draws.
    few = np.random.default_rng(3).uniform(0.3, 1.0, 60)
    assert ece_if_calibrated(few, groups=[f"t{i}" for i in range(60)]) == ece_if_calibrated(few)
    copies = np.tile(few, 4)
    labels = [i % 60 for i in range(240)]
    assert ece_if_calibrated(copies, groups=labels) == pytest.approx(
        ece_if_calibrated(few), rel=1e-12
    )
    assert ece_if_calibrated(copies)[1] < ece_if_calibrated(few)[1]
    with pytest.raises(InvalidInputError, match="groups"):
        ece_if_calibrated(few, groups=[0, 1])
    result = calibration(np.array([[0.5, 0.5], [0.5, 0.5]]), [0, 0], 0.95, groups=["a", "a"])
    assert result.ece_if_calibrated == (0.5, 0.5)


def test_a_calibrated_recogniser_lies_within_its_sampling_noise() -> None:
    """Labels drawn from the stated posteriors: the observed ECE is of the size of the null's
    mean, and an overconfident posterior of the same answers lies far above its 95th
    percentile."""
    p, labels = _labels_from_own_posterior(240, seed=2)
    result = calibration(p, labels, threshold=0.95)
    assert result.ece is not None
    assert result.ece_if_calibrated is not None
    assert result.ece <= result.ece_if_calibrated[1]
    overconfident = p**4 / np.sum(p**4, axis=1, keepdims=True)
    sharp = calibration(overconfident, labels, threshold=0.95)
    assert sharp.ece is not None
    assert sharp.ece_if_calibrated is not None
    assert sharp.ece > 2 * sharp.ece_if_calibrated[1]
