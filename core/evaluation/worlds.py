"""Synthetic tactile worlds: the paper's Experiment 1 and Experiment-2-like random worlds.

A world maps (object, action) to a noisy observation. It knows the ground truth (the true object
parameter θ, or a true latent), so a recognition run can be scored. Pure maths: randomness comes in
as an ``np.random.Generator``.

:func:`make_world` is the one registry of the worlds by name (:data:`WORLD_NAMES`, with their noise
defaults :data:`DEFAULT_NOISE_STD`): the command line, the API's simulated trials and the
evaluations name worlds with it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal, Protocol

import numpy as np

from core.errors import InvalidInputError
from core.types import TrainingData
from core.validation import FloatArray, as_float_array

#: θ of the paper's four objects (Experiment 1, §III-A).
EXPERIMENT1_THETAS: tuple[float, ...] = (-0.5, 0.0, 0.2, 0.5)


class World(Protocol):
    """What a simulated trial or data collection needs from a world."""

    @property
    def object_names(self) -> tuple[str, ...]: ...

    @property
    def action_dim(self) -> int: ...

    @property
    def observation_dim(self) -> int: ...

    @property
    def action_mean(self) -> FloatArray: ...

    @property
    def action_cov(self) -> FloatArray: ...

    def mean_response(self, object_index: int, actions: FloatArray) -> FloatArray: ...

    def observe(
        self, object_index: int, actions: FloatArray, rng: np.random.Generator
    ) -> FloatArray: ...


def experiment1_h(theta: float, actions: FloatArray) -> FloatArray:
    """The paper's eq. (6): h(θ, x) = [exp(-(x-θ)²), exp(-(x-θ²)²), exp(-(x-θ³)²)].

    Args:
        theta: True object parameter θ.
        actions: Actions x. Shape (n, 1).

    Returns:
        Noise-free observations. Shape (n, 3).
    """
    x = as_float_array(actions, "actions", (None, 1))[:, 0]
    centres = np.array([theta, theta**2, theta**3])
    return np.asarray(np.exp(-((x[:, None] - centres[None, :]) ** 2)), dtype=np.float64)


def _check_object(index: int, n_objects: int) -> int:
    if not 0 <= int(index) < n_objects:
        raise InvalidInputError(f"object_index: expected 0..{n_objects - 1}, received {index}.")
    return int(index)


@dataclass(frozen=True)
class Experiment1World:
    """The paper's Experiment 1: y = h(θ, x) + ε, ε ~ N(0, noise_std² I), x ~ N(0, 1).

    Attributes:
        thetas: θ of each object. Shape (L,).
        noise_std: Standard deviation of the observation noise (0.1 in the paper as read by
            docs/method.md; ``sqrt(0.1)`` gives the variance-0.1 reading).
    """

    thetas: tuple[float, ...] = EXPERIMENT1_THETAS
    noise_std: float = 0.1

    def __post_init__(self) -> None:
        if len(self.thetas) < 2:
            raise InvalidInputError(f"thetas: need at least 2 objects, received {self.thetas}.")
        if not np.isfinite(self.noise_std) or self.noise_std < 0:
            raise InvalidInputError(f"noise_std: must be finite and ≥ 0, got {self.noise_std}.")

    @property
    def object_names(self) -> tuple[str, ...]:
        """``O1``…``OL`` as in the paper."""
        return tuple(f"O{i + 1}" for i in range(len(self.thetas)))

    @property
    def action_dim(self) -> int:
        """dx = 1."""
        return 1

    @property
    def observation_dim(self) -> int:
        """dy = 3."""
        return 3

    @property
    def action_mean(self) -> FloatArray:
        """Mean of the action prior x ~ N(0, 1). Shape (1,)."""
        return np.zeros(1)

    @property
    def action_cov(self) -> FloatArray:
        """Covariance of the action prior. Shape (1, 1)."""
        return np.eye(1)

    @property
    def truth(self) -> FloatArray:
        """The true object parameters θ. Shape (L, 1)."""
        return np.asarray(self.thetas, dtype=np.float64)[:, None]

    def mean_response(self, object_index: int, actions: FloatArray) -> FloatArray:
        """h(θ_l, x). Shape (n, 3) for actions of shape (n, 1)."""
        index = _check_object(object_index, len(self.thetas))
        return experiment1_h(self.thetas[index], actions)

    def observe(
        self, object_index: int, actions: FloatArray, rng: np.random.Generator
    ) -> FloatArray:
        """Noisy observations h(θ_l, x) + ε. Shape (n, 3)."""
        mean = self.mean_response(object_index, actions)
        return mean + self.noise_std * rng.standard_normal(mean.shape)


@dataclass(frozen=True)
class RandomFeatureWorld:
    """An Experiment-2-like world: a smooth random function of (s, x) through random features.

    Each feature is f_a(s, x) = offset_a + amplitude_a · sqrt(2/K) Σ_k w_ak cos(ω_kᵀ z + b_k),
    z = [s / latent_scale; x / action_scale]: a draw from (approximately) a GP with a squared-
    exponential kernel. Objects sit at latent points ``latents``.

    Attributes:
        latents: True object latents. Shape (L, ds).
        frequencies: ω. Shape (K, ds + dx).
        phases: b. Shape (K,).
        weights: w. Shape (dy, K).
        offsets: Per-feature constant. Shape (dy,).
        amplitudes: Per-feature amplitude. Shape (dy,).
        latent_scale: Length-scale of the response along s.
        action_scale: Length-scale of the response along x.
        noise_std: Observation noise standard deviation per feature. Shape (dy,).
        names: Object names.
        noise_correlation: Correlation of the noise across features, or ``None`` for
            independent noise. Shape (dy, dy), positive definite. The noise covariance is
            diag(noise_std) · noise_correlation · diag(noise_std).
    """

    latents: FloatArray
    frequencies: FloatArray
    phases: FloatArray
    weights: FloatArray
    offsets: FloatArray
    amplitudes: FloatArray
    latent_scale: float
    action_scale: float
    noise_std: FloatArray
    names: tuple[str, ...] = field(default_factory=tuple)
    noise_correlation: FloatArray | None = None

    def __post_init__(self) -> None:
        if self.noise_correlation is None:
            return
        dy = self.weights.shape[0]
        correlation = as_float_array(self.noise_correlation, "noise_correlation", (dy, dy))
        if not np.allclose(correlation, correlation.T) or not np.allclose(np.diag(correlation), 1):
            raise InvalidInputError("noise_correlation: must be symmetric with a unit diagonal.")
        if np.linalg.eigvalsh(correlation).min() <= 0:
            raise InvalidInputError("noise_correlation: must be positive definite.")

    @property
    def noise_covariance(self) -> FloatArray:
        """Σ_ε = diag(σ) R diag(σ) (diagonal without a correlation). Shape (dy, dy)."""
        std = np.asarray(self.noise_std, dtype=np.float64)
        if self.noise_correlation is None:
            return np.diag(std**2)
        return np.asarray(self.noise_correlation * np.outer(std, std), dtype=np.float64)

    @property
    def object_names(self) -> tuple[str, ...]:
        """Object names (``O1``… unless given)."""
        return self.names or tuple(f"O{i + 1}" for i in range(self.latents.shape[0]))

    @property
    def latent_dim(self) -> int:
        """ds."""
        return int(self.latents.shape[1])

    @property
    def action_dim(self) -> int:
        """dx."""
        return int(self.frequencies.shape[1] - self.latents.shape[1])

    @property
    def observation_dim(self) -> int:
        """dy."""
        return int(self.weights.shape[0])

    @property
    def action_mean(self) -> FloatArray:
        """Mean of the action prior, N(0, I). Shape (dx,)."""
        return np.zeros(self.action_dim)

    @property
    def action_cov(self) -> FloatArray:
        """Covariance of the action prior. Shape (dx, dx)."""
        return np.eye(self.action_dim)

    @property
    def truth(self) -> FloatArray:
        """The true latents. Shape (L, ds)."""
        return self.latents

    def mean_response(self, object_index: int, actions: FloatArray) -> FloatArray:
        """Noise-free response. Shape (n, dy) for actions of shape (n, dx)."""
        index = _check_object(object_index, self.latents.shape[0])
        x = as_float_array(actions, "actions", (None, self.action_dim))
        s = np.broadcast_to(self.latents[index], (x.shape[0], self.latent_dim))
        z = np.hstack([s / self.latent_scale, x / self.action_scale])
        n_features = self.phases.shape[0]
        basis = np.sqrt(2.0 / n_features) * np.cos(z @ self.frequencies.T + self.phases)
        return np.asarray(self.offsets + self.amplitudes * (basis @ self.weights.T))

    def observe(
        self, object_index: int, actions: FloatArray, rng: np.random.Generator
    ) -> FloatArray:
        """Noisy observations, correlated across features if ``noise_correlation`` is set.

        Returns:
            Shape (n, dy).
        """
        mean = self.mean_response(object_index, actions)
        if self.noise_correlation is None:
            return mean + self.noise_std * rng.standard_normal(mean.shape)
        factor = np.linalg.cholesky(self.noise_covariance)
        return np.asarray(mean + rng.standard_normal(mean.shape) @ factor.T, dtype=np.float64)


def random_experiment2_world(
    rng: np.random.Generator,
    n_objects: int = 4,
    latent_dim: int = 2,
    action_dim: int = 6,
    observation_dim: int = 5,
    noise_std: float = 0.05,
    latent_scale: float = 1.0,
    action_scale: float = 1.5,
    n_features: int = 200,
) -> RandomFeatureWorld:
    """Draw an Experiment-2-like world (ds = 2, dx = 6, dy = 5 by default).

    Objects are placed at latent points drawn from N(0, I); responses have unit amplitude and
    per-feature offsets, so features are on comparable scales.
    """
    for value, name in (
        (n_objects, "n_objects"),
        (latent_dim, "latent_dim"),
        (action_dim, "action_dim"),
        (observation_dim, "observation_dim"),
        (n_features, "n_features"),
    ):
        if int(value) < 1:
            raise InvalidInputError(f"{name}: must be ≥ 1, received {value}.")
    if n_objects < 2:
        raise InvalidInputError(f"n_objects: need at least 2, received {n_objects}.")
    dims = latent_dim + action_dim
    return RandomFeatureWorld(
        latents=rng.standard_normal((n_objects, latent_dim)),
        frequencies=rng.standard_normal((n_features, dims)),
        phases=rng.uniform(0.0, 2.0 * np.pi, n_features),
        weights=rng.standard_normal((observation_dim, n_features)),
        offsets=rng.uniform(-1.0, 1.0, observation_dim),
        amplitudes=np.ones(observation_dim),
        latent_scale=latent_scale,
        action_scale=action_scale,
        noise_std=np.full(observation_dim, noise_std),
    )


def sample_dataset(
    world: World,
    rng: np.random.Generator,
    touches_per_object: int = 100,
) -> TrainingData:
    """Touch every object ``touches_per_object`` times with x ~ N(action_mean, action_cov).

    This is the paper's random collection design (a fresh action per touch).

    Returns:
        Training data with touches grouped by object (eq. (4) of the paper).
    """
    if touches_per_object < 2:
        raise InvalidInputError(
            f"touches_per_object: need at least 2, received {touches_per_object}."
        )
    names = world.object_names
    actions, observations, index = [], [], []
    for obj in range(len(names)):
        x = rng.multivariate_normal(world.action_mean, world.action_cov, touches_per_object)
        actions.append(x)
        observations.append(world.observe(obj, x, rng))
        index.append(np.full(touches_per_object, obj))
    return TrainingData(
        object_names=names,
        object_index=np.concatenate(index),
        actions=np.vstack(actions),
        observations=np.vstack(observations),
    )


def sample_experiment1(
    rng: np.random.Generator, touches_per_object: int = 100, noise_std: float = 0.1
) -> TrainingData:
    """The paper's Experiment 1 training set (4 objects × 100 touches, x ~ N(0, 1))."""
    return sample_dataset(Experiment1World(noise_std=noise_std), rng, touches_per_object)


#: Noise correlation of :func:`correlated_noise_world`'s five channels, in the order vibration
#: RMS, vibration mean, pressure, heat flux, temperature. Modelled on the residual correlations
#: of a first M1 fit to the public multimodal-fingertip data set (docs/method.md "Real tactile
#: data": 0.69 between the two vibration features, 0.74 between vibration mean and pressure,
#: 0.4–0.5 between heat flux and the others), rounded up so that some pairs reach ≥ 0.7 and
#: with heat flux and temperature, two views of one heat exchange, at 0.8.
TACTILE_NOISE_CORRELATION: tuple[tuple[float, ...], ...] = (
    (1.0, 0.8, 0.7, 0.4, 0.3),
    (0.8, 1.0, 0.75, 0.4, 0.3),
    (0.7, 0.75, 1.0, 0.5, 0.4),
    (0.4, 0.4, 0.5, 1.0, 0.8),
    (0.3, 0.3, 0.4, 0.8, 1.0),
)

#: Per-channel scales of :func:`correlated_noise_world` (vibration RMS in the hundreds, a
#: temperature of order 1), so the features sit on wildly different scales as real ones do.
TACTILE_FEATURE_SCALES: tuple[float, ...] = (100.0, 30.0, 5.0, 2.0, 1.0)


def correlated_noise_world(
    rng: np.random.Generator,
    n_objects: int = 6,
    latent_dim: int = 2,
    action_dim: int = 1,
    noise_std: float = 0.3,
    latent_scale: float = 1.0,
    action_scale: float = 1.5,
    n_features: int = 200,
    feature_scales: tuple[float, ...] = TACTILE_FEATURE_SCALES,
) -> RandomFeatureWorld:
    """An Experiment-2-like world with five tactile-like channels whose noise is correlated.

    The responses are those of :func:`random_experiment2_world` (unit amplitude before scaling;
    objects at N(0, I) latents, so two objects' responses differ by O(1)); the noise has the
    correlation :data:`TACTILE_NOISE_CORRELATION` and standard deviation ``noise_std`` (0.3:
    comparable to the differences between objects); channel a is then multiplied by
    ``feature_scales[a]`` (offset, response and noise alike).

    Args:
        rng: Random generator (objects, response function).
        n_objects: L ≥ 2.
        latent_dim: ds of the true latents.
        action_dim: dx (1: e.g. the sliding speed).
        noise_std: Noise standard deviation of every channel in unscaled units.
        latent_scale: Length-scale of the response along s.
        action_scale: Length-scale of the response along x.
        n_features: Random features of the response function.
        feature_scales: Per-channel scale, 5 of them.
    """
    scales = as_float_array(feature_scales, "feature_scales", (len(TACTILE_NOISE_CORRELATION),))
    if np.any(scales <= 0):
        raise InvalidInputError(f"feature_scales: must be > 0, received {scales}.")
    if not np.isfinite(noise_std) or noise_std <= 0:
        raise InvalidInputError(f"noise_std: must be finite and > 0, received {noise_std}.")
    base = random_experiment2_world(
        rng,
        n_objects=n_objects,
        latent_dim=latent_dim,
        action_dim=action_dim,
        observation_dim=scales.shape[0],
        noise_std=noise_std,
        latent_scale=latent_scale,
        action_scale=action_scale,
        n_features=n_features,
    )
    return RandomFeatureWorld(
        latents=base.latents,
        frequencies=base.frequencies,
        phases=base.phases,
        weights=base.weights,
        offsets=base.offsets * scales,
        amplitudes=base.amplitudes * scales,
        latent_scale=latent_scale,
        action_scale=action_scale,
        noise_std=base.noise_std * scales,
        noise_correlation=np.asarray(TACTILE_NOISE_CORRELATION, dtype=np.float64),
    )


#: The synthetic worlds by name: ``exp1``, the paper's Experiment 1 (objects O1..O4, dx = 1,
#: dy = 3); ``exp2``, an Experiment-2-like random world drawn from a seed (dx = 6, dy = 5).
WorldName = Literal["exp1", "exp2"]

#: Every :data:`WorldName`.
WORLD_NAMES: tuple[WorldName, ...] = ("exp1", "exp2")

#: The observation noise standard deviation of each world when none is given (the paper's 0.1
#: for Experiment 1).
DEFAULT_NOISE_STD: dict[WorldName, float] = {"exp1": 0.1, "exp2": 0.05}


def make_world(name: str, *, world_seed: int = 0, noise_std: float | None = None) -> World:
    """The synthetic world called ``name``.

    Args:
        name: One of :data:`WORLD_NAMES`.
        world_seed: Seed that draws the ``exp2`` world (unused by ``exp1``).
        noise_std: Observation noise standard deviation; :data:`DEFAULT_NOISE_STD` of the
            world when ``None``.

    Raises:
        InvalidInputError: Unknown name (the message lists the worlds), or a bad noise.
    """
    if name == "exp1":
        return Experiment1World(
            noise_std=DEFAULT_NOISE_STD["exp1"] if noise_std is None else noise_std
        )
    if name == "exp2":
        return random_experiment2_world(
            np.random.default_rng(world_seed),
            noise_std=DEFAULT_NOISE_STD["exp2"] if noise_std is None else noise_std,
        )
    raise InvalidInputError(
        f"world: {name!r} is not a synthetic world; choose from {list(WORLD_NAMES)}."
    )
