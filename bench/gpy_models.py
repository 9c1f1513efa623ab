"""GPy counterparts of the manifold model, for the speed comparison (optional ``bench`` extra).

The manifold model is, per feature a, a GP over z = [s; x] with one ARD squared-exponential
kernel (σ_f,a², ds + dx length-scales) and Gaussian noise σ_n,a². With the latents S given, the
same model in GPy is five independent ``GPRegression`` models with ``RBF(ds + dx, ARD=True)``
on inputs [S[obj]; X] and the centred observations. GPy then fits the hyperparameters only:
the latents stay fixed (GPy cannot learn them).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from core.types import Hyperparameters, TrainingData
from core.validation import FloatArray

#: The stopping rule of GPy's ``optimize()`` (its L-BFGS-B wrapper leaves scipy's
#: ``fmin_l_bfgs_b`` defaults: factr = 1e7, i.e. a relative reduction of 1e7 machine epsilons,
#: and pgtol = 1e-5; ``max_iters`` = 1000 caps iterations and evaluations).
GPY_FTOL = 1e7 * float(np.finfo(np.float64).eps)
GPY_GTOL = 1e-5
GPY_MAX_ITERATIONS = 1000


def load_gpy() -> tuple[Any, str]:
    """The ``GPy`` module, or ``None`` and the reason it could not be imported."""
    try:
        import GPy
    except Exception as exc:  # ImportError, or a broken install
        return None, f"GPy not importable ({type(exc).__name__}: {exc}); install the bench extra"
    return GPy, f"GPy {GPy.__version__}"


def build_models(
    gpy: Any, data: TrainingData, latents: FloatArray, hyperparameters: Hyperparameters
) -> list[Any]:
    """One ``GPRegression`` per feature with the given latents and hyperparameters."""
    h = hyperparameters
    inputs = np.hstack([latents[data.object_index], data.actions])
    centred = data.observations - data.observation_mean
    models = []
    for a in range(h.observation_dim):
        kernel = gpy.kern.RBF(
            inputs.shape[1],
            ARD=True,
            variance=float(h.signal_variance[a]),
            lengthscale=np.concatenate([h.latent_lengthscales[a], h.action_lengthscales[a]]),
        )
        models.append(
            gpy.models.GPRegression(
                inputs, centred[:, a : a + 1], kernel, noise_var=float(h.noise_variance[a])
            )
        )
    return models


def value_and_gradient(models: list[Any]) -> tuple[float, FloatArray]:
    """Σ -log p of the models and the concatenated gradient in GPy's own parametrisation
    (one objective-and-gradient evaluation per model, as GPy's optimiser does)."""
    total = 0.0
    grads = []
    for model in models:
        value, grad = model._objective_grads(model.optimizer_array)
        total += float(value)
        grads.append(np.asarray(grad, dtype=np.float64))
    return total, np.concatenate(grads)


@dataclass(frozen=True)
class GPyFit:
    """Result of fitting the GPy models.

    Attributes:
        seconds: Wall time of all the ``optimize`` calls.
        log_likelihood: Σ_a log p(y_a) at GPy's optimum.
        evaluations: Objective evaluations summed over the models.
    """

    seconds: float
    log_likelihood: float
    evaluations: int


def fit(models: list[Any], max_iters: int = GPY_MAX_ITERATIONS) -> GPyFit:
    """``model.optimize()`` (GPy's default L-BFGS-B) on every model in turn."""
    started = time.perf_counter()
    evaluations = 0
    for model in models:
        model.optimize(max_iters=max_iters)
        runs = getattr(model, "optimization_runs", [])
        if runs:
            evaluations += int(getattr(runs[-1], "funct_eval", 0) or 0)
    seconds = time.perf_counter() - started
    log_likelihood = float(sum(float(model.log_likelihood()) for model in models))
    return GPyFit(seconds=seconds, log_likelihood=log_likelihood, evaluations=evaluations)
