"""What a fitted model learns from its training touches after the fit, before it recognises.

The fit (docs/method.md (M2)) gives the latents and hyperparameters. The object likelihood a trial
is scored with also needs what the fit cannot see in isolated touches, each estimated from the
training collection alone, in this order (each uses the model the previous one left):

1. the placement effect σ_b² (:mod:`core.gp.placement_effect`, refitted with it),
2. the drift effect σ_d² (:mod:`core.gp.drift_effect`),
3. each object's own placement variance σ_b,l² (:mod:`core.gp.object_placement`, shrunk towards
   the pooled σ_b²; scores trials only), only when asked: measured on the unseen workshop table
   it cost 12-18 points of accuracy (docs/calibration.md, "Each object's placement variance"),
4. the input shift σ_δ² and its creep (:mod:`core.gp.input_shift`), along the action dimensions
   a placement can shift (all unless told),
5. the uncertainty Σ_l of each object's latent point (:mod:`core.recognition.latent_uncertainty`,
   docs/method.md (L1)–(L3)), on by default; a sparse model (more than
   :data:`core.gp.posterior.AUTO_SPARSE_ABOVE` touches) keeps point latents, since the Laplace
   step is dense (O(N³) per feature),
6. tempering β (:mod:`core.recognition.tempering`), a last resort, off by default.

The first four apply only when the touches record placements and times. ``activetouch fit`` and
the server's fits both go through :func:`calibrate`, so a model means the same from either.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from core.gp.drift_effect import DriftEstimate, with_drift_effect
from core.gp.fit_options import FitOptions
from core.gp.input_shift import ShiftEstimate, with_input_shift
from core.gp.object_placement import ObjectPlacementEstimate, with_object_placement
from core.gp.placement_effect import PlacementEstimate, PlacementPooling, with_placement_effect
from core.recognition.latent_uncertainty import LatentLaplace, with_latent_uncertainty
from core.recognition.tempering import TemperingFit, fit_tempering
from core.types import ManifoldModel
from core.validation import IntArray


@dataclass(frozen=True)
class Calibrations:
    """What :func:`calibrate` estimated; ``None`` for what did not apply or was not asked for,
    and why a step that was asked for did not run (``notes``)."""

    placement: PlacementEstimate | None = None
    drift: DriftEstimate | None = None
    shift: ShiftEstimate | None = None
    laplace: LatentLaplace | None = None
    tempering: TemperingFit | None = None
    notes: tuple[str, ...] = ()
    object_placement: ObjectPlacementEstimate | None = None


def calibrate(
    model: ManifoldModel,
    options: FitOptions,
    rng: np.random.Generator,
    *,
    latent_uncertainty: bool = True,
    tempering: bool = False,
    object_placement: bool = False,
    placement_pooling: PlacementPooling = "mean",
    shift_dimensions: IntArray | None = None,
) -> tuple[ManifoldModel, Calibrations]:
    """The fitted ``model`` with every effect of its training touches (module docstring).

    Args:
        model: A model as the fit left it.
        options: The fit's options (the placement effect's refits use them).
        rng: Source of tempering's cross-validation folds (unused without tempering).
        latent_uncertainty: Carry each object's Laplace Σ_l into the object likelihood.
        tempering: Fit β ≤ 1 on the training touches' held-out log-loss (a last resort).
        object_placement: Score each object's trials with its own placement variance (not
            adopted: off by default).
        placement_pooling: How the objects' placements make the one σ_b² every trial is scored
            with: the ``"mean"`` over every placement (the default) or the ``"median"`` of
            each object's own estimate (measured, not adopted:
            :func:`core.gp.placement_effect.estimate_placement_variance`).
        shift_dimensions: The action dimensions a placement can shift
            (:func:`core.gp.input_shift.estimate_shift_variance`); ``None``: all of them.

    Returns:
        The calibrated model, and what was estimated.
    """
    model, placement = with_placement_effect(model, options, pooling=placement_pooling)
    model, drift = with_drift_effect(model)
    by_object = None
    if object_placement:
        model, by_object = with_object_placement(model)
    model, shift = with_input_shift(model, shift_dimensions)
    laplace = None
    notes: list[str] = []
    if latent_uncertainty and model.posterior.inducing is not None:
        notes.append(
            f"latent uncertainty not computed: a sparse model ({model.data.n_touches} touches) "
            "keeps point latents (the Laplace step is dense)"
        )
    elif latent_uncertainty:
        model, laplace = with_latent_uncertainty(model)
    tempered = None
    if tempering:
        tempered = fit_tempering(model, rng)
        model = dataclasses.replace(model, tempering=tempered.exponent)
    return model, Calibrations(placement, drift, shift, laplace, tempered, tuple(notes), by_object)
