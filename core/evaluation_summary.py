"""Summaries of evaluation trials: accuracy by touch with Wilson intervals, per object, confusion,
touches to confidence, and the comparison of policies (METHOD.md, "Evaluation protocols").

Pure functions of :class:`core.evaluation_records.TrialRecord` lists; the result is JSON-ready.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from core.errors import InvalidInputError
from core.evaluation_records import TrialRecord

#: z of a two-sided 95 % normal interval, Φ⁻¹(0.975).
Z_95 = 1.959963984540054


def wilson_interval(successes: int, trials: int, z: float = Z_95) -> tuple[float, float]:
    """The Wilson score interval of a binomial proportion.

    With p̂ = k/n: centre (p̂ + z²/2n) / (1 + z²/n), half-width
    z / (1 + z²/n) · sqrt(p̂(1 - p̂)/n + z²/4n²). Unlike p̂ ± z·sqrt(p̂(1-p̂)/n) it stays inside
    [0, 1] and is not empty at k = 0 or k = n.

    Args:
        successes: k, 0 ≤ k ≤ n.
        trials: n ≥ 1.
        z: Normal quantile (95 % by default).

    Raises:
        InvalidInputError: n < 1 or k outside 0..n.
    """
    if trials < 1 or not 0 <= successes <= trials:
        raise InvalidInputError(
            f"wilson_interval: expected 0 ≤ successes ≤ trials and trials ≥ 1, received "
            f"successes={successes}, trials={trials}."
        )
    n = float(trials)
    p = successes / n
    denominator = 1.0 + z * z / n
    centre = (p + z * z / (2.0 * n)) / denominator
    half = z / denominator * math.sqrt(p * (1.0 - p) / n + z * z / (4.0 * n * n))
    return (max(0.0, centre - half), min(1.0, centre + half))


def touches_to_confidence(
    record: TrialRecord, object_names: Sequence[str], confidence: float
) -> int | None:
    """The first touch (1-based) after which the answer's probability is ≥ ``confidence``.

    The answer's probability is the posterior probability of the object answered after that
    touch (``object_names`` gives the order of ``record.probabilities``). ``None`` when it never
    gets there within the touches performed.
    """
    names = tuple(object_names)
    for touch, (answer, probabilities) in enumerate(
        zip(record.answers, record.probabilities, strict=True), start=1
    ):
        if probabilities[names.index(answer)] >= confidence:
            return touch
    return None


def median_touches(values: Sequence[int | None]) -> float | None:
    """Median of touch counts where ``None`` (never reached) counts as more than any count.

    Returns ``None`` when the median itself is "never" (at least half never reached it).
    """
    if not values:
        return None
    ordered = sorted(math.inf if v is None else float(v) for v in values)
    median = float(np.median(ordered))
    return None if math.isinf(median) or math.isnan(median) else median


def first_touch_reaching(curve: Sequence[float], level: float) -> int | None:
    """The first touch t (1-based) with ``curve[t-1] ≥ level``, or ``None``."""
    for touch, value in enumerate(curve, start=1):
        if value >= level:
            return touch
    return None


def summarise(
    records: Sequence[TrialRecord],
    object_names: Sequence[str],
    steps: int,
    confidence: float,
) -> dict[str, dict[str, Any]]:
    """The summary of each policy's trials.

    Args:
        records: Trials (any order); each with at most ``steps`` touches.
        object_names: The model's objects, in the order of the records' probabilities.
        steps: T; answers of trials that stopped early are carried forward to T.
        confidence: Threshold of "touches to confidence" and of the accuracy level compared
            between policies.

    Returns:
        Per policy (in order of first appearance): ``accuracy_by_touch`` [T],
        ``accuracy_interval`` [[lo, hi]]·T (95 % Wilson), ``per_object`` {object: {"accuracy",
        "trials"}} (final answers), ``confusion`` {true: {answer: count}} (final answers, every
        model object as a row and column), ``median_touches_to_confidence`` (median over trials
        of the first touch whose answer has probability ≥ ``confidence``; trials that never get
        there count as more than T; ``None`` when at least half never do),
        ``touches_to_accuracy`` (first touch whose accuracy is ≥ ``confidence``, or ``None``),
        ``trials``.

    Raises:
        InvalidInputError: No records, bad ``steps`` or ``confidence``, a record longer than
            ``steps`` or naming an object that is not in ``object_names``.
    """
    names = tuple(object_names)
    if steps < 1:
        raise InvalidInputError(f"steps: must be ≥ 1, received {steps}.")
    if not 0.0 < confidence <= 1.0:
        raise InvalidInputError(f"confidence: must lie in (0, 1], received {confidence}.")
    if not records:
        raise InvalidInputError("records: need at least one trial to summarise.")
    by_policy: dict[str, list[TrialRecord]] = {}
    for record in records:
        unknown = {record.target, *record.answers} - set(names)
        if unknown:
            raise InvalidInputError(
                f"records: objects {sorted(unknown)} are not among the model's {list(names)}."
            )
        if any(len(p) != len(names) for p in record.probabilities):
            raise InvalidInputError(
                f"records: a trial of {record.target!r} has probabilities of the wrong length "
                f"(the model has {len(names)} objects)."
            )
        by_policy.setdefault(record.policy, []).append(record)
    return {
        policy: _summarise_policy(mine, names, steps, confidence)
        for policy, mine in by_policy.items()
    }


def _summarise_policy(
    records: list[TrialRecord], names: tuple[str, ...], steps: int, confidence: float
) -> dict[str, Any]:
    n = len(records)
    answers = [r.answers_by_touch(steps) for r in records]
    correct = np.array(
        [[a == r.target for a in row] for r, row in zip(records, answers, strict=True)],
        dtype=bool,
    )  # (n, T)
    counts = correct.sum(axis=0)
    accuracy = [float(c) / n for c in counts]
    intervals = [list(wilson_interval(int(c), n)) for c in counts]
    per_object: dict[str, dict[str, Any]] = {}
    confusion: dict[str, dict[str, int]] = {}
    for name in names:
        mine = [r for r in records if r.target == name]
        if not mine:
            continue
        finals = [r.answers[-1] for r in mine]
        per_object[name] = {
            "accuracy": sum(f == name for f in finals) / len(mine),
            "trials": len(mine),
        }
        confusion[name] = {other: sum(f == other for f in finals) for other in names}
    reached = [touches_to_confidence(r, names, confidence) for r in records]
    return {
        "accuracy_by_touch": accuracy,
        "accuracy_interval": intervals,
        "per_object": per_object,
        "confusion": confusion,
        "median_touches_to_confidence": median_touches(reached),
        "touches_to_accuracy": first_touch_reaching(accuracy, confidence),
        "trials": n,
    }


def comparison_sentence(summaries: dict[str, dict[str, Any]], level: float) -> str:
    """ "active reaches 95 % after 3 touches, passive after 6" (or "does not within T").

    Args:
        summaries: The result of :func:`summarise`.
        level: Accuracy level compared (a fraction).
    """
    parts = []
    for index, (policy, summary) in enumerate(summaries.items()):
        touch = first_touch_reaching(summary["accuracy_by_touch"], level)
        steps = len(summary["accuracy_by_touch"])
        if touch is None:
            text = f"does not within {steps} touches"
        else:
            text = f"after {touch} touch{'es' if touch != 1 else ''}"
        if index == 0:
            parts.append(f"{policy} reaches {100 * level:g} % accuracy {text}")
        else:
            parts.append(f"{policy} {text}")
    return ", ".join(parts)
