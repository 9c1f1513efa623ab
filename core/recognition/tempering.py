"""Posterior tempering fitted on the training touches only: a last resort (docs/calibration.md,
"Fix 6").

The object posterior with a tempered likelihood is p_β(l | D) ∝ p(D | l)^β, 0 < β ≤ 1. β is not
a model of anything: it treats the symptom (over-confidence) of model errors that the likelihood
does not describe. It is chosen by cross-validation on the training collection alone —
never on evaluation trials — as the β of smallest held-out log-loss over pseudo-trials of held-out
training touches (:func:`fit_tempering`), and stored in the model document.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
import scipy.optimize
import scipy.special

from core.errors import InvalidInputError
from core.gp.posterior import condition
from core.recognition.object_posterior import object_log_likelihoods
from core.types import ManifoldModel, TrainingData
from core.validation import FloatArray, IntArray

#: β is searched in [MIN_EXPONENT, 1]: tempering only ever softens the likelihood.
MIN_EXPONENT = 1e-3


@dataclass(frozen=True)
class TemperingFit:
    """The exponent chosen by :func:`fit_tempering` and what it was chosen on.

    Attributes:
        exponent: β in [MIN_EXPONENT, 1].
        log_loss: Held-out log-loss −mean log p_β(true | D) at β. Nats.
        log_loss_untempered: The same at β = 1. Nats.
        answers: Pseudo-trial prefixes scored (one answer per trial and touch).
    """

    exponent: float
    log_loss: float
    log_loss_untempered: float
    answers: int


def check_exponent(exponent: float) -> float:
    """β as a checked float in [MIN_EXPONENT, 1].

    Raises:
        InvalidInputError: Not a finite number in that range.
    """
    value = float(exponent)
    if not np.isfinite(value) or not MIN_EXPONENT <= value <= 1.0:
        raise InvalidInputError(
            f"tempering exponent: must lie in [{MIN_EXPONENT}, 1], received {exponent!r}."
        )
    return value


def tempered_log_loss(log_likelihoods: FloatArray, truth: IntArray, exponent: float) -> float:
    """−mean_k log softmax(β · ℓ_k)[truth_k] over answers k.

    Args:
        log_likelihoods: log p(D_k | l) of every answer k. Shape (K, L).
        truth: The true object of every answer. Shape (K,).
        exponent: β.
    """
    scaled = exponent * np.asarray(log_likelihoods, dtype=np.float64)
    log_p = scaled - scipy.special.logsumexp(scaled, axis=1, keepdims=True)
    return float(-np.mean(log_p[np.arange(log_p.shape[0]), truth]))


def held_out_log_likelihoods(
    model: ManifoldModel, folds: int, trial_length: int, rng: np.random.Generator
) -> tuple[FloatArray, IntArray]:
    """log p(D | l) of pseudo-trials of held-out training touches, every prefix of each trial.

    Every object's training touches are split into ``folds`` parts at random. For each fold the
    GP is conditioned on the other folds' touches (latents and hyperparameters as fitted, in the
    model's space; no refit), and the fold's touches of each object, shuffled, form trials of
    ``trial_length`` touches (a shorter last one). A trial's prefixes of 1, 2, … touches are
    scored by the model's own trial likelihood
    (:func:`core.recognition.object_posterior.object_log_likelihoods`, joint; σ_b² left out, since a
    collection's touches each met their own placement; the latent covariance used if the model
    has one).

    Args:
        model: A fitted model.
        folds: K ≥ 2.
        trial_length: Touches per pseudo-trial, ≥ 1.
        rng: Source of the random split and order.

    Returns:
        The log-likelihoods (K answers, L objects) and the true object of each. Shapes (K, L), (K,).

    Raises:
        InvalidInputError: Fewer than 2 folds, a trial length below 1, or an object with fewer
            touches than folds.
    """
    if isinstance(folds, bool) or int(folds) != folds or folds < 2:
        raise InvalidInputError(f"folds: must be an integer ≥ 2, received {folds!r}.")
    if isinstance(trial_length, bool) or int(trial_length) != trial_length or trial_length < 1:
        raise InvalidInputError(f"trial_length: must be an integer ≥ 1, received {trial_length!r}.")
    data = model.data
    counts = np.bincount(data.object_index, minlength=data.n_objects)
    if counts.min() < folds:
        raise InvalidInputError(
            f"folds: every object needs at least {folds} touches; "
            f"{data.object_names[int(np.argmin(counts))]} has {int(counts.min())}."
        )
    assignment = np.empty(data.n_touches, dtype=np.int64)
    for obj in range(data.n_objects):
        members = np.flatnonzero(data.object_index == obj)
        assignment[rng.permutation(members)] = np.arange(members.size) % folds
    rows: list[FloatArray] = []
    truth: list[int] = []
    for fold in range(folds):
        kept = assignment != fold
        reduced = condition(
            TrainingData(
                data.object_names,
                data.object_index[kept],
                data.actions[kept],
                data.observations[kept],
            ),
            model.latents,
            model.hyperparameters,
            structure="dense",
        )
        reduced = dataclasses.replace(reduced, latent_covariance=model.latent_covariance)
        for obj in range(data.n_objects):
            held = rng.permutation(
                np.flatnonzero((assignment == fold) & (data.object_index == obj))
            )
            for start in range(0, held.size, trial_length):
                trial = held[start : start + trial_length]
                for t in range(1, trial.size + 1):
                    rows.append(
                        object_log_likelihoods(
                            reduced,
                            data.actions[trial[:t]],
                            data.observations[trial[:t]],
                            "joint",
                            shared_placement=False,
                        )
                    )
                    truth.append(obj)
    return np.stack(rows), np.asarray(truth, dtype=np.int64)


def fit_tempering(
    model: ManifoldModel, rng: np.random.Generator, folds: int = 5, trial_length: int = 6
) -> TemperingFit:
    """β of smallest held-out log-loss over the training touches' pseudo-trials.

    The log-loss is convex in β (a log-sum-exp of linear functions minus a linear one), so a
    bounded scalar minimisation over [MIN_EXPONENT, 1] finds it.

    Args:
        model: A fitted model (its own training touches are the only data used).
        rng: Source of the folds and trial order (:func:`held_out_log_likelihoods`).
        folds: K of the cross-validation.
        trial_length: Touches per pseudo-trial (the evaluation's T).
    """
    log_likelihoods, truth = held_out_log_likelihoods(model, folds, trial_length, rng)
    return choose_exponent(log_likelihoods, truth)


def choose_exponent(log_likelihoods: FloatArray, truth: IntArray) -> TemperingFit:
    """The β in [MIN_EXPONENT, 1] of smallest :func:`tempered_log_loss` (convex in β).

    Args:
        log_likelihoods: log p(D_k | l) of every held-out answer k. Shape (K, L).
        truth: The true object of every answer. Shape (K,).
    """
    result = scipy.optimize.minimize_scalar(
        lambda b: tempered_log_loss(log_likelihoods, truth, b),
        bounds=(MIN_EXPONENT, 1.0),
        method="bounded",
        options={"xatol": 1e-5},
    )
    exponent = float(result.x)
    untempered = tempered_log_loss(log_likelihoods, truth, 1.0)
    if untempered <= float(result.fun):
        exponent = 1.0
    return TemperingFit(
        exponent=exponent,
        log_loss=tempered_log_loss(log_likelihoods, truth, exponent),
        log_loss_untempered=untempered,
        answers=int(np.asarray(truth).size),
    )
