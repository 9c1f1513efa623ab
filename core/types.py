"""Frozen value types shared across :mod:`core`.

Notation follows ``METHOD.md``: L objects, N touches, ``dx`` action dimension, ``dy`` observation
dimension (features), ``ds`` latent dimension.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from core.errors import InvalidInputError
from core.validation import FloatArray, IntArray, as_float_array, require_positive


@dataclass(frozen=True)
class TrainingData:
    """Touches of known objects.

    Attributes:
        object_names: Names of the L objects, in latent order.
        object_index: Object of each touch, ``obj[i]`` in METHOD.md. Shape (N,), values in
            ``0..L-1``.
        actions: Action parameters x_i. Shape (N, dx).
        observations: Observed features y_i. Shape (N, dy).
    """

    object_names: tuple[str, ...]
    object_index: IntArray
    actions: FloatArray
    observations: FloatArray

    def __post_init__(self) -> None:
        names = tuple(str(n) for n in self.object_names)
        if len(set(names)) != len(names):
            raise InvalidInputError(f"object_names: names must be unique, received {names}.")
        if len(names) < 2:
            raise InvalidInputError(
                f"object_names: at least 2 objects are needed to learn a manifold, "
                f"received {len(names)} ({', '.join(names) or 'none'})."
            )
        index = np.asarray(self.object_index)
        if index.ndim != 1 or not np.issubdtype(index.dtype, np.integer):
            raise InvalidInputError(
                f"object_index: expected a 1-D integer array, received dtype {index.dtype} "
                f"with shape {index.shape}."
            )
        n = index.shape[0]
        actions = as_float_array(self.actions, "actions", (n, None))
        observations = as_float_array(self.observations, "observations", (n, None))
        if actions.shape[1] < 1 or observations.shape[1] < 1:
            raise InvalidInputError(
                f"actions and observations need at least one column, received "
                f"{actions.shape} and {observations.shape}."
            )
        if np.any(index < 0) or np.any(index >= len(names)):
            raise InvalidInputError(
                f"object_index: values must lie in 0..{len(names) - 1}, "
                f"received min {index.min()} and max {index.max()}."
            )
        counts = np.bincount(index, minlength=len(names))
        for name, count in zip(names, counts, strict=True):
            if count < 2:
                raise InvalidInputError(
                    f"object {name!r} has {count} touch(es); every object needs at least 2."
                )
        object.__setattr__(self, "object_names", names)
        object.__setattr__(self, "object_index", index.astype(np.int64))
        object.__setattr__(self, "actions", actions)
        object.__setattr__(self, "observations", observations)
        for array in (self.object_index, self.actions, self.observations):
            array.flags.writeable = False

    @property
    def n_objects(self) -> int:
        """L, the number of objects."""
        return len(self.object_names)

    @property
    def n_touches(self) -> int:
        """N, the number of touches."""
        return int(self.object_index.shape[0])

    @property
    def action_dim(self) -> int:
        """dx."""
        return int(self.actions.shape[1])

    @property
    def observation_dim(self) -> int:
        """dy."""
        return int(self.observations.shape[1])

    @property
    def observation_mean(self) -> FloatArray:
        """Per-feature mean of the observations, the GP's constant mean. Shape (dy,)."""
        return np.asarray(self.observations.mean(axis=0), dtype=np.float64)

    def touches_per_object(self) -> IntArray:
        """N_l for each object. Shape (L,)."""
        return np.bincount(self.object_index, minlength=self.n_objects).astype(np.int64)


@dataclass(frozen=True)
class Hyperparameters:
    """GP hyperparameters of every feature, stacked (METHOD.md eq. (M1)).

    Length-scales are stored as length-scales, not squared: Λ^s_a = diag(latent_lengthscales[a]²).

    Attributes:
        signal_variance: σ_f,a². Shape (dy,).
        noise_variance: σ_n,a². Shape (dy,).
        latent_lengthscales: Shape (dy, ds).
        action_lengthscales: Shape (dy, dx).
    """

    signal_variance: FloatArray
    noise_variance: FloatArray
    latent_lengthscales: FloatArray
    action_lengthscales: FloatArray

    def __post_init__(self) -> None:
        signal = as_float_array(self.signal_variance, "signal_variance", (None,))
        dy = signal.shape[0]
        noise = as_float_array(self.noise_variance, "noise_variance", (dy,))
        latent = as_float_array(self.latent_lengthscales, "latent_lengthscales", (dy, None))
        action = as_float_array(self.action_lengthscales, "action_lengthscales", (dy, None))
        for value, name in (
            (signal, "signal_variance"),
            (noise, "noise_variance"),
            (latent, "latent_lengthscales"),
            (action, "action_lengthscales"),
        ):
            require_positive(value, name)
            value.flags.writeable = False
            object.__setattr__(self, name, value)

    @property
    def observation_dim(self) -> int:
        """dy."""
        return int(self.signal_variance.shape[0])

    @property
    def latent_dim(self) -> int:
        """ds."""
        return int(self.latent_lengthscales.shape[1])

    @property
    def action_dim(self) -> int:
        """dx."""
        return int(self.action_lengthscales.shape[1])


@dataclass(frozen=True)
class GaussianBelief:
    """Belief s ~ N(mean, cov) over the latent point of the object being touched.

    Attributes:
        mean: μ. Shape (ds,).
        cov: Σ, symmetric positive definite. Shape (ds, ds).
    """

    mean: FloatArray
    cov: FloatArray

    def __post_init__(self) -> None:
        mean = as_float_array(self.mean, "belief mean", (None,))
        ds = mean.shape[0]
        cov = as_float_array(self.cov, "belief cov", (ds, ds))
        if not np.allclose(cov, cov.T, rtol=1e-8, atol=1e-12):
            raise InvalidInputError("belief cov: must be symmetric.")
        if np.linalg.eigvalsh(cov).min() <= 0:
            raise InvalidInputError("belief cov: must be positive definite.")
        mean.flags.writeable = False
        cov.flags.writeable = False
        object.__setattr__(self, "mean", mean)
        object.__setattr__(self, "cov", cov)

    @property
    def dim(self) -> int:
        """ds."""
        return int(self.mean.shape[0])


@dataclass(frozen=True)
class GPPosterior:
    """Quantities of the conditioned GP that prediction and moment matching reuse.

    Attributes:
        beta: β_a = K_a⁻¹ (y_a - mean_a). Shape (dy, N).
        gram_inverse: K_a⁻¹ of the noisy Gram matrix. Shape (dy, N, N).
        jitter: Jitter added to the diagonal of each K_a (0 when none was needed). Shape (dy,).
    """

    beta: FloatArray
    gram_inverse: FloatArray
    jitter: FloatArray


@dataclass(frozen=True)
class FitDiagnostics:
    """How a manifold fit went.

    Attributes:
        starts_log_likelihood: Final log-likelihood of each start (start 0 is the PCA start).
        best_start: Index of the start that was kept.
        iterations: Optimiser iterations of the kept start.
        converged: Whether the optimiser of the kept start reported convergence.
        message: The optimiser's message for the kept start.
        jitter_used: Largest jitter added to any Gram matrix during the fit (0 if none).
        hyperparameters_at_bounds: Names of hyperparameters that ended on a bound.
    """

    starts_log_likelihood: tuple[float, ...]
    best_start: int
    iterations: int
    converged: bool
    message: str
    jitter_used: float
    hyperparameters_at_bounds: tuple[str, ...] = field(default_factory=tuple)


@dataclass(frozen=True)
class ManifoldModel:
    """A fitted object manifold: latent points, GP hyperparameters and the conditioned GP.

    Build it with :func:`core.posterior.condition` (or by fitting), never by hand, so that the
    posterior matches the data, latents and hyperparameters.

    Attributes:
        data: The training touches.
        latents: s_l of every object, normalised (centred, RMS distance to the centre 1).
            Shape (L, ds).
        hyperparameters: Per-feature GP hyperparameters.
        posterior: β and K⁻¹ of every feature.
        log_likelihood: Σ_a log p(y_a | S, X, γ_a) (METHOD.md eq. (M2)).
        diagnostics: Fit diagnostics, ``None`` for a model that was not fitted here.
    """

    data: TrainingData
    latents: FloatArray
    hyperparameters: Hyperparameters
    posterior: GPPosterior
    log_likelihood: float
    diagnostics: FitDiagnostics | None = None

    @property
    def latent_dim(self) -> int:
        """ds."""
        return int(self.latents.shape[1])

    @property
    def object_names(self) -> tuple[str, ...]:
        """Names of the L objects."""
        return self.data.object_names
