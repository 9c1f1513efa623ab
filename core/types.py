"""Frozen value types shared across :mod:`core`.

Notation follows ``docs/method.md``: L objects, N touches, ``dx`` action dimension, ``dy``
observation dimension (features), ``ds`` latent dimension.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from core.errors import CoreError, InvalidInputError
from core.features.pipeline import FeaturePipeline
from core.observation_transform import ObservationTransform
from core.validation import FloatArray, IntArray, as_float_array, require_positive, store_read_only


@dataclass(frozen=True)
class TrainingData:
    """Touches of known objects.

    Attributes:
        object_names: Names of the L objects, in latent order.
        object_index: Object of each touch, ``obj[i]`` in docs/method.md. Shape (N,), values in
            ``0..L-1``.
        actions: Action parameters x_i. Shape (N, dx).
        observations: Observed features y_i. Shape (N, dy).
        placement_index: Which placement of its object each touch met (the object was set
            down once and touched several times), or ``None`` when not recorded (every touch
            then counts as its own placement). Touches share a placement when they share both
            object and placement number. Shape (N,), values ≥ 0.
        touch_times_s: When each touch was made, in seconds on one clock (any origin), or
            ``None`` when not recorded. The slow drift of the sensor and the room is shared by
            touches made close together (:mod:`core.gp.drift_effect`). Shape (N,), finite.
        touch_duration_s: How long each touch lasted as planned, in seconds (the time scaling
            that turns an action into a trajectory; the same for every touch), or ``None`` when
            not recorded. The same action at another duration is another touch, so whoever
            touches to recognise (the rig world, the server's rig) must use this one.
        min_touches_per_object: The fewest touches an object may have: 2 for objects to learn
            (their latent needs more than one touch), 1 for the pseudo-objects of
            :mod:`core.gp.placement_latent` (one per placement, which may be touched once).
    """

    object_names: tuple[str, ...]
    object_index: IntArray
    actions: FloatArray
    observations: FloatArray
    placement_index: IntArray | None = None
    touch_times_s: FloatArray | None = None
    touch_duration_s: float | None = None
    min_touches_per_object: int = field(default=2, compare=False)

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
            if count < self.min_touches_per_object:
                raise InvalidInputError(
                    f"object {name!r} has {count} touch(es); every object needs at least "
                    f"{self.min_touches_per_object}."
                )
        object.__setattr__(self, "object_names", names)
        store_read_only(
            self, object_index=index.astype(np.int64), actions=actions, observations=observations
        )
        if self.placement_index is not None:
            placement = np.asarray(self.placement_index)
            if placement.shape != (n,) or not np.issubdtype(placement.dtype, np.integer):
                raise InvalidInputError(
                    f"placement_index: expected {n} integers, received dtype {placement.dtype} "
                    f"with shape {placement.shape}."
                )
            if n and placement.min() < 0:
                raise InvalidInputError(
                    f"placement_index: values must be ≥ 0, received {placement.min()}."
                )
            store_read_only(self, placement_index=placement.astype(np.int64))
        if self.touch_times_s is not None:
            times = as_float_array(self.touch_times_s, "touch_times_s", (n,))
            store_read_only(self, touch_times_s=times)
        if self.touch_duration_s is not None:
            duration = self.touch_duration_s
            if isinstance(duration, bool) or not isinstance(duration, int | float | np.floating):
                raise InvalidInputError(
                    f"touch_duration_s: expected a number of seconds, received {duration!r}."
                )
            if not (math.isfinite(duration) and duration > 0):
                raise InvalidInputError(
                    f"touch_duration_s: must be a finite number > 0, received {duration!r}."
                )
            object.__setattr__(self, "touch_duration_s", float(duration))

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

    @functools.cached_property
    def observation_mean(self) -> FloatArray:
        """Per-feature mean of the observations, the GP's constant mean (computed once: the
        observations are read-only; predictions read it per feature and object). Shape (dy,)."""
        mean = np.asarray(self.observations.mean(axis=0), dtype=np.float64)
        mean.flags.writeable = False
        return mean

    def touches_per_object(self) -> IntArray:
        """N_l for each object. Shape (L,)."""
        return np.bincount(self.object_index, minlength=self.n_objects).astype(np.int64)


@dataclass(frozen=True)
class Hyperparameters:
    """GP hyperparameters of every feature, stacked (docs/method.md eq. (M1)).

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
        arrays = {
            "signal_variance": signal,
            "noise_variance": noise,
            "latent_lengthscales": latent,
            "action_lengthscales": action,
        }
        for name, value in arrays.items():
            require_positive(value, name)
        store_read_only(self, **arrays)

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
        store_read_only(self, mean=mean, cov=cov)

    @property
    def dim(self) -> int:
        """ds."""
        return int(self.mean.shape[0])


#: Largest N for which a structured posterior materialises its dense K⁻¹ on request
#: (dy · N² floats; above this the structured consumers must be used).
DENSE_INVERSE_LIMIT = 6000

#: How a posterior represents K_a⁻¹ (see :class:`GPPosterior`).
PosteriorStructure = Literal["dense", "kronecker", "sparse"]


@dataclass(frozen=True)
class KroneckerFactors:
    """A shared-design posterior: K_a = σ_f,a² K^s_a ⊗ K^x_a + σ_n,a² I in its eigenbasis.

    Every object was touched with the same M design actions, so in grid order (object-major,
    touch (l, m) at position l·M + m) the Gram matrix is a Kronecker product plus noise
    (docs/method.md, "Shared action designs"). With K^s_a = U_s Λ_s U_sᵀ and K^x_a = U_x Λ_x U_xᵀ,
    K_a = (U_s ⊗ U_x) diag(D_a) (U_s ⊗ U_x)ᵀ where D_a[j, k] = σ_f,a² Λ_s[j] Λ_x[k] + σ_n,a²
    (+ jitter). Memory O(dy (L² + M² + L·M)).

    Attributes:
        design: The M design actions. Shape (M, dx).
        grid_index: Grid position l·M + m of every training touch (data order). Shape (N,).
        latent_eigenvalues: Λ_s of K^s_a. Shape (dy, L).
        latent_eigenvectors: U_s of K^s_a (columns). Shape (dy, L, L).
        action_eigenvalues: Λ_x of K^x_a. Shape (dy, M).
        action_eigenvectors: U_x of K^x_a (columns). Shape (dy, M, M).
        spectrum: D_a, the eigenvalues of the noisy K_a. Shape (dy, L, M).
        beta_grid: β_a = K_a⁻¹ (y_a - mean_a) in grid order, as an L × M matrix. Shape (dy, L, M).
    """

    design: FloatArray
    grid_index: IntArray
    latent_eigenvalues: FloatArray
    latent_eigenvectors: FloatArray
    action_eigenvalues: FloatArray
    action_eigenvectors: FloatArray
    spectrum: FloatArray
    beta_grid: FloatArray

    @property
    def n_design(self) -> int:
        """M, the number of design actions."""
        return int(self.design.shape[0])

    def dense_inverse(self) -> FloatArray:
        """K_a⁻¹ in data order, materialised. Shape (dy, N, N); O(dy · N²) memory."""
        dy = self.spectrum.shape[0]
        out = np.empty((dy, self.grid_index.shape[0], self.grid_index.shape[0]))
        for a in range(dy):
            basis = np.kron(self.latent_eigenvectors[a], self.action_eigenvectors[a])
            basis = basis[self.grid_index]  # rows in data order
            out[a] = (basis / self.spectrum[a].reshape(-1)) @ basis.T
        return out


@dataclass(frozen=True)
class InducingPoints:
    """Support points of a sparse (inducing-point) posterior.

    Each inducing point is a training touch's input (s_obj, x): its latent is that of its object
    (so it moves with S during a fit) and its action is the touch's action.

    Attributes:
        object_index: Object of every inducing point. Shape (m,).
        actions: Action of every inducing point. Shape (m, dx).
        touch_index: The training touch each was taken from. Shape (m,).
    """

    object_index: IntArray
    actions: FloatArray
    touch_index: IntArray

    @property
    def size(self) -> int:
        """m, the number of inducing points."""
        return int(self.object_index.shape[0])


@dataclass(frozen=True, init=False)
class GPPosterior:
    """Quantities of the conditioned GP that prediction and moment matching reuse.

    The GP's predictive at an input z* = (s*, x*) is mean_a + k_a(z*, Z)ᵀ β_a and variance
    σ_f,a² - k_a(z*, Z)ᵀ A_a k_a(z*, Z) (+ σ_n,a²), over support points Z with weights β and a
    matrix A. Three structures:

    * ``"dense"``: Z = the training touches, A_a = K_a⁻¹ stored densely.
    * ``"kronecker"``: Z = the training touches on a shared action design, A_a = K_a⁻¹ held as
      eigendecompositions (:class:`KroneckerFactors`); :attr:`gram_inverse` materialises it on
      request for N ≤ :data:`DENSE_INVERSE_LIMIT`.
    * ``"sparse"``: Z = inducing points (:class:`InducingPoints`), β_a the weights of the
      variational posterior and A_a = K_uu⁻¹ - (K_uu + σ_n⁻² K_uf K_fu)⁻¹ (see
      :mod:`core.gp.sparse`).

    Attributes:
        beta: β_a over the support points (the touches in data order, or the inducing points).
            Shape (dy, N) or (dy, m).
        jitter: Jitter added to the diagonal of each K_a (0 when none was needed). Shape (dy,).
        kronecker: The shared-design factors, or ``None``.
        inducing: The inducing points of a sparse posterior, or ``None``.
    """

    beta: FloatArray
    jitter: FloatArray
    kronecker: KroneckerFactors | None
    inducing: InducingPoints | None

    def __init__(
        self,
        beta: FloatArray,
        gram_inverse: FloatArray | None,
        jitter: FloatArray,
        kronecker: KroneckerFactors | None = None,
        inducing: InducingPoints | None = None,
    ) -> None:
        if gram_inverse is None and kronecker is None:
            raise InvalidInputError(
                "GPPosterior: needs gram_inverse (dense or sparse) or kronecker factors."
            )
        if kronecker is not None and inducing is not None:
            raise InvalidInputError("GPPosterior: kronecker and inducing are exclusive.")
        object.__setattr__(self, "beta", beta)
        object.__setattr__(self, "jitter", jitter)
        object.__setattr__(self, "kronecker", kronecker)
        object.__setattr__(self, "inducing", inducing)
        object.__setattr__(self, "_gram_inverse", gram_inverse)

    @property
    def structure(self) -> PosteriorStructure:
        """``"dense"``, ``"kronecker"`` or ``"sparse"``."""
        if self.kronecker is not None:
            return "kronecker"
        return "sparse" if self.inducing is not None else "dense"

    @property
    def gram_inverse(self) -> FloatArray:
        """A_a over the support points: K_a⁻¹ of the noisy Gram matrix (dense, Kronecker) or the
        sparse posterior's matrix. Shape (dy, N, N) or (dy, m, m).

        A Kronecker posterior materialises it on first use (and keeps it).

        Raises:
            CoreError: A Kronecker posterior with N > :data:`DENSE_INVERSE_LIMIT` (use the
                structured paths of :mod:`core.gp.kronecker` instead).
        """
        stored: FloatArray | None = getattr(self, "_gram_inverse")  # noqa: B009
        if stored is not None:
            return stored
        factors = self.kronecker
        assert factors is not None  # guaranteed by __init__
        n = int(factors.grid_index.shape[0])
        if n > DENSE_INVERSE_LIMIT:
            raise CoreError(
                f"gram_inverse: this Kronecker posterior has N = {n} touches; its dense K⁻¹ "
                f"(dy · N² floats) is not materialised above N = {DENSE_INVERSE_LIMIT}. Use the "
                f"structured functions of core.gp.kronecker."
            )
        dense = factors.dense_inverse()
        store_read_only(self, _gram_inverse=dense)
        return dense

    @property
    def has_dense_inverse(self) -> bool:
        """Whether :attr:`gram_inverse` is stored (or already materialised)."""
        return getattr(self, "_gram_inverse") is not None  # noqa: B009


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
        kernels: ``"per_feature"`` (every feature its own length-scales) or ``"tied"`` (the
            features shared them in the fit: ``FitOptions.kernels``).
    """

    starts_log_likelihood: tuple[float, ...]
    best_start: int
    iterations: int
    converged: bool
    message: str
    jitter_used: float
    hyperparameters_at_bounds: tuple[str, ...] = field(default_factory=tuple)
    kernels: str = "per_feature"


@dataclass(frozen=True)
class ManifoldModel:
    """A fitted object manifold: latent points, GP hyperparameters and the conditioned GP.

    Build it with :func:`core.gp.posterior.condition` (or by fitting), never by hand, so that the
    posterior matches the data, latents and hyperparameters.

    Attributes:
        data: The training touches.
        latents: s_l of every object, normalised (centred, RMS distance to the centre 1).
            Shape (L, ds).
        hyperparameters: Per-feature GP hyperparameters.
        posterior: β and K⁻¹ (or its structured form) of every feature.
        log_likelihood: Σ_a log p(y_a | S, X, γ_a) (docs/method.md eq. (M2)); with an observation
            transform, the log-likelihood of the raw observations: the model-space value plus
            N · log|det M| (the Jacobian, -½ log det Σ_ε per touch), so that models with
            different noise models are comparable.
        diagnostics: Fit diagnostics, ``None`` for a model that was not fitted here.
        transform: The map y' = M (y - c) from raw observations to the space the GPs model
            (:mod:`core.observation_transform`); ``None`` means the identity. ``data`` holds the
            transformed observations, :attr:`raw_data` the raw ones.
        source_data: The raw training touches when ``transform`` is not ``None`` (``None``
            otherwise: ``data`` is raw).
        placement_variance: σ_b,a², the variance of the offset shared by the touches of one
            placement, per model-space feature (:mod:`core.gp.placement_effect`); ``None`` (or all
            zero) when not estimated: the touches of a trial are then independent given the
            object. Shape (dy,).
        placement_in_fit: Whether σ_b² is also in the training covariance the posterior was
            conditioned with (touches of one training placement share an offset,
            :func:`core.gp.posterior.condition`); ``False``: the training touches' noise was
            taken as independent and σ_b² only enters the scoring of a trial.
        object_placement_variance: σ_b,l,a², each object's own placement variance
            (:mod:`core.gp.object_placement`, shrunk towards ``placement_variance``): a trial is
            scored under object l with row l in place of σ_b²; the training covariance keeps the
            pooled σ_b². ``None``: every object has ``placement_variance``. Shape (L, dy).
        latent_covariance: Σ_l, the Laplace covariance of every object's latent point
            (:mod:`core.recognition.latent_uncertainty`, docs/method.md (L1)); ``None``: the latents
            are taken as known and the object likelihood uses them as points. Shape (L, ds, ds).
        tempering: β in (0, 1], the exponent on the object likelihood fitted by
            cross-validation on the training touches (:mod:`core.recognition.tempering`, a last
            resort); ``None``: untempered.
        features: The feature pipeline that turns a raw touch into y
            (:mod:`core.features.pipeline`); ``None``: y is given as it is (the channel means).
        drift_variance: σ_d,a², the variance of the slow drift shared by a trial's touches
            (made within a minute or two) whatever the placement, per model-space feature
            (:mod:`core.gp.drift_effect`); a part of σ_n,a², like σ_b² under (C2). ``None``:
            not estimated (the training touches' times were not recorded). Shape (dy,).
        shift_variance: σ_δ,k², the variance of a placement's shift of the action, per action
            dimension (:mod:`core.gp.input_shift`): under object l the touches of one placement
            share J_l(x_t) diag(σ_δ²) J_l(x_u)ᵀ through the slope of the mean. ``None``: not
            estimated. Shape (dx,).
        shift_creep_variance: σ_c,k², the variance the shift gains at each touch of a placement
            after its first (:mod:`core.gp.input_shift`): touches t, u of one placement share
            J_l(x_t) diag(σ_δ² + σ_c² min(t, u)) J_l(x_u)ᵀ. ``None``: no creep (not estimated,
            or no runs of three touches to estimate it from). Shape (dx,).
    """

    data: TrainingData
    latents: FloatArray
    hyperparameters: Hyperparameters
    posterior: GPPosterior
    log_likelihood: float
    diagnostics: FitDiagnostics | None = None
    transform: ObservationTransform | None = None
    source_data: TrainingData | None = None
    placement_variance: FloatArray | None = None
    placement_in_fit: bool = False
    features: FeaturePipeline | None = None
    latent_covariance: FloatArray | None = None
    tempering: float | None = None
    drift_variance: FloatArray | None = None
    shift_variance: FloatArray | None = None
    shift_creep_variance: FloatArray | None = None
    object_placement_variance: FloatArray | None = None

    @property
    def raw_data(self) -> TrainingData:
        """The training touches in raw units (what was recorded)."""
        return self.source_data if self.source_data is not None else self.data

    @property
    def observation_transform(self) -> ObservationTransform:
        """The observation transform (the identity when none was applied)."""
        if self.transform is not None:
            return self.transform
        return ObservationTransform.identity(self.data.observation_dim)

    def to_model_space(self, observations: FloatArray) -> FloatArray:
        """Raw observations (n, dy) → the space the GPs model, y' = M (y - c). Shape (n, dy)."""
        if self.transform is None:
            return as_float_array(observations, "observations", (None, self.data.observation_dim))
        return self.transform.apply(observations)

    @property
    def latent_dim(self) -> int:
        """ds."""
        return int(self.latents.shape[1])

    @property
    def object_names(self) -> tuple[str, ...]:
        """Names of the L objects."""
        return self.data.object_names
