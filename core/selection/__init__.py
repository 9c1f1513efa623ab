"""Choosing the model's latent dimension by how well it predicts objects it has not seen.

``held_out_objects`` (a fit's log-likelihood of held-out objects), ``nested_fits`` (fits for
ds = 1, 2, … each started from the last, or each on its own and carried over) and
``latent_selection`` (the folds, the criteria and :func:`select_latent_dim`). Above
``core.recognition``: a held-out touch is scored by the object posterior's likelihood.
"""

from core.selection.latent_selection import (
    CRITERIA,
    DEFAULT_FOLDS,
    DEFAULT_MAX_LATENT_DIM,
    RUNG_COST_IN_REFITS,
    FoldMap,
    FoldPlan,
    FoldResult,
    FoldTask,
    LatentSelection,
    WarmMap,
    WarmRefit,
    candidate_dims,
    score_fold,
    score_warm_fold,
    select_latent_dim,
    serial_map,
    serial_warm_map,
)
from core.selection.nested_fits import (
    RungPlan,
    RungResult,
    RungTask,
    fit_rung,
)

__all__ = [
    "CRITERIA",
    "DEFAULT_FOLDS",
    "DEFAULT_MAX_LATENT_DIM",
    "RUNG_COST_IN_REFITS",
    "FoldMap",
    "FoldPlan",
    "FoldResult",
    "FoldTask",
    "LatentSelection",
    "RungPlan",
    "RungResult",
    "RungTask",
    "WarmMap",
    "WarmRefit",
    "candidate_dims",
    "fit_rung",
    "score_fold",
    "score_warm_fold",
    "select_latent_dim",
    "serial_map",
    "serial_warm_map",
]
