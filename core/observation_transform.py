"""The affine map from raw observations to the space the per-feature GPs model.

docs/method.md, "Real tactile data": with correlated channel noise the per-feature GPs are fitted to
y' = M (y - c), where M = W · diag(1/scale) standardises each feature and then whitens the noise
(W = Σ_z^{-1/2}, Σ_z the noise covariance of the standardised features). Everything downstream —
moments, mutual information, the belief update, the object posterior — works in y'; raw
observations are mapped at the entry (:meth:`ObservationTransform.apply`) and predictions back
(:meth:`ObservationTransform.restore_mean`, :meth:`ObservationTransform.restore_covariance`).
Densities in raw units pick up the Jacobian log|det M| = -½ log det Σ_ε per touch.

Kinds: ``"identity"`` (M = I, c = 0: models fitted before the transform existed), ``"independent"``
(standardisation only, W = I) and ``"correlated"`` (standardisation and whitening).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from core.errors import InvalidInputError
from core.validation import FloatArray, as_float_array, store_read_only

#: What a transform did: nothing, standardise, or standardise and whiten the noise.
TransformKind = Literal["identity", "independent", "correlated"]
TRANSFORM_KINDS: tuple[str, ...] = ("identity", "independent", "correlated")


@dataclass(frozen=True, eq=False)
class ObservationTransform:
    """y' = W · ((y - offset) / scale): standardise each feature, then whiten the noise.

    Attributes:
        kind: ``"identity"``, ``"independent"`` or ``"correlated"``.
        offset: c, subtracted from every observation. Shape (dy,).
        scale: Per-feature divisor (a standard deviation). Shape (dy,), > 0.
        whitening: W, applied after standardising; the identity unless ``"correlated"``.
            Shape (dy, dy), invertible.
        correlation: The noise correlation that W whitens (the identity unless
            ``"correlated"``). Shape (dy, dy).
        note: How the transform was chosen (for reports).
        matrix: M = W · diag(1/scale), so y' = M (y - c). Shape (dy, dy). Derived.
        inverse: M⁻¹. Shape (dy, dy). Derived.
        log_jacobian: log|det M|, the change of a touch's log-density from y' to y. Derived.
    """

    kind: TransformKind
    offset: FloatArray
    scale: FloatArray
    whitening: FloatArray
    correlation: FloatArray
    note: str = ""
    matrix: FloatArray = field(init=False, repr=False)
    inverse: FloatArray = field(init=False, repr=False)
    log_jacobian: float = field(init=False)

    def __post_init__(self) -> None:
        if self.kind not in TRANSFORM_KINDS:
            raise InvalidInputError(
                f"transform kind: expected one of {', '.join(TRANSFORM_KINDS)}, received "
                f"{self.kind!r}."
            )
        offset = as_float_array(self.offset, "transform offset", (None,))
        dy = offset.shape[0]
        scale = as_float_array(self.scale, "transform scale", (dy,))
        whitening = as_float_array(self.whitening, "transform whitening", (dy, dy))
        correlation = as_float_array(self.correlation, "transform correlation", (dy, dy))
        if np.any(scale <= 0):
            raise InvalidInputError(f"transform scale: every entry must be > 0, received {scale}.")
        matrix = whitening / scale[None, :]
        sign, log_det = np.linalg.slogdet(matrix)
        if sign == 0 or not np.isfinite(log_det):
            raise InvalidInputError("transform whitening: must be invertible.")
        inverse = np.linalg.inv(matrix)
        store_read_only(
            self,
            offset=offset,
            scale=scale,
            whitening=whitening,
            correlation=correlation,
            matrix=matrix,
            inverse=inverse,
        )
        object.__setattr__(self, "log_jacobian", float(log_det))

    @classmethod
    def identity(cls, observation_dim: int) -> ObservationTransform:
        """The transform that changes nothing (M = I, c = 0)."""
        eye = np.eye(observation_dim)
        ones = np.ones(observation_dim)
        return cls("identity", np.zeros(observation_dim), ones, eye, eye.copy(), "")

    @property
    def dim(self) -> int:
        """dy."""
        return int(self.offset.shape[0])

    @property
    def is_identity(self) -> bool:
        """Whether y' = y exactly."""
        return bool(
            np.all(self.offset == 0.0)
            and np.all(self.scale == 1.0)
            and np.array_equal(self.whitening, np.eye(self.dim))
        )

    def apply(self, observations: FloatArray) -> FloatArray:
        """y' = M (y - c) for every row.

        Args:
            observations: Raw observations. Shape (n, dy).

        Returns:
            Model-space observations. Shape (n, dy).
        """
        y = as_float_array(observations, "observations", (None, self.dim))
        if self.is_identity:
            return y.copy()
        return np.asarray((y - self.offset) @ self.matrix.T, dtype=np.float64)

    def restore_mean(self, mean: FloatArray) -> FloatArray:
        """Raw-unit mean M⁻¹ m' + c of model-space means. Shape (n, dy) → (n, dy)."""
        m = as_float_array(mean, "model-space mean", (None, self.dim))
        if self.is_identity:
            return m.copy()
        return np.asarray(m @ self.inverse.T + self.offset, dtype=np.float64)

    def restore_covariance(self, covariance: FloatArray) -> FloatArray:
        """Raw-unit covariance M⁻¹ S' M⁻ᵀ of model-space covariances. Shape (..., dy, dy)."""
        s = np.asarray(covariance, dtype=np.float64)
        if s.shape[-2:] != (self.dim, self.dim):
            raise InvalidInputError(
                f"model-space covariance: expected shape (..., {self.dim}, {self.dim}), "
                f"received {s.shape}."
            )
        return np.asarray(self.inverse @ s @ self.inverse.T, dtype=np.float64)

    def restore_variance(self, variance: FloatArray) -> FloatArray:
        """Raw-unit marginal variances of independent model-space variances.

        diag(M⁻¹ diag(v') M⁻ᵀ) for every row.

        Args:
            variance: Model-space variances (features independent). Shape (n, dy).

        Returns:
            Raw-unit variance of each feature. Shape (n, dy).
        """
        v = as_float_array(variance, "model-space variance", (None, self.dim))
        if self.is_identity:
            return v.copy()
        return np.asarray(v @ (self.inverse**2).T, dtype=np.float64)
