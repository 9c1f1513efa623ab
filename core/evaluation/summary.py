"""Summaries of evaluation trials: accuracy by touch with Wilson intervals, per object, confusion,
touches to confidence, calibration of the answers' probabilities, and the comparison of policies
(docs/method.md, "Evaluation protocols").

Pure functions of :class:`core.evaluation.records.TrialRecord` lists; the result is JSON-ready.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Sequence
from typing import Any

import numpy as np

from core.errors import InvalidInputError
from core.evaluation.calibration import DEFAULT_BINS, calibration
from core.evaluation.records import TrialRecord

#: z of a two-sided 95 % normal interval, Φ⁻¹(0.975).
Z_95 = 1.959963984540054


def wilson_interval(successes: float, trials: float, z: float = Z_95) -> tuple[float, float]:
    """The Wilson score interval of a binomial proportion.

    With p̂ = k/n: centre (p̂ + z²/2n) / (1 + z²/n), half-width
    z / (1 + z²/n) · sqrt(p̂(1 - p̂)/n + z²/4n²). Unlike p̂ ± z·sqrt(p̂(1-p̂)/n) it stays inside
    [0, 1] and is not empty at k = 0 or k = n. A non-integer n is an effective sample size
    (:func:`effective_trials`), with k = p̂·n.

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


def effective_trials(keys: Sequence[object]) -> float:
    """Kish's effective sample size of trials that share their evidence: (Σ n_c)² / Σ n_c².

    Trials with equal keys — the same recorded touches so far, hence the same posterior and the
    same answer — are one observation counted n_c times: their outcomes are perfectly
    correlated, so the variance of the accuracy is p(1 − p) Σ n_c² / n² instead of p(1 − p)/n.
    When every key differs (fresh touches on the rig or from the model) this is the number of
    trials. Replay, where the planners pick the same few recorded touches in many trials, is
    the case it is for (docs/method.md, "Evaluation protocols").

    Args:
        keys: One hashable key per trial.

    Raises:
        InvalidInputError: No keys.
    """
    if not keys:
        raise InvalidInputError("effective_trials: need at least one trial.")
    counts = np.array(list(Counter(keys).values()), dtype=np.float64)
    return float(counts.sum() ** 2 / np.sum(counts**2))


def evidence_key(record: TrialRecord, touch: int) -> tuple[object, ...]:
    """What a trial's answer after ``touch`` (1-based, carried forward after an early stop)
    rests on: the target, the actions touched so far and the posterior they gave. Equal keys
    mean equal recorded touches (the posterior is a deterministic function of them); on the
    rig or the model's samples every touch's observation is fresh and no two keys are equal."""
    done = min(touch, record.touches)
    posterior = record.probabilities[done - 1] if done else ()
    return (record.target, record.actions[:done], posterior)


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
        Per policy (in order of first appearance): ``accuracy_by_touch`` [T], ``accuracy_interval``
        [[lo, hi]]·T (95 % Wilson, on the effective number of trials), ``effective_trials`` [T]
        (:func:`effective_trials` of the trials' evidence after each touch, :func:`evidence_key`:
        the trials unless some share recorded touches), ``per_object`` {object: {"accuracy",
        "trials"}} (final answers), ``confusion`` {true: {answer: count}} (final answers, every
        model object as a row and column), ``median_touches_to_confidence`` (median over trials of
        the first touch whose answer has probability ≥ ``confidence``; trials that never get there
        count as more than T; ``None`` when at least half never do), ``touches_to_accuracy`` (first
        touch whose accuracy is ≥ ``confidence``, or ``None``), ``calibration``
        (:func:`calibration_summary`, its "sure and wrong" at ``confidence``), ``trials``.

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
    effective = [
        effective_trials([evidence_key(r, touch) for r in records]) for touch in range(1, steps + 1)
    ]
    intervals = [
        list(wilson_interval(p * size, size)) for p, size in zip(accuracy, effective, strict=True)
    ]
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
        "effective_trials": effective,
        "per_object": per_object,
        "confusion": confusion,
        "median_touches_to_confidence": median_touches(reached),
        "touches_to_accuracy": first_touch_reaching(accuracy, confidence),
        "calibration": calibration_summary(records, names, steps, confidence),
        "trials": n,
    }


def calibration_summary(
    records: Sequence[TrialRecord],
    object_names: Sequence[str],
    steps: int,
    threshold: float,
    n_bins: int = DEFAULT_BINS,
) -> dict[str, Any]:
    """How far the probabilities of one policy's answers can be trusted
    (core.evaluation.calibration).

    Every answer is scored with the object posterior behind it (``record.probabilities``, in the
    order of ``object_names``) against the trial's target. The answers are counted exactly as
    accuracy by touch counts them: a trial that stopped early (converged, confident, pool
    exhausted) keeps its last answer and the posterior behind it up to touch ``steps``, so the
    scores at touch t cover every trial, ``by_touch[t-1]["accuracy"]`` is the accuracy after
    touch t, and a confident early stop counts once per touch it carries forward to (as a user
    reading the recogniser at touch t would see it). Refused trials are not records and are not
    scored.

    Args:
        records: Completed trials of one policy, each with at most ``steps`` touches.
        object_names: The model's objects, the order of the records' probabilities.
        steps: T.
        threshold: The confidence threshold of "sure and wrong" (the evaluation's).
        n_bins: Bins of the reliability tables.

    Returns:
        ``all_touches`` (:meth:`core.evaluation.calibration.Calibration.to_dict` over every
        (trial, touch), n·T answers), ``final`` (the same at touch T, n answers) and
        ``by_touch`` [T] (per touch: ``answers``, ``accuracy``, ``ece``, ``brier``,
        ``log_loss``, ``sure_and_wrong``; the reliability table left out).

    Raises:
        InvalidInputError: No records, a record longer than ``steps``, an object that is not in
            ``object_names``, or probabilities that are not a distribution over them.
    """
    names = tuple(object_names)
    if not records:
        raise InvalidInputError("records: need at least one trial to score.")
    index = {name: k for k, name in enumerate(names)}
    unknown = {n for r in records for n in (r.target, *r.answers)} - set(index)
    if unknown:
        raise InvalidInputError(
            f"records: objects {sorted(unknown)} are not among the model's {list(names)}."
        )
    # (n, T, L) posteriors, (n, T) answers and (n,) targets, carried forward like the answers.
    probabilities = np.array(
        [_carried(r.probabilities, r.touches, steps) for r in records], dtype=np.float64
    )
    if probabilities.shape[2:] != (len(names),):
        raise InvalidInputError(
            f"records: probabilities of length {probabilities.shape[2:]} for the model's "
            f"{len(names)} objects."
        )
    answers = np.array(
        [[index[a] for a in r.answers_by_touch(steps)] for r in records], dtype=np.int64
    )
    targets = np.array([index[r.target] for r in records], dtype=np.int64)
    labels = np.repeat(targets[:, None], steps, axis=1)
    n, t, n_objects = probabilities.shape

    # (n, T) evidence of each answer: replay trials that took the same recorded touches are one
    # event in the ECE's sampling spread (core.evaluation.calibration.ece_if_calibrated).
    evidence = [[evidence_key(r, touch) for touch in range(1, steps + 1)] for r in records]

    def scored(p: np.ndarray, y: np.ndarray, a: np.ndarray, groups: list[Any]) -> dict[str, Any]:
        return calibration(p, y, threshold, answers=a, n_bins=n_bins, groups=groups).to_dict()

    by_touch = []
    for touch in range(t):
        entry = scored(
            probabilities[:, touch],
            labels[:, touch],
            answers[:, touch],
            [keys[touch] for keys in evidence],
        )
        entry.pop("reliability")
        by_touch.append(entry)
    return {
        "all_touches": scored(
            probabilities.reshape(n * t, n_objects),
            labels.reshape(-1),
            answers.reshape(-1),
            [key for keys in evidence for key in keys],
        ),
        "final": scored(
            probabilities[:, -1], labels[:, -1], answers[:, -1], [keys[-1] for keys in evidence]
        ),
        "by_touch": by_touch,
    }


def _carried(
    rows: tuple[tuple[float, ...], ...], touches: int, steps: int
) -> tuple[tuple[float, ...], ...]:
    """``rows`` (one per touch performed) with the last carried forward to ``steps``."""
    if steps < touches:
        raise InvalidInputError(f"steps: {steps} is fewer than the {touches} touches of a trial.")
    return rows + (rows[-1],) * (steps - touches)


def comparison_sentence(summaries: dict[str, dict[str, Any]], level: float) -> str:
    """ "active reaches 95 % accuracy after 3 touches, passive after 6 touches".

    A policy that never gets there: "… does not reach 95 % accuracy within 10 touches" (first)
    or "passive does not within 10 touches".

    Args:
        summaries: The result of :func:`summarise`.
        level: Accuracy level compared (a fraction).
    """
    parts = []
    for index, (policy, summary) in enumerate(summaries.items()):
        touch = first_touch_reaching(summary["accuracy_by_touch"], level)
        steps = len(summary["accuracy_by_touch"])
        after = None if touch is None else f"after {touch} touch{'es' if touch != 1 else ''}"
        if index == 0:
            parts.append(
                f"{policy} reaches {100 * level:g} % accuracy {after}"
                if after
                else f"{policy} does not reach {100 * level:g} % accuracy within {steps} touches"
            )
        else:
            parts.append(
                f"{policy} {after}" if after else f"{policy} does not within {steps} touches"
            )
    return ", ".join(parts)
