"""The feature pipeline a model carries: raw touch → reducers → standardise → PCA → y (dy,).

Two kinds:

``"means"``: y is the mean of each channel over the touch (a vector channel gives one mean per
element): the paper's observation, kept for models fitted that way.

``"whole"``: every channel is reduced by well-known summaries (:mod:`core.features.reducers`)
according to its role, decided from the first training touch:

- a *vector* channel (an electrode array, width w): its normalised pattern (w), its level (the
  norm of the per-element means), and each element's standard deviation and slope (2w);
- a scalar channel sampled at ``vibration_min_rate_hz`` or faster (a *vibration* channel):
  mean, RMS, standard deviation, slope, the log power in ``n_bands`` logarithmically spaced bands
  from the first Welch bin to Nyquist, and the spectral centroid;
- any other scalar channel: mean, RMS, standard deviation and slope.

The reduced features are standardised with the training touches' mean and standard deviation,
and projected on their first dy principal components (PCA by SVD) or, when it measurably
recognises better, on their first dy linear discriminants (LDA: between-object against pooled
within-object scatter, dy ≤ L − 1). The projection and dy are chosen by cross-validated
recognition (:func:`select_feature_dim`) unless given. PCA keeps what varies most, including what
varies with the action; LDA keeps what separates the objects on average, and sees the action's
effect as spread — so PCA is kept unless LDA does better by more than the folds' noise.

Pure maths: the touches come in as arrays, randomness as a seed.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from core.errors import InvalidInputError
from core.features import reducers
from core.features.raw import RawChannel, RawTouch, check_same_layout
from core.validation import FloatArray, IntArray

FeatureKind = Literal["means", "whole"]
FEATURE_KINDS: tuple[FeatureKind, ...] = ("means", "whole")
ChannelRole = Literal["scalar", "vibration", "array"]
Projection = Literal["pca", "lda"]
PROJECTIONS: tuple[Projection, ...] = ("pca", "lda")

#: Candidate feature dimensions tried by :func:`select_feature_dim` (those ≤ the largest allowed).
FEATURE_DIM_CANDIDATES: tuple[int, ...] = (1, 2, 3, 4, 5, 6, 8, 10, 12, 15, 20, 25, 30)


@dataclass(frozen=True)
class FeatureSettings:
    """Settings of the ``"whole"`` pipeline.

    Attributes:
        n_bands: Log-spaced bands of each vibration channel's spectrum.
        vibration_min_rate_hz: A scalar channel sampled at least this fast is a vibration
            channel (gets band powers and a spectral centroid).
        segment_samples: Samples per Welch segment; a vibration series needs at least this many.
        min_samples: Samples every other channel needs (standard deviation and slope).
        max_feature_dim: Largest dy considered.
        folds: Folds of the cross-validation that chooses dy.
    """

    n_bands: int = 6
    vibration_min_rate_hz: float = 500.0
    segment_samples: int = 256
    min_samples: int = 4
    max_feature_dim: int = 30
    folds: int = 5

    def __post_init__(self) -> None:
        for name in ("n_bands", "segment_samples", "max_feature_dim"):
            if getattr(self, name) < 1:
                raise InvalidInputError(f"{name}: must be ≥ 1, received {getattr(self, name)}.")
        if self.min_samples < 2:
            raise InvalidInputError(f"min_samples: must be ≥ 2, received {self.min_samples}.")
        if self.folds < 2:
            raise InvalidInputError(f"folds: must be ≥ 2, received {self.folds}.")
        if not self.vibration_min_rate_hz > 0:
            raise InvalidInputError(
                f"vibration_min_rate_hz: must be > 0, received {self.vibration_min_rate_hz}."
            )


@dataclass(frozen=True)
class ChannelPlan:
    """How one channel is reduced.

    Attributes:
        name: Channel name.
        role: ``"scalar"``, ``"vibration"`` or ``"array"``.
        width: Elements per sample (0 for a scalar channel).
        band_edges_hz: Band edges of a vibration channel (n_bands + 1), else empty.
    """

    name: str
    role: ChannelRole
    width: int = 0
    band_edges_hz: tuple[float, ...] = ()


@dataclass(frozen=True)
class FeatureDimScore:
    """Cross-validated recognition of one feature dimension.

    Attributes:
        feature_dim: dy.
        projection: ``"pca"`` or ``"lda"``.
        fold_scores: Share of held-out touches recognised in each fold.
        mean: Mean of ``fold_scores``.
        standard_error: Standard error of ``mean`` over the folds.
        difference: Mean over folds of this candidate's score minus the best candidate's.
        difference_standard_error: Standard error of ``difference`` (0 for the best).
    """

    feature_dim: int
    projection: Projection
    fold_scores: tuple[float, ...]
    mean: float
    standard_error: float
    difference: float
    difference_standard_error: float


@dataclass(frozen=True)
class FeatureSelection:
    """How dy was chosen: the candidates' scores, the choice and why.

    Attributes:
        chosen: The dy kept (smallest within one standard error of the best, PCA first).
        projection: The projection kept.
        best: The dy with the best mean score.
        best_projection: Its projection.
        n_folds: Folds used.
        candidates: Score of each candidate, increasing dy.
        explanation: One sentence on the choice.
    """

    chosen: int
    projection: Projection
    best: int
    best_projection: Projection
    n_folds: int
    candidates: tuple[FeatureDimScore, ...]
    explanation: str


@dataclass(frozen=True)
class FeaturePipeline:
    """A fitted feature pipeline: what turns a raw touch into the model's observation y.

    Attributes:
        kind: ``"means"`` or ``"whole"``.
        channels: How each channel is reduced, in order (the touches' channel layout).
        reduced_names: Name of each reduced feature. Length R.
        settings: Settings of the ``"whole"`` pipeline.
        center: Mean of each reduced feature over the training touches. Shape (R,) (``"whole"``).
        scale: Their standard deviation (1 where it was 0). Shape (R,) (``"whole"``).
        components: Projection axes of the standardised features. Shape (R, dy)
            (``"whole"``): orthonormal principal axes, or discriminant axes scaled to unit
            pooled within-object variance.
        explained_variance: Variance of the standardised training features along each axis.
            Shape (dy,) (``"whole"``).
        projection: ``"pca"`` or ``"lda"`` (``"whole"``).
        selection: How dy was chosen, if it was.
    """

    kind: FeatureKind
    channels: tuple[ChannelPlan, ...]
    reduced_names: tuple[str, ...]
    settings: FeatureSettings = field(default_factory=FeatureSettings)
    center: FloatArray | None = None
    scale: FloatArray | None = None
    components: FloatArray | None = None
    explained_variance: FloatArray | None = None
    selection: FeatureSelection | None = None
    projection: Projection = "pca"

    def __post_init__(self) -> None:
        if self.projection not in PROJECTIONS:
            raise InvalidInputError(
                f"projection: expected one of {PROJECTIONS}, received {self.projection!r}."
            )
        if self.kind not in FEATURE_KINDS:
            raise InvalidInputError(
                f"kind: expected one of {FEATURE_KINDS}, received {self.kind!r}."
            )
        n = len(self.reduced_names)
        if self.kind == "whole":
            center, scale = self.center, self.scale
            components, variance = self.components, self.explained_variance
            if center is None or scale is None or components is None or variance is None:
                raise InvalidInputError(
                    "a 'whole' feature pipeline needs center, scale, components and "
                    "explained_variance."
                )
            if center.shape != (n,) or scale.shape != (n,):
                raise InvalidInputError(
                    f"center and scale: expected shape ({n},), received {center.shape} "
                    f"and {scale.shape}."
                )
            if components.ndim != 2 or components.shape[0] != n:
                raise InvalidInputError(
                    f"components: expected shape ({n}, dy), received {components.shape}."
                )
            if variance.shape != (components.shape[1],):
                raise InvalidInputError("explained_variance: one value per component expected.")
            if np.any(scale <= 0):
                raise InvalidInputError("scale: every entry must be positive.")

    @property
    def output_dim(self) -> int:
        """dy: length of the observation y."""
        if self.components is not None:
            return int(self.components.shape[1])
        return len(self.reduced_names)

    @property
    def output_names(self) -> tuple[str, ...]:
        """Names of the features of y."""
        if self.kind == "means":
            return self.reduced_names
        return tuple(f"pc_{k + 1}" for k in range(self.output_dim))

    def min_samples(self, plan: ChannelPlan) -> int:
        """The shortest series this pipeline accepts on channel ``plan``."""
        return window_samples(self.kind, plan.role, self.settings)

    def check(self, touch: RawTouch) -> None:
        """Require the channel layout and series lengths this pipeline needs.

        Raises:
            InvalidInputError: A channel missing, extra, of another width, or shorter than the
                pipeline's window (the message names the channel).
        """
        names = tuple(p.name for p in self.channels)
        missing = [n for n in names if n not in touch.names]
        extra = [n for n in touch.names if n not in names]
        if missing or extra:
            raise InvalidInputError(
                f"the channel set differs from the model's ({list(names)}): missing {missing}, "
                f"extra {extra}."
            )
        for plan in self.channels:
            channel = touch.channel(plan.name)
            width = channel.width if channel.is_vector else 0
            if width != plan.width:
                raise InvalidInputError(
                    f"channel {plan.name!r}: width {width or 'scalar'}, the model's is "
                    f"{plan.width or 'scalar'}."
                )
            needed = self.min_samples(plan)
            if channel.n_samples < needed:
                raise InvalidInputError(
                    f"channel {plan.name!r}: {channel.n_samples} samples, shorter than the "
                    f"pipeline's window of {needed}."
                )

    def reduce(self, touch: RawTouch) -> FloatArray:
        """The reduced features of a touch (before standardisation). Shape (R,).

        Raises:
            InvalidInputError: See :meth:`check`.
        """
        self.check(touch)
        parts = [
            _reduce_channel(plan, touch.channel(plan.name), self.kind, self.settings)
            for plan in self.channels
        ]
        return np.concatenate(parts)

    def transform(self, touch: RawTouch) -> FloatArray:
        """y: the observation of a touch. Shape (dy,).

        Raises:
            InvalidInputError: See :meth:`check`.
        """
        reduced = self.reduce(touch)
        if self.kind == "means":
            return reduced
        return np.asarray(self.project(reduced[None, :])[0], dtype=np.float64)

    def transform_many(self, touches: Sequence[RawTouch]) -> FloatArray:
        """y of each touch. Shape (N, dy).

        Raises:
            InvalidInputError: A touch the pipeline refuses; the message starts with its index.
        """
        rows = []
        for k, touch in enumerate(touches):
            try:
                rows.append(self.transform(touch))
            except InvalidInputError as exc:
                raise InvalidInputError(f"touch {k + 1}: {exc}") from None
        return np.asarray(rows, dtype=np.float64).reshape(len(rows), self.output_dim)

    def project(self, reduced: FloatArray) -> FloatArray:
        """Standardise and project reduced features. (N, R) → (N, dy)."""
        if self.center is None or self.scale is None or self.components is None:
            return reduced
        return np.asarray(((reduced - self.center) / self.scale) @ self.components)


def window_samples(kind: FeatureKind, role: ChannelRole, settings: FeatureSettings) -> int:
    """The shortest series a pipeline of ``kind`` accepts on a channel of ``role``: one Welch
    segment for a vibration channel and ``min_samples`` for any other with ``"whole"``, one
    sample with ``"means"``."""
    if kind == "means":
        return 1
    if role == "vibration":
        return settings.segment_samples
    return settings.min_samples


def check_touches(
    touches: Sequence[RawTouch], kind: FeatureKind, settings: FeatureSettings | None = None
) -> None:
    """Require touches a pipeline of ``kind`` can be fitted to: one channel layout (the first
    touch's) and every series at least its window (:func:`window_samples`) long.

    Raises:
        InvalidInputError: The first touch that fails, as ``touch k: channel 'NAME': …``.
    """
    settings = settings or FeatureSettings()
    if kind not in FEATURE_KINDS:
        raise InvalidInputError(f"kind: expected one of {FEATURE_KINDS}, received {kind!r}.")
    if len(touches) == 0:
        raise InvalidInputError("touches: at least one touch is needed.")
    plans = plan_channels(touches[0], settings)
    for k, touch in enumerate(touches, start=1):
        try:
            check_same_layout(touches[0], touch)
            for plan in plans:
                channel = touch.channel(plan.name)
                needed = window_samples(kind, plan.role, settings)
                if channel.n_samples < needed:
                    raise InvalidInputError(
                        f"channel {plan.name!r}: {channel.n_samples} samples, shorter than the "
                        f"pipeline's window of {needed}."
                    )
        except InvalidInputError as exc:
            raise InvalidInputError(f"touch {k}: {exc}") from None


def plan_channels(touch: RawTouch, settings: FeatureSettings) -> tuple[ChannelPlan, ...]:
    """Each channel's role, from one touch: array if vector, vibration if sampled fast enough."""
    plans = []
    for channel in touch.channels:
        if channel.is_vector:
            plans.append(ChannelPlan(channel.name, "array", channel.width))
        elif channel.rate_hz >= settings.vibration_min_rate_hz:
            edges = reducers.log_band_edges(
                channel.rate_hz, settings.segment_samples, settings.n_bands
            )
            plans.append(ChannelPlan(channel.name, "vibration", 0, tuple(float(e) for e in edges)))
        else:
            plans.append(ChannelPlan(channel.name, "scalar"))
    return tuple(plans)


def reduced_feature_names(plans: Sequence[ChannelPlan], kind: FeatureKind) -> tuple[str, ...]:
    """Names of the reduced features, in the order :meth:`FeaturePipeline.reduce` gives them."""
    names: list[str] = []
    for plan in plans:
        elements = [f"{plan.name}[{i}]" for i in range(plan.width)] or [plan.name]
        if kind == "means":
            names += elements
            continue
        if plan.role == "array":
            names += [f"pattern:{e}" for e in elements] + [f"level:{plan.name}"]
            names += [f"std:{e}" for e in elements] + [f"slope:{e}" for e in elements]
            continue
        names += [f"{r}:{plan.name}" for r in ("mean", "rms", "std", "slope")]
        if plan.role == "vibration":
            edges = plan.band_edges_hz
            names += [
                f"log_power:{plan.name}:{lo:.0f}-{hi:.0f}Hz" for lo, hi in itertools.pairwise(edges)
            ]
            names.append(f"centroid_hz:{plan.name}")
    return tuple(names)


def _reduce_channel(
    plan: ChannelPlan, channel: RawChannel, kind: FeatureKind, settings: FeatureSettings
) -> FloatArray:
    series = channel.samples
    if kind == "means":
        return reducers.mean(series)
    if plan.role == "array":
        level = float(np.linalg.norm(reducers.mean(series)))
        return np.concatenate(
            [
                reducers.normalised_pattern(series),
                [level],
                reducers.std(series),
                reducers.slope(series, channel.rate_hz),
            ]
        )
    parts = [
        reducers.mean(series),
        reducers.rms(series),
        reducers.std(series),
        reducers.slope(series, channel.rate_hz),
    ]
    if plan.role == "vibration":
        freqs, psd = reducers.welch_spectrum(series, channel.rate_hz, settings.segment_samples)
        edges = np.asarray(plan.band_edges_hz, dtype=np.float64)
        parts += [
            reducers.log_band_powers(freqs, psd, edges),
            np.array([reducers.spectral_centroid(freqs, psd)]),
        ]
    return np.concatenate(parts)


def means_pipeline(touch: RawTouch) -> FeaturePipeline:
    """The ``"means"`` pipeline for touches laid out like ``touch``."""
    plans = plan_channels(touch, FeatureSettings())
    return FeaturePipeline("means", plans, reduced_feature_names(plans, "means"))


def _check_touches(touches: Sequence[RawTouch], object_index: IntArray) -> None:
    if len(touches) == 0:
        raise InvalidInputError("touches: at least one touch is needed.")
    if object_index.shape != (len(touches),):
        raise InvalidInputError(
            f"object_index: expected shape ({len(touches)},), received {object_index.shape}."
        )
    for k, touch in enumerate(touches[1:], start=2):
        try:
            check_same_layout(touches[0], touch)
        except InvalidInputError as exc:
            raise InvalidInputError(f"touch {k}: {exc}") from None


def standardise(reduced: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Mean and standard deviation of each column (1 where it is 0). (N, R) → (R,), (R,)."""
    center = reduced.mean(axis=0)
    scale = reduced.std(axis=0)
    scale = np.where(scale > 1e-12 * np.maximum(1.0, np.abs(center)), scale, 1.0)
    return np.asarray(center, dtype=np.float64), np.asarray(scale, dtype=np.float64)


def principal_axes(standardised: FloatArray, dim: int) -> tuple[FloatArray, FloatArray]:
    """The first ``dim`` principal axes of centred rows, and the variance along each.

    Each axis's sign is fixed (its largest-magnitude entry positive), so the result does not
    depend on the SVD routine's sign choice.

    Args:
        standardised: Centred rows. Shape (N, R).
        dim: Axes kept, ≤ min(N, R).

    Returns:
        Axes, shape (R, dim), orthonormal columns; variances, shape (dim,).
    """
    _, singular, vt = np.linalg.svd(standardised, full_matrices=False)
    axes = vt[:dim].T.copy()
    signs = np.sign(axes[np.argmax(np.abs(axes), axis=0), np.arange(dim)])
    axes *= np.where(signs == 0, 1.0, signs)
    variance = singular[:dim] ** 2 / standardised.shape[0]
    return np.asarray(axes, dtype=np.float64), np.asarray(variance, dtype=np.float64)


def discriminant_axes(
    standardised: FloatArray, object_index: IntArray, dim: int
) -> tuple[FloatArray, FloatArray]:
    """The first ``dim`` linear discriminants (Fisher's LDA) of standardised rows.

    Solves S_b v = λ S_w v (:func:`scipy.linalg.eigh`) for the between-object scatter S_b of the
    object means and the pooled within-object covariance S_w, shrunk by 5 % of its mean
    variance towards a multiple of the identity so that it stays invertible with many
    features; each axis v has vᵀ S_w v = 1 (unit within-object variance). S_w is shrunk towards
    its mean variance times the identity by R / (R + N − L): much when there are few touches
    per feature, little when there are many, so that it stays invertible and does not fit noise.

    Args:
        standardised: Centred rows. Shape (N, R).
        object_index: Object of each row. Shape (N,).
        dim: Axes kept, ≤ L − 1 and ≤ R.

    Returns:
        Axes, shape (R, dim); the variance of the rows along each, shape (dim,).
    """
    from scipy import linalg

    classes = np.unique(object_index)
    if not 1 <= dim <= min(len(classes) - 1, standardised.shape[1]):
        raise InvalidInputError(
            f"LDA: dy must be between 1 and L − 1 = {len(classes) - 1}, received {dim}."
        )
    means = np.stack([standardised[object_index == c].mean(axis=0) for c in classes])
    counts = np.array([np.sum(object_index == c) for c in classes], dtype=np.float64)
    residuals = standardised - means[np.searchsorted(classes, object_index)]
    within = residuals.T @ residuals / max(1, len(standardised) - len(classes))
    dof = max(1, len(standardised) - len(classes))
    shrinkage = within.shape[0] / (within.shape[0] + dof)
    target = float(np.trace(within)) / within.shape[0] * np.eye(within.shape[0])
    within = (1.0 - shrinkage) * within + shrinkage * target
    between = (means * counts[:, None]).T @ means / counts.sum()
    values, vectors = linalg.eigh(between, within)
    axes = vectors[:, np.argsort(values)[::-1][:dim]]
    signs = np.sign(axes[np.argmax(np.abs(axes), axis=0), np.arange(dim)])
    axes = axes * np.where(signs == 0, 1.0, signs)
    variance = np.var(standardised @ axes, axis=0)
    return np.asarray(axes, dtype=np.float64), np.asarray(variance, dtype=np.float64)


def projection_axes(
    projection: Projection, standardised: FloatArray, object_index: IntArray, dim: int
) -> tuple[FloatArray, FloatArray]:
    """:func:`principal_axes` or :func:`discriminant_axes`."""
    if projection == "lda":
        return discriminant_axes(standardised, object_index, dim)
    return principal_axes(standardised, dim)


def largest_feature_dim(settings: FeatureSettings, n_touches: int, n_reduced: int) -> int:
    """The largest dy the data allow: ≤ max_feature_dim, R and N − 1."""
    return max(1, min(settings.max_feature_dim, n_reduced, n_touches - 1))


def fit_features(
    touches: Sequence[RawTouch],
    object_index: IntArray,
    kind: FeatureKind = "whole",
    settings: FeatureSettings | None = None,
    feature_dim: int | None = None,
    seed: int = 0,
    projection: Projection | None = None,
) -> FeaturePipeline:
    """Fit the feature pipeline on training touches.

    Args:
        touches: The training touches, one channel layout. Length N.
        object_index: Object of each touch (for choosing dy). Shape (N,).
        kind: ``"means"`` or ``"whole"``.
        settings: Settings of the ``"whole"`` pipeline.
        feature_dim: dy; ``None`` chooses it (and the projection, unless given) by
            :func:`select_feature_dim`.
        seed: Seed of the cross-validation folds.
        projection: ``"pca"`` or ``"lda"``; ``None``: chosen with dy, or PCA when dy is given.

    Raises:
        InvalidInputError: Touches of different channel layouts, a series shorter than the
            pipeline's window (naming the touch and the channel), or a dy out of range.
    """
    settings = settings or FeatureSettings()
    object_index = np.asarray(object_index, dtype=np.int64)
    _check_touches(touches, object_index)
    plans = plan_channels(touches[0], settings)
    names = reduced_feature_names(plans, kind)
    if kind == "means":
        pipeline = FeaturePipeline("means", plans, names, settings)
        pipeline.transform_many(touches)  # refuses what it cannot read
        return pipeline
    empty = np.zeros(len(names))
    template = FeaturePipeline(
        "whole",
        plans,
        names,
        settings,
        empty,
        np.ones(len(names)),
        np.eye(len(names), 1),
        np.ones(1),
    )
    reduced = np.empty((len(touches), len(names)))
    for k, touch in enumerate(touches):
        try:
            reduced[k] = template.reduce(touch)
        except InvalidInputError as exc:
            raise InvalidInputError(f"touch {k + 1}: {exc}") from None
    largest = largest_feature_dim(settings, len(touches), len(names))
    selection = None
    if feature_dim is None:
        selection = select_feature_dim(reduced, object_index, settings, seed, projection)
        feature_dim, projection = selection.chosen, selection.projection
    projection = projection or "pca"
    if not 1 <= feature_dim <= largest:
        raise InvalidInputError(
            f"feature_dim: must be between 1 and {largest} (max_feature_dim, {len(names)} reduced "
            f"features, {len(touches)} touches − 1), received {feature_dim}."
        )
    center, scale = standardise(reduced)
    components, variance = projection_axes(
        projection, (reduced - center) / scale, object_index, feature_dim
    )
    return FeaturePipeline(
        "whole",
        plans,
        names,
        settings,
        center,
        scale,
        components,
        variance,
        selection,
        projection,
    )


def _fold_of_each_touch(object_index: IntArray, folds: int, seed: int) -> IntArray:
    """Deal each object's touches, in a shuffled order, round-robin to the folds."""
    rng = np.random.default_rng(seed)
    fold = np.empty(len(object_index), dtype=np.int64)
    for obj in np.unique(object_index):
        members = np.flatnonzero(object_index == obj)
        rng.shuffle(members)
        fold[members] = np.arange(len(members)) % folds
    return fold


def gaussian_classify(train: FloatArray, train_index: IntArray, test: FloatArray) -> IntArray:
    """Nearest class mean under one pooled covariance (linear discriminant, equal priors).

    Args:
        train: Training features. Shape (N, d).
        train_index: Class of each. Shape (N,).
        test: Features to classify. Shape (M, d).

    Returns:
        The class picked for each test row. Shape (M,).
    """
    classes = np.unique(train_index)
    means = np.stack([train[train_index == c].mean(axis=0) for c in classes])
    residuals = train - means[np.searchsorted(classes, train_index)]
    covariance = residuals.T @ residuals / max(1, len(train) - len(classes))
    ridge = 1e-6 * max(float(np.trace(covariance)) / covariance.shape[0], 1e-12)
    covariance += ridge * np.eye(covariance.shape[0])
    chol = np.linalg.cholesky(covariance)
    whitened_test = np.linalg.solve(chol, test.T).T
    whitened_means = np.linalg.solve(chol, means.T).T
    distances = ((whitened_test[:, None, :] - whitened_means[None, :, :]) ** 2).sum(axis=2)
    return np.asarray(classes[np.argmin(distances, axis=1)], dtype=np.int64)


def select_feature_dim(
    reduced: FloatArray,
    object_index: IntArray,
    settings: FeatureSettings | None = None,
    seed: int = 0,
    projection: Projection | None = None,
) -> FeatureSelection:
    """Choose the projection and dy by cross-validated recognition of held-out touches.

    Each object's touches are dealt to K folds; for each fold the standardisation and the
    projection are fitted on the other folds, and each held-out touch is recognised by a
    Gaussian classifier with one pooled covariance (:func:`gaussian_classify`) on its first dy
    features. The score of a candidate is the share recognised. The choice is the smallest dy
    whose fold-by-fold difference to the best candidate is ≥ −1 standard error (the
    one-standard-error rule, as :mod:`core.selection.latent_selection` uses for ds), looking at PCA
    first: LDA is chosen only when no PCA candidate comes within that margin.

    Args:
        reduced: Reduced features of the training touches. Shape (N, R).
        object_index: Object of each touch. Shape (N,).
        settings: Supplies ``folds`` and ``max_feature_dim``.
        seed: Seed of the folds.
        projection: Consider only this projection (``None``: both).

    Raises:
        InvalidInputError: Fewer than two objects, or an object with fewer than two touches.
    """
    settings = settings or FeatureSettings()
    object_index = np.asarray(object_index, dtype=np.int64)
    classes, counts = np.unique(object_index, return_counts=True)
    if len(classes) < 2:
        raise InvalidInputError("choosing dy needs touches of at least two objects.")
    folds = min(settings.folds, int(counts.min()))
    if folds < 2:
        raise InvalidInputError(
            "choosing dy needs at least 2 touches of every object (one to hold out)."
        )
    fold = _fold_of_each_touch(object_index, folds, seed)
    smallest_train = int(min(np.sum(fold != f) for f in range(folds)))
    largest = largest_feature_dim(settings, smallest_train, reduced.shape[1])
    candidates: list[tuple[Projection, int]] = []
    for name in (projection,) if projection else PROJECTIONS:
        top = largest if name == "pca" else min(largest, len(classes) - 1)
        candidates += [(name, d) for d in FEATURE_DIM_CANDIDATES if d <= top] or [(name, 1)]
    scores = np.empty((len(candidates), folds))
    for f in range(folds):
        train, test = fold != f, fold == f
        center, scale = standardise(reduced[train])
        z_train = (reduced[train] - center) / scale
        z_test = (reduced[test] - center) / scale
        for name in {c[0] for c in candidates}:
            widest = max(d for n, d in candidates if n == name)
            axes, _ = projection_axes(name, z_train, object_index[train], widest)
            train_y, test_y = z_train @ axes, z_test @ axes
            for c, (n, dim) in enumerate(candidates):
                if n == name:
                    picked = gaussian_classify(
                        train_y[:, :dim], object_index[train], test_y[:, :dim]
                    )
                    scores[c, f] = float(np.mean(picked == object_index[test]))
    means = scores.mean(axis=1)
    best = int(np.argmax(means))
    differences = scores - scores[best]
    diff_se = differences.std(axis=1, ddof=1) / np.sqrt(folds)
    within = [c for c in range(len(candidates)) if differences[c].mean() >= -diff_se[c]]
    chosen = min(within, key=lambda c: (candidates[c][0] != "pca", candidates[c][1]))
    table = tuple(
        FeatureDimScore(
            feature_dim=dim,
            projection=name,
            fold_scores=tuple(float(v) for v in scores[c]),
            mean=float(means[c]),
            standard_error=float(scores[c].std(ddof=1) / np.sqrt(folds)),
            difference=float(differences[c].mean()),
            difference_standard_error=float(diff_se[c]),
        )
        for c, (name, dim) in enumerate(candidates)
    )
    (chosen_name, chosen_dim), (best_name, best_dim) = candidates[chosen], candidates[best]
    explanation = (
        f"{chosen_name.upper()} to dy = {chosen_dim}: the smallest within one standard error of "
        f"the best ({best_name.upper()} to {best_dim}: {means[best]:.1%} of held-out touches "
        f"recognised, {folds}-fold)."
        if chosen != best
        else f"{best_name.upper()} to dy = {best_dim}: the best ({means[best]:.1%} of held-out "
        f"touches recognised, {folds}-fold)."
    )
    return FeatureSelection(chosen_dim, chosen_name, best_dim, best_name, folds, table, explanation)
