"""How honest a stated probability is: reliability, ECE, Brier score, log-loss, sure-and-wrong.

A recogniser answers with an object and a probability (its object posterior). Accuracy alone says
how often the answer was right; calibration says whether the probability can be trusted: of the
answers given with p ≈ 0.9, about 90 % should be right. The measures here are the standard ones
(Guo et al. 2017, "On calibration of modern neural networks", for the reliability diagram and
the expected calibration error; Brier 1950 for the multi-class Brier score), computed over any
set of answers — in an evaluation, one per (trial, touch). See docs/method.md, "Calibration and
model error".

All functions are pure and take arrays:

* ``probabilities``: the object posterior of each answer, shape (n, L), rows summing to 1;
* ``labels``: the index of the true object of each answer, shape (n,), in 0..L-1;
* ``answers`` (optional): the index of the object answered, shape (n,); by default the most
  probable object of each row. The *confidence* of an answer is the probability it was given.
"""

from __future__ import annotations

from collections.abc import Hashable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from core.errors import InvalidInputError
from core.validation import FloatArray

IntArray = npt.NDArray[np.int64]

#: Bins of the reliability table unless told otherwise: ten of width 0.1.
DEFAULT_BINS = 10

#: Tolerance on the sum of each probability row.
_ROW_SUM_TOLERANCE = 1e-6


def _checked(
    probabilities: FloatArray, labels: npt.ArrayLike, answers: npt.ArrayLike | None
) -> tuple[FloatArray, IntArray, IntArray]:
    """Validate the inputs and return (probabilities (n, L), labels (n,), answers (n,))."""
    p = np.asarray(probabilities, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] < 1:
        raise InvalidInputError(
            f"probabilities: expected shape (n, L) with L ≥ 1, received {p.shape}."
        )
    n, n_objects = p.shape
    if not np.all(np.isfinite(p)) or np.any(p < 0.0):
        raise InvalidInputError("probabilities: every entry must be finite and ≥ 0.")
    sums = p.sum(axis=1)
    bad = np.flatnonzero(np.abs(sums - 1.0) > _ROW_SUM_TOLERANCE)
    if bad.size:
        raise InvalidInputError(
            f"probabilities: row {int(bad[0])} sums to {float(sums[bad[0]]):.6g}, not 1."
        )
    y = _indices(labels, "labels", n, n_objects)
    a = (
        np.argmax(p, axis=1).astype(np.int64)
        if answers is None
        else _indices(answers, "answers", n, n_objects)
    )
    return p, y, a


def _indices(values: npt.ArrayLike, name: str, n: int, n_objects: int) -> IntArray:
    raw = np.asarray(values)
    if raw.shape != (n,):
        raise InvalidInputError(f"{name}: expected shape ({n},), received {raw.shape}.")
    if n and not np.issubdtype(raw.dtype, np.integer):
        raise InvalidInputError(f"{name}: expected object indices (integers), got {raw.dtype}.")
    idx = raw.astype(np.int64)
    if n and (idx.min() < 0 or idx.max() >= n_objects):
        raise InvalidInputError(f"{name}: indices must lie in 0..{n_objects - 1}.")
    return idx


def answer_confidence(
    probabilities: FloatArray, labels: npt.ArrayLike, answers: npt.ArrayLike | None = None
) -> tuple[FloatArray, npt.NDArray[np.bool_]]:
    """The probability each answer was given, and whether it was right.

    Returns:
        ``(confidence, correct)``, both shape (n,).
    """
    p, y, a = _checked(probabilities, labels, answers)
    return p[np.arange(p.shape[0]), a], a == y


@dataclass(frozen=True)
class ReliabilityBin:
    """One bin of stated probability [lower, upper) (the last bin includes 1).

    Attributes:
        lower: Lower edge of the bin.
        upper: Upper edge of the bin.
        count: Answers whose confidence fell in the bin.
        mean_confidence: Their mean stated probability (``None`` when the bin is empty).
        accuracy: The share of them that were right (``None`` when the bin is empty).
    """

    lower: float
    upper: float
    count: int
    mean_confidence: float | None
    accuracy: float | None

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready."""
        return {
            "lower": self.lower,
            "upper": self.upper,
            "count": self.count,
            "mean_confidence": self.mean_confidence,
            "accuracy": self.accuracy,
        }


def reliability_table(
    confidence: FloatArray, correct: npt.ArrayLike, n_bins: int = DEFAULT_BINS
) -> tuple[ReliabilityBin, ...]:
    """Stated probability against observed accuracy, in ``n_bins`` equal-width bins.

    Args:
        confidence: Probability each answer was given. Shape (n,), in [0, 1].
        correct: Whether each answer was right. Shape (n,).
        n_bins: Number of bins of width 1 / n_bins.
    """
    c, ok = _confidence_and_correct(confidence, correct)
    if n_bins < 1:
        raise InvalidInputError(f"n_bins: must be ≥ 1, received {n_bins}.")
    which = _bin_index(c, n_bins)
    bins = []
    for b in range(n_bins):
        members = which == b
        count = int(members.sum())
        bins.append(
            ReliabilityBin(
                lower=b / n_bins,
                upper=(b + 1) / n_bins,
                count=count,
                mean_confidence=float(c[members].mean()) if count else None,
                accuracy=float(ok[members].mean()) if count else None,
            )
        )
    return tuple(bins)


def expected_calibration_error(
    confidence: FloatArray, correct: npt.ArrayLike, n_bins: int = DEFAULT_BINS
) -> float:
    """ECE = Σ_b (n_b / n) |accuracy_b − mean confidence_b| over equal-width bins.

    0 for a perfectly calibrated recogniser (up to binning); ``nan`` for no answers.
    """
    table = reliability_table(confidence, correct, n_bins)
    total = sum(b.count for b in table)
    if total == 0:
        return float("nan")
    return float(
        sum(
            b.count * abs(b.accuracy - b.mean_confidence)
            for b in table
            if b.accuracy is not None and b.mean_confidence is not None
        )
        / total
    )


#: Monte Carlo draws of :func:`ece_if_calibrated` (its 95th percentile moves by ~0.002 between
#: seeds at 240 answers with 400 draws).
NULL_DRAWS = 400


def ece_if_calibrated(
    confidence: FloatArray,
    n_bins: int = DEFAULT_BINS,
    draws: int = NULL_DRAWS,
    seed: int = 0,
    groups: Sequence[Hashable] | None = None,
) -> tuple[float, float]:
    """The ECE these stated probabilities would show by sampling alone, were they calibrated.

    Each answer is drawn right with exactly the probability it was given, independently, and the
    ECE of the draw is Σ_b |Σ_{i ∈ b} (right_i − p_i)| / n (the bins of
    :func:`expected_calibration_error`; the bins' mean confidences are the stated ones). A
    calibrated recogniser scored on n answers shows an ECE of about the draws' mean, not 0: at
    240 answers (40 trials of six touches) about 0.04, at 1,200 about 0.02. An observed ECE is
    evidence of miscalibration only where it lies above the draws' 95th percentile.

    Answers that rest on the same evidence (``groups``: replay trials that took the same
    recorded touches of the same target have one posterior and one answer) are one event, not
    several: one draw decides them all, so k copies of an answer weigh like one in the spread
    (docs/method.md, "Evaluation protocols"). The answers of one trial at successive touches are
    correlated too (one posterior, touch after touch), which no grouping describes: the figures
    stay a lower bound on the noise. The draws are seeded, so the figures are a deterministic
    function of the confidences and the groups.

    Args:
        confidence: Probability each answer was given. Shape (n,), in [0, 1].
        n_bins: Bins of width 1 / n_bins.
        draws: Monte Carlo draws.
        seed: Seed of the draws.
        groups: Evidence of each answer, any hashable labels; equal labels share one draw.
            Shape (n,). ``None``: every answer is its own (the same draws as all-distinct
            labels).

    Returns:
        (mean, 95th percentile) of the ECE over the draws; ``(nan, nan)`` for no answers.
    """
    c, _ = _confidence_and_correct(confidence, np.zeros(np.shape(confidence), dtype=bool))
    if n_bins < 1 or draws < 1:
        raise InvalidInputError(f"n_bins and draws: must be ≥ 1, received {n_bins} and {draws}.")
    if c.size == 0:
        return float("nan"), float("nan")
    event = _event_index(groups, c.size)
    members = np.zeros((c.size, n_bins))
    members[np.arange(c.size), _bin_index(c, n_bins)] = 1.0
    uniforms = np.random.default_rng(seed).random((draws, int(event.max()) + 1))
    outcomes = uniforms[:, event] < c  # (draws, n): one uniform per event
    excess = (outcomes - c) @ members  # Σ_{i ∈ b} (right_i − p_i), (draws, bins)
    values = np.abs(excess).sum(axis=1) / c.size
    return float(values.mean()), float(np.percentile(values, 95))


def brier_score(probabilities: FloatArray, labels: npt.ArrayLike) -> float:
    """Multi-class Brier score: the mean over answers of Σ_l (p_l − [l = true])².

    0 is perfect, 2 the worst possible; a uniform posterior over L objects scores 1 − 1/L.
    """
    p, y, _ = _checked(probabilities, labels, None)
    if p.shape[0] == 0:
        return float("nan")
    onehot = np.zeros_like(p)
    onehot[np.arange(p.shape[0]), y] = 1.0
    return float(np.mean(np.sum((p - onehot) ** 2, axis=1)))


def log_loss(probabilities: FloatArray, labels: npt.ArrayLike, floor: float = 1e-15) -> float:
    """Mean negative log probability of the true object, in nats.

    Probabilities below ``floor`` count as ``floor``, so one answer that ruled the truth out
    (p = 0 in floating point) costs −log(floor) ≈ 34.5 nats rather than infinity.
    """
    p, y, _ = _checked(probabilities, labels, None)
    if p.shape[0] == 0:
        return float("nan")
    return float(np.mean(-np.log(np.maximum(p[np.arange(p.shape[0]), y], floor))))


@dataclass(frozen=True)
class SureAndWrong:
    """Answers given with probability ≥ a threshold, and how many of them were wrong.

    Attributes:
        threshold: The confidence threshold.
        sure: Answers given with p ≥ threshold.
        wrong: Of those, the ones that were wrong.
    """

    threshold: float
    sure: int
    wrong: int

    @property
    def share_wrong(self) -> float | None:
        """wrong / sure, or ``None`` when no answer reached the threshold."""
        return self.wrong / self.sure if self.sure else None

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready."""
        return {
            "threshold": self.threshold,
            "sure": self.sure,
            "wrong": self.wrong,
            "share_wrong": self.share_wrong,
        }


def sure_and_wrong(
    confidence: FloatArray, correct: npt.ArrayLike, threshold: float
) -> SureAndWrong:
    """Count the answers given with p ≥ ``threshold`` and the wrong ones among them."""
    c, ok = _confidence_and_correct(confidence, correct)
    if not 0.0 < threshold <= 1.0:
        raise InvalidInputError(f"threshold: must lie in (0, 1], received {threshold}.")
    sure = c >= threshold
    return SureAndWrong(threshold=threshold, sure=int(sure.sum()), wrong=int((sure & ~ok).sum()))


@dataclass(frozen=True)
class Calibration:
    """Every calibration measure of one set of answers.

    Attributes:
        answers: Number of answers scored.
        accuracy: Share of them that were right.
        reliability: The reliability table.
        ece: Expected calibration error over :attr:`reliability`'s bins.
        brier: Multi-class Brier score of the object posterior.
        log_loss: Mean −log p(true object), nats.
        sure_and_wrong: Answers at or above the confidence threshold, and the wrong ones.
        ece_if_calibrated: The ECE these answers' stated probabilities would show by sampling
            alone were they calibrated (:func:`ece_if_calibrated`): its mean and 95th
            percentile, ``None`` for no answers.
    """

    answers: int
    accuracy: float | None
    reliability: tuple[ReliabilityBin, ...]
    ece: float | None
    brier: float | None
    log_loss: float | None
    sure_and_wrong: SureAndWrong
    ece_if_calibrated: tuple[float, float] | None = None

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready (no NaN: an empty set gives ``None`` measures)."""
        return {
            "answers": self.answers,
            "accuracy": self.accuracy,
            "reliability": [b.to_dict() for b in self.reliability],
            "ece": self.ece,
            "brier": self.brier,
            "log_loss": self.log_loss,
            "sure_and_wrong": self.sure_and_wrong.to_dict(),
            "ece_if_calibrated": None
            if self.ece_if_calibrated is None
            else {"mean": self.ece_if_calibrated[0], "p95": self.ece_if_calibrated[1]},
        }


def calibration(
    probabilities: FloatArray,
    labels: npt.ArrayLike,
    threshold: float,
    answers: npt.ArrayLike | None = None,
    n_bins: int = DEFAULT_BINS,
    groups: Sequence[Hashable] | None = None,
) -> Calibration:
    """All the measures at once.

    Args:
        probabilities: Object posterior behind each answer. Shape (n, L).
        labels: True object index of each answer. Shape (n,).
        threshold: Confidence threshold for "sure and wrong" (the stop rule's, typically).
        answers: Object index answered; by default the most probable. Shape (n,).
        n_bins: Bins of the reliability table.
        groups: The evidence each answer rests on (:func:`ece_if_calibrated`); ``None``: each
            answer its own.
    """
    confidence, correct = answer_confidence(probabilities, labels, answers)
    n = int(confidence.shape[0])

    def finite(value: float) -> float | None:
        return value if np.isfinite(value) else None

    return Calibration(
        answers=n,
        accuracy=float(correct.mean()) if n else None,
        reliability=reliability_table(confidence, correct, n_bins),
        ece=finite(expected_calibration_error(confidence, correct, n_bins)),
        brier=finite(brier_score(probabilities, labels)),
        log_loss=finite(log_loss(probabilities, labels)),
        sure_and_wrong=sure_and_wrong(confidence, correct, threshold),
        ece_if_calibrated=ece_if_calibrated(confidence, n_bins, groups=groups) if n else None,
    )


def _confidence_and_correct(
    confidence: FloatArray, correct: npt.ArrayLike
) -> tuple[FloatArray, npt.NDArray[np.bool_]]:
    c = np.asarray(confidence, dtype=np.float64)
    ok = np.asarray(correct)
    if c.ndim != 1 or ok.shape != c.shape:
        raise InvalidInputError(
            f"confidence and correct: expected two arrays of shape (n,), received {c.shape} "
            f"and {ok.shape}."
        )
    if not np.all(np.isfinite(c)) or np.any((c < 0.0) | (c > 1.0)):
        raise InvalidInputError("confidence: every entry must lie in [0, 1].")
    return c, ok.astype(bool)


def _event_index(groups: Sequence[Hashable] | None, n: int) -> IntArray:
    """Each answer's event, numbered by first appearance (so n distinct labels give 0..n-1)."""
    if groups is None:
        return np.arange(n, dtype=np.int64)
    labels = list(groups)
    if len(labels) != n:
        raise InvalidInputError(
            f"groups: expected {n} labels, one per answer, received {len(labels)}."
        )
    first: dict[Hashable, int] = {}
    return np.array([first.setdefault(label, len(first)) for label in labels], dtype=np.int64)


def _bin_index(confidence: FloatArray, n_bins: int) -> IntArray:
    """Bin b holds [b / n_bins, (b + 1) / n_bins); the last bin also holds 1."""
    return np.minimum(np.floor(confidence * n_bins), n_bins - 1).astype(np.int64)
