"""Packing of the manifold-learning unknowns into one vector, with data-relative bounds.

The optimiser of docs/method.md eq. (M2) works on one flat vector θ holding, in this order:

* the object latents S, row-major (L·ds numbers — one s per object, shared by its touches);
* log σ_f,a² for every feature a (dy numbers);
* log σ_n,a² (dy);
* log ℓ^s_a,d, the log latent length-scales (dy·ds, row-major by feature);
* log ℓ^x_a,d, the log action length-scales (dy·dx, row-major by feature).

Length-scales are packed as logs of length-scales (not of squared length-scales), so
Λ^s_a = diag(exp(2 θ_ls[a])).

A *tied* layout (``ParameterLayout.tied``, the tied kernels of docs/fitting.md) holds one row of
length-scales shared by every feature instead: ds latent and dx action length-scales, after the
dy signal and dy noise variances. It unpacks to the ordinary per-feature
:class:`~core.types.Hyperparameters` (the shared row repeated per feature), so nothing downstream
of a fit knows the difference.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from core.errors import InvalidInputError
from core.types import Hyperparameters, TrainingData
from core.validation import FloatArray, as_float_array

#: Bounds relative to the data scales (docs/method.md, recommended defaults), as multiples of the
#: data variance: Λ^x ∈ [1e-2, 1e4]·var(x), σ_f² ∈ [1e-3, 1e2]·var(y), σ_n² ∈ [1e-6, 1]·var(y),
#: Λ^s ∈ [1e-4, 1e4] for latents of unit spread.
ACTION_LENGTHSCALE_SQUARED_RANGE: tuple[float, float] = (1e-2, 1e4)
SIGNAL_VARIANCE_RANGE: tuple[float, float] = (1e-3, 1e2)
NOISE_VARIANCE_RANGE: tuple[float, float] = (1e-6, 1.0)
LATENT_LENGTHSCALE_SQUARED_RANGE: tuple[float, float] = (1e-4, 1e4)

#: Variances below this are treated as this (a constant feature or action dimension).
_TINY_VARIANCE = 1e-12


@dataclass(frozen=True)
class ParameterLayout:
    """Where each group of unknowns sits in the packed vector.

    Attributes:
        n_objects: L.
        latent_dim: ds.
        action_dim: dx.
        observation_dim: dy.
        tied: One row of length-scales shared by every feature (module docstring), not one
            row per feature.
    """

    n_objects: int
    latent_dim: int
    action_dim: int
    observation_dim: int
    tied: bool = False

    @classmethod
    def for_data(cls, data: TrainingData, latent_dim: int, tied: bool = False) -> ParameterLayout:
        """The layout for ``data`` with ``latent_dim`` latent dimensions (shared length-scales
        when ``tied``)."""
        return cls(data.n_objects, int(latent_dim), data.action_dim, data.observation_dim, tied)

    @property
    def lengthscale_rows(self) -> int:
        """Rows of length-scales: 1 when :attr:`tied`, dy otherwise."""
        return 1 if self.tied else self.observation_dim

    @property
    def latents(self) -> slice:
        """S, L·ds entries."""
        return slice(0, self.n_objects * self.latent_dim)

    @property
    def log_signal_variance(self) -> slice:
        """log σ_f², dy entries."""
        start = self.latents.stop
        return slice(start, start + self.observation_dim)

    @property
    def log_noise_variance(self) -> slice:
        """log σ_n², dy entries."""
        start = self.log_signal_variance.stop
        return slice(start, start + self.observation_dim)

    @property
    def log_latent_lengthscales(self) -> slice:
        """log ℓ^s, dy·ds entries (ds when tied)."""
        start = self.log_noise_variance.stop
        return slice(start, start + self.lengthscale_rows * self.latent_dim)

    @property
    def log_action_lengthscales(self) -> slice:
        """log ℓ^x, dy·dx entries (dx when tied)."""
        start = self.log_latent_lengthscales.stop
        return slice(start, start + self.lengthscale_rows * self.action_dim)

    @property
    def hyperparameters(self) -> slice:
        """Every log-hyperparameter (everything but S)."""
        return slice(self.latents.stop, self.size)

    @property
    def size(self) -> int:
        """Length of the packed vector."""
        return int(self.log_action_lengthscales.stop)

    def pack(self, latents: FloatArray, hyperparameters: Hyperparameters) -> FloatArray:
        """Pack S (L, ds) and the hyperparameters into one vector of length :attr:`size`.

        A tied layout packs, per dimension, the mean over features of the log length-scales:
        exactly the shared ones of a tied model, the geometric mean of a per-feature model's
        (e.g. a warm start from it).
        """
        h = hyperparameters
        latents = as_float_array(latents, "latents", (self.n_objects, self.latent_dim))
        if (h.observation_dim, h.latent_dim, h.action_dim) != (
            self.observation_dim,
            self.latent_dim,
            self.action_dim,
        ):
            raise InvalidInputError(
                f"hyperparameters: expected dy={self.observation_dim}, ds={self.latent_dim}, "
                f"dx={self.action_dim}; received dy={h.observation_dim}, ds={h.latent_dim}, "
                f"dx={h.action_dim}."
            )
        log_ls = np.log(h.latent_lengthscales)
        log_lx = np.log(h.action_lengthscales)
        if self.tied:
            log_ls = log_ls.mean(axis=0)
            log_lx = log_lx.mean(axis=0)
        return np.concatenate(
            [
                latents.ravel(),
                np.log(h.signal_variance),
                np.log(h.noise_variance),
                log_ls.ravel(),
                log_lx.ravel(),
            ]
        )

    def join(
        self,
        latents: FloatArray,
        log_signal_variance: FloatArray,
        log_noise_variance: FloatArray,
        log_latent_lengthscales: FloatArray,
        log_action_lengthscales: FloatArray,
    ) -> FloatArray:
        """One vector of length :attr:`size` from its five groups, in :meth:`split`'s order
        (a gradient with respect to the packed vector is assembled this way).

        Args:
            latents: Shape (L, ds) or (L·ds,).
            log_signal_variance: Shape (dy,).
            log_noise_variance: Shape (dy,).
            log_latent_lengthscales: Shape (dy, ds) or (dy·ds,); (ds,) or (1, ds) when tied.
            log_action_lengthscales: Shape (dy, dx) or (dy·dx,); (dx,) or (1, dx) when tied.
        """
        vector = np.empty(self.size)
        vector[self.latents] = np.ravel(latents)
        vector[self.log_signal_variance] = log_signal_variance
        vector[self.log_noise_variance] = log_noise_variance
        vector[self.log_latent_lengthscales] = np.ravel(log_latent_lengthscales)
        vector[self.log_action_lengthscales] = np.ravel(log_action_lengthscales)
        return vector

    def split(
        self, vector: FloatArray
    ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray]:
        """Views of the groups: S (L, ds), log σ_f² (dy,), log σ_n² (dy,), log ℓ^s (dy, ds),
        log ℓ^x (dy, dx); the length-scales (1, ds) and (1, dx) when tied."""
        dy = self.lengthscale_rows
        return (
            vector[self.latents].reshape(self.n_objects, self.latent_dim),
            vector[self.log_signal_variance],
            vector[self.log_noise_variance],
            vector[self.log_latent_lengthscales].reshape(dy, self.latent_dim),
            vector[self.log_action_lengthscales].reshape(dy, self.action_dim),
        )

    def unpack(self, vector: FloatArray) -> tuple[FloatArray, Hyperparameters]:
        """S (L, ds) and the :class:`Hyperparameters` held in a packed vector."""
        vector = as_float_array(vector, "parameter vector", (self.size,))
        latents, log_sf, log_sn, log_ls, log_lx = self.split(vector)
        repeats = self.observation_dim if self.tied else 1  # the shared row, once per feature
        return latents.copy(), Hyperparameters(
            signal_variance=np.exp(log_sf),
            noise_variance=np.exp(log_sn),
            latent_lengthscales=np.repeat(np.exp(log_ls), repeats, axis=0),
            action_lengthscales=np.repeat(np.exp(log_lx), repeats, axis=0),
        )

    def names(self) -> tuple[str, ...]:
        """A readable name for every entry, e.g. ``noise_variance[feature 2]``."""
        names = [
            f"latent[object {obj}, dim {d}]"
            for obj in range(self.n_objects)
            for d in range(self.latent_dim)
        ]
        names += [f"signal_variance[feature {a}]" for a in range(self.observation_dim)]
        names += [f"noise_variance[feature {a}]" for a in range(self.observation_dim)]
        rows = (
            ["every feature"]
            if self.tied
            else [f"feature {a}" for a in range(self.observation_dim)]
        )
        names += [f"latent_lengthscale[{r}, dim {d}]" for r in rows for d in range(self.latent_dim)]
        names += [f"action_lengthscale[{r}, dim {d}]" for r in rows for d in range(self.action_dim)]
        return tuple(names)


def check_conditioning(
    data: TrainingData, latents: FloatArray, hyperparameters: Hyperparameters
) -> FloatArray:
    """The latents a posterior is conditioned on, checked against its data and hyperparameters.

    Every conditioning path (dense, Kronecker, sparse) starts here.

    Args:
        data: Training touches.
        latents: Object latents. Shape (L, ds), ds that of ``hyperparameters``.
        hyperparameters: Per-feature hyperparameters, for the data's dx and dy.

    Returns:
        The latents as a float array. Shape (L, ds).

    Raises:
        InvalidInputError: The latents' shape, or the hyperparameters' dx or dy, disagree.
    """
    h = hyperparameters
    latents = as_float_array(latents, "latents", (data.n_objects, h.latent_dim))
    if h.action_dim != data.action_dim or h.observation_dim != data.observation_dim:
        raise InvalidInputError(
            f"hyperparameters are for dx={h.action_dim}, dy={h.observation_dim} but the data "
            f"has dx={data.action_dim}, dy={data.observation_dim}."
        )
    return latents


def data_scales(data: TrainingData) -> tuple[FloatArray, FloatArray]:
    """var(y_a) per feature (dy,) and var(x_d) per action dimension (dx,), floored at 1e-12."""
    y_var = np.maximum(np.var(data.observations, axis=0), _TINY_VARIANCE)
    x_var = np.maximum(np.var(data.actions, axis=0), _TINY_VARIANCE)
    return np.asarray(y_var, dtype=np.float64), np.asarray(x_var, dtype=np.float64)


def parameter_bounds(
    data: TrainingData, layout: ParameterLayout, latent_bound: float
) -> tuple[FloatArray, FloatArray]:
    """Lower and upper bounds of the packed vector, relative to the data (docs/method.md defaults).

    Args:
        data: Training touches, for var(y) and var(x).
        layout: The packing.
        latent_bound: Latents are boxed in [-latent_bound, latent_bound] (they start with unit
            spread).

    Returns:
        lower, upper. Shape (layout.size,) each.
    """
    y_var, x_var = data_scales(data)
    lower = np.empty(layout.size)
    upper = np.empty(layout.size)
    lower[layout.latents], upper[layout.latents] = -latent_bound, latent_bound
    lower[layout.log_signal_variance] = np.log(SIGNAL_VARIANCE_RANGE[0] * y_var)
    upper[layout.log_signal_variance] = np.log(SIGNAL_VARIANCE_RANGE[1] * y_var)
    lower[layout.log_noise_variance] = np.log(NOISE_VARIANCE_RANGE[0] * y_var)
    upper[layout.log_noise_variance] = np.log(NOISE_VARIANCE_RANGE[1] * y_var)
    ls_low, ls_high = (0.5 * np.log(v) for v in LATENT_LENGTHSCALE_SQUARED_RANGE)
    lower[layout.log_latent_lengthscales] = ls_low
    upper[layout.log_latent_lengthscales] = ls_high
    x_low = 0.5 * np.log(ACTION_LENGTHSCALE_SQUARED_RANGE[0] * x_var)
    x_high = 0.5 * np.log(ACTION_LENGTHSCALE_SQUARED_RANGE[1] * x_var)
    lower[layout.log_action_lengthscales] = np.tile(x_low, layout.lengthscale_rows)
    upper[layout.log_action_lengthscales] = np.tile(x_high, layout.lengthscale_rows)
    return lower, upper


def initial_hyperparameters(
    data: TrainingData,
    latent_dim: int,
    latent_lengthscale: float = 10.0,
    noise_fraction: float = 0.1,
) -> Hyperparameters:
    """Starting hyperparameters for latents of unit spread.

    σ_f² = var(y_a), σ_n² = ``noise_fraction``·var(y_a), ℓ^x_d = std(x_d) and ℓ^s =
    ``latent_lengthscale`` (≈10× the latent spread: random starts then reach the best optimum
    far more often, docs/method.md recommended defaults).

    Args:
        data: Training touches.
        latent_dim: ds.
        latent_lengthscale: Initial latent length-scale (in units of the latent spread).
        noise_fraction: Initial noise variance as a fraction of var(y).
    """
    y_var, x_var = data_scales(data)
    dy = data.observation_dim
    return Hyperparameters(
        signal_variance=y_var.copy(),
        noise_variance=noise_fraction * y_var,
        latent_lengthscales=np.full((dy, latent_dim), float(latent_lengthscale)),
        action_lengthscales=np.tile(np.sqrt(x_var), (dy, 1)),
    )
