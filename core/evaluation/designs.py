"""Collection designs: which action touches which object when the training set is collected.

* **Random design** (the paper's): a fresh action x ~ N(μ_x, Σ_x) for every touch.
* **Shared design**: M actions, each applied to every object (N = L·M). The actions are a
  scrambled Sobol set mapped through the action prior's inverse CDF (x = μ_x + L_x Φ⁻¹(u), L_x
  the Cholesky factor of Σ_x), so they fill the prior more evenly than M random draws. Every
  object then shares the Gram factor K^x and the fit and the planner run through the exact
  Kronecker path of :mod:`core.gp.kronecker` (docs/method.md, "Shared action designs"): hundreds of
  objects × hundreds of actions instead of a few hundred touches in all.

A :class:`CollectionDesign` is just the (object, action) list; :func:`collect` touches a
simulated world with it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.special
from scipy.stats import qmc

from core.errors import InvalidInputError
from core.evaluation.worlds import World
from core.types import TrainingData
from core.validation import FloatArray, IntArray, as_float_array

#: Sobol points are kept this far from 0 and 1 before the inverse normal CDF.
_UNIT_MARGIN = 1e-12


@dataclass(frozen=True)
class CollectionDesign:
    """The touches to collect, object by object.

    Attributes:
        object_index: Object of every touch, grouped by object. Shape (N,).
        actions: Action of every touch. Shape (N, dx).
        shared: Whether every object gets the same actions (a Kronecker design).
    """

    object_index: IntArray
    actions: FloatArray
    shared: bool

    @property
    def n_touches(self) -> int:
        """N."""
        return int(self.object_index.shape[0])


def _check_prior(mean: FloatArray, cov: FloatArray) -> tuple[FloatArray, FloatArray]:
    mean = as_float_array(mean, "action mean", (None,))
    dx = mean.shape[0]
    if dx < 1:
        raise InvalidInputError("action mean: needs at least one dimension, received none.")
    cov = as_float_array(cov, "action cov", (dx, dx))
    if not np.allclose(cov, cov.T, rtol=1e-8, atol=1e-12):
        raise InvalidInputError("action cov: must be symmetric.")
    eigenvalues, vectors = np.linalg.eigh(0.5 * (cov + cov.T))
    if eigenvalues.min() < -1e-10 * max(1.0, float(np.abs(eigenvalues).max())):
        raise InvalidInputError(
            f"action cov: must be positive semi-definite, smallest eigenvalue "
            f"{eigenvalues.min():.3g}."
        )
    # A square root that also works for a singular covariance.
    root = vectors * np.sqrt(np.maximum(eigenvalues, 0.0))
    return mean, np.asarray(root, dtype=np.float64)


def _check_count(value: int, name: str, minimum: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < minimum:
        raise InvalidInputError(f"{name}: expected an integer ≥ {minimum}, received {value!r}.")
    return int(value)


def sobol_normal_actions(
    n_actions: int, mean: FloatArray, cov: FloatArray, rng: np.random.Generator
) -> FloatArray:
    """M scrambled-Sobol actions mapped to N(mean, cov) by the inverse normal CDF.

    The first ``n_actions`` points of a base-2 scrambled Sobol sequence (balanced when
    ``n_actions`` is a power of two), each coordinate through Φ⁻¹, then x = mean + R z with R a
    square root of ``cov`` (its Cholesky factor up to a rotation: the symmetric eigen-root).

    Args:
        n_actions: M ≥ 1.
        mean: μ_x. Shape (dx,).
        cov: Σ_x, symmetric positive semi-definite. Shape (dx, dx).
        rng: Seeds the scrambling.

    Returns:
        Shape (M, dx).
    """
    n_actions = _check_count(n_actions, "n_actions", 1)
    mean, root = _check_prior(mean, cov)
    dx = mean.shape[0]
    m = max(int(np.ceil(np.log2(n_actions))), 0)
    unit = qmc.Sobol(dx, scramble=True, rng=rng).random_base2(m)[:n_actions]
    unit = np.clip(unit, _UNIT_MARGIN, 1.0 - _UNIT_MARGIN)
    z = scipy.special.ndtri(unit)
    return np.asarray(mean + z @ root.T, dtype=np.float64)


def random_design(
    n_objects: int,
    touches_per_object: int,
    mean: FloatArray,
    cov: FloatArray,
    rng: np.random.Generator,
) -> CollectionDesign:
    """The paper's design: x ~ N(mean, cov) independently for every touch.

    Args:
        n_objects: L ≥ 2.
        touches_per_object: N_l ≥ 2.
        mean: μ_x. Shape (dx,).
        cov: Σ_x. Shape (dx, dx).
        rng: Draws the actions.
    """
    n_objects = _check_count(n_objects, "n_objects", 2)
    per_object = _check_count(touches_per_object, "touches_per_object", 2)
    mean, root = _check_prior(mean, cov)
    n = n_objects * per_object
    actions = mean + rng.standard_normal((n, mean.shape[0])) @ root.T
    index = np.repeat(np.arange(n_objects, dtype=np.int64), per_object)
    return CollectionDesign(object_index=index, actions=actions, shared=False)


def shared_design(
    n_objects: int,
    n_actions: int,
    mean: FloatArray,
    cov: FloatArray,
    rng: np.random.Generator,
) -> CollectionDesign:
    """M actions (:func:`sobol_normal_actions`), each applied to every object.

    Args:
        n_objects: L ≥ 2.
        n_actions: M ≥ 2.
        mean: μ_x. Shape (dx,).
        cov: Σ_x. Shape (dx, dx).
        rng: Seeds the Sobol scrambling.
    """
    n_objects = _check_count(n_objects, "n_objects", 2)
    n_actions = _check_count(n_actions, "n_actions", 2)
    actions = sobol_normal_actions(n_actions, mean, cov, rng)
    index = np.repeat(np.arange(n_objects, dtype=np.int64), n_actions)
    return CollectionDesign(
        object_index=index, actions=np.tile(actions, (n_objects, 1)), shared=True
    )


def collect(world: World, design: CollectionDesign, rng: np.random.Generator) -> TrainingData:
    """Touch a simulated world with a design.

    Args:
        world: Produces noisy observations (``world.observe``).
        design: Which actions touch which object; objects index ``world.object_names``.
        rng: Observation noise.

    Returns:
        Training data in the design's touch order.

    Raises:
        InvalidInputError: The design does not fit the world (dimension or object count).
    """
    names = world.object_names
    if design.actions.shape[1] != world.action_dim:
        raise InvalidInputError(
            f"design: has dx={design.actions.shape[1]}, the world has dx={world.action_dim}."
        )
    if design.object_index.size and int(design.object_index.max()) >= len(names):
        raise InvalidInputError(
            f"design: touches object {int(design.object_index.max())}, the world has "
            f"{len(names)} objects."
        )
    observations = np.empty((design.n_touches, world.observation_dim))
    for obj in range(len(names)):
        rows = np.flatnonzero(design.object_index == obj)
        if rows.size:
            observations[rows] = world.observe(obj, design.actions[rows], rng)
    return TrainingData(
        object_names=names,
        object_index=design.object_index,
        actions=design.actions,
        observations=observations,
    )
