"""The joint optimum reached from a given starting model: the reference a fit is judged by.

A fit started from the data should end where a fit started from the true latents ends (or
better); :func:`joint_optimum` runs that second fit — one L-BFGS-B run over S and γ together,
to convergence (no stall stop), with the fit's bounds and tolerances.
"""

from __future__ import annotations

import numpy as np

from core.gp import FitOptions, make_likelihood
from core.gp.hyperparameter_fit import minimize_free
from core.gp.parameters import parameter_bounds
from core.types import ManifoldModel, TrainingData
from core.validation import FloatArray


def joint_optimum(
    data: TrainingData, start: ManifoldModel, options: FitOptions
) -> tuple[float, FloatArray]:
    """Optimise S and γ jointly from ``start``'s latents and hyperparameters.

    Args:
        data: Training touches.
        start: Starting model, e.g. :func:`core.gp.manifold.fit_hyperparameters` on the true
            latents.
        options: Bounds (``latent_bound``), ``max_iterations``, ``ftol``, ``gtol`` and the
            likelihood ``structure``.

    Returns:
        (log-likelihood at the optimum, its latents (L, ds)).
    """
    likelihood = make_likelihood(data, start.latent_dim, options.structure)
    layout = likelihood.layout
    lower, upper = parameter_bounds(data, layout, options.latent_bound)
    vector = np.clip(layout.pack(start.latents, start.hyperparameters), lower, upper)
    result = minimize_free(
        likelihood,
        vector,
        np.ones(layout.size, dtype=bool),
        lower,
        upper,
        options.max_iterations,
        options.ftol,
        options.gtol,
    )
    latents, _ = layout.unpack(result.x)
    return -float(result.fun), latents
