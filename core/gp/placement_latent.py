"""A latent coordinate per placement in the GP's input (docs/calibration.md, "A latent per
placement, measured"). An experiment the product does not use: on the cushions it scores the
rig's trials worse than the model without it (the fitted u_p take up noise).

A placement changes how an object answers every touch (on the simulated rig: the contact
angle, which moves the whole flexion trajectory), and that change is mostly not a direction of
the action space. So it enters the GP as an input of its own: touch i of placement p of object l
has the input [s_l, u_p, x_i], u_p a scalar. The kernel is the manifold's
squared exponential over the longer latent (eq. (M1) with ds + 1 latent dimensions): placements
of one object whose u differ by ℓ^u_a answer alike up to a correlation of e^{-1/2}.

Training is (M2) on one *pseudo-object* per placement, whose latent is [s_l, u_p]: the dense
likelihood (:class:`core.gp.likelihood.ManifoldLikelihood`) of the pseudo-objects with latent
dimension ds + 1. Its gradient with respect to s_l is the sum of the first ds latent entries over
the placements of object l (the chain rule), with respect to u_p the last one.

The u_p of every object have zero mean and unit spread by construction: the packed vector holds
free v_p and, over the placements of each object l, u = (v − v̄_l) / σ_l with
σ_l² = mean((v − v̄_l)²). Both halves of that are needed (measured on a test world, 4 objects
× 10 placements of 3 touches, each placement shifting the action the object feels):

* A prior N(0, 1) on u alone does not fix their scale. The kernel depends only on u / ℓ^u, and
  shrinking u and ℓ^u together always raises the prior, so the fit slid to u → 0, ℓ^u → 0
  (ℓ^u 0.05, u spread 0.02-0.07 after 400 iterations), every placement a function of its own.
* With the spread fixed over all placements but not per object, the fit used u as an object
  coordinate: three of the four objects' s merged and their placements' u formed one cluster
  per object (spreads 0.14 to 1.39 within objects).

Per object, u says only how this placement differs from the object's others, and N(0, 1) is
the distribution a new placement's u is drawn from. The spread of each object's v is free (the
value does not depend on it); ½ Σ_l (log σ_l)² pins it at 1 without moving the optimum.

Recognition: a new trial is a new placement, so its touches share one u ~ N(0, 1), and under
object l the latent input is [s, u] ~ N([s_l, 0], diag(Σ_l, 1)): the Gaussian-input moments of
docs/method.md (L2), over the trial's touches at once (:mod:`core.recognition.placement_latent`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from core.errors import InvalidInputError
from core.gp.likelihood import ManifoldLikelihood
from core.gp.parameters import ParameterLayout
from core.gp.placement_groups import placement_groups
from core.types import Hyperparameters, TrainingData
from core.validation import FloatArray, IntArray, as_float_array


@dataclass(frozen=True)
class Placements:
    """The training touches as one pseudo-object per placement.

    Attributes:
        data: The touches with ``object_index`` the placement (P pseudo-objects).
        placement_object: The object of every placement. Shape (P,).
    """

    data: TrainingData
    placement_object: IntArray

    @property
    def n_placements(self) -> int:
        """P."""
        return int(self.placement_object.shape[0])


def placements_of(data: TrainingData) -> Placements:
    """One pseudo-object per (object, placement number) of ``data``.

    Raises:
        InvalidInputError: The touches record no placements.
    """
    if data.placement_index is None:
        raise InvalidInputError(
            "placement_index: a latent per placement needs touches that record their placement "
            "(collect with --placements)."
        )
    groups = placement_groups(data.object_index, data.placement_index)
    # Placements grouped by object (the pseudo-objects of one object contiguous).
    groups.sort(key=lambda g: int(data.object_index[g[0]]))
    pseudo = np.empty(data.n_touches, dtype=np.intp)
    owner = np.empty(len(groups), dtype=np.intp)
    names = []
    for p, group in enumerate(groups):
        pseudo[group] = p
        owner[p] = int(data.object_index[group[0]])
        names.append(f"{data.object_names[owner[p]]}@{int(data.placement_index[group[0]])}")
    touches = TrainingData(
        object_names=tuple(names),
        object_index=pseudo,
        actions=data.actions,
        observations=data.observations,
        # Each pseudo-object is one placement (for a placement variance in the fit).
        placement_index=np.zeros(data.n_touches, dtype=np.int64),
        touch_times_s=data.touch_times_s,
        touch_duration_s=data.touch_duration_s,
        min_touches_per_object=1,
    )
    return Placements(data=touches, placement_object=owner)


def pseudo_latents(
    latents: FloatArray, placement_object: IntArray, offsets: FloatArray
) -> FloatArray:
    """[s_l(p), u_p] of every placement p, l(p) = ``placement_object[p]``. Shape (P, ds + 1)."""
    return np.column_stack([latents[placement_object], offsets])


@dataclass(frozen=True)
class PlacementLayout:
    """The packed vector: S (L·ds), v (P; u standardised from v), then the pseudo-objects'
    log-hyperparameters (the layout of :class:`core.gp.parameters.ParameterLayout` with ds + 1
    latent dimensions, from log σ_f² on).

    Attributes:
        n_objects: L.
        latent_dim: ds (the objects' latents; the kernel sees ds + 1).
        placement_object: The object of every placement. Shape (P,).
        pseudo: The layout of the pseudo-objects' vector.
    """

    n_objects: int
    latent_dim: int
    placement_object: IntArray
    pseudo: ParameterLayout

    @property
    def n_placements(self) -> int:
        """P."""
        return int(self.placement_object.shape[0])

    @property
    def size(self) -> int:
        """Length of the packed vector."""
        return self.n_objects * self.latent_dim + self.n_placements + self._n_hyper

    @property
    def _n_hyper(self) -> int:
        return int(self.pseudo.size - self.pseudo.hyperparameters.start)

    def split(self, vector: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """S (L, ds), v (P,) and the log-hyperparameters (pseudo layout order), as views."""
        ls = self.n_objects * self.latent_dim
        p = self.n_placements
        return (
            vector[:ls].reshape(self.n_objects, self.latent_dim),
            vector[ls : ls + p],
            vector[ls + p :],
        )

    def pack(
        self, latents: FloatArray, offsets: FloatArray, hyperparameters: Hyperparameters
    ) -> FloatArray:
        """Pack S (L, ds), v (P,) and hyperparameters with ds + 1 latent length-scales."""
        latents = as_float_array(latents, "latents", (self.n_objects, self.latent_dim))
        offsets = as_float_array(offsets, "offsets", (self.n_placements,))
        full = self.pseudo.pack(self.pseudo_latents(latents, offsets), hyperparameters)
        return np.concatenate([latents.ravel(), offsets, full[self.pseudo.hyperparameters]])

    def pseudo_latents(self, latents: FloatArray, offsets: FloatArray) -> FloatArray:
        """[s_l(p), u_p] of every placement. Shape (P, ds + 1)."""
        return pseudo_latents(latents, self.placement_object, offsets)

    @property
    def placement_counts(self) -> IntArray:
        """P_l, the placements of each object. Shape (L,)."""
        return np.bincount(self.placement_object, minlength=self.n_objects)

    def _object_sums(self, values: FloatArray) -> FloatArray:
        """Σ of ``values`` (given per placement) over each object's placements. Shape (L,)."""
        sums = np.bincount(self.placement_object, weights=values, minlength=self.n_objects)
        return np.asarray(sums, dtype=np.float64)

    def _object_means(self, values: FloatArray) -> FloatArray:
        """Mean of ``values`` over each object's placements, given per placement. Shape (P,)."""
        means = self._object_sums(values) / self.placement_counts
        return np.asarray(means[self.placement_object], dtype=np.float64)

    def log_spreads(self, free: FloatArray) -> FloatArray:
        """log σ_l of each object's v. Shape (L,)."""
        centred = free - self._object_means(free)
        variance = self._object_sums(centred**2) / self.placement_counts
        return np.asarray(0.5 * np.log(variance), dtype=np.float64)

    def standardised(self, free: FloatArray) -> FloatArray:
        """u = (v − v̄_l) / σ_l over each object's placements. Shape (P,)."""
        spread = np.exp(self.log_spreads(free))[self.placement_object]
        return np.asarray((free - self._object_means(free)) / spread, dtype=np.float64)

    def expand(self, vector: FloatArray) -> FloatArray:
        """The pseudo-objects' packed vector (:attr:`pseudo` layout), u standardised from v."""
        latents, free, hyper = self.split(vector)
        pseudo = self.pseudo_latents(latents, self.standardised(free))
        return np.concatenate([pseudo.ravel(), hyper])

    def reduce(self, gradient: FloatArray, free: FloatArray) -> FloatArray:
        """A gradient with respect to the pseudo-objects' vector → with respect to this one
        (S by summing over each object's placements; v through u = (v − v̄_l) / σ_l, per object:
        ∂/∂v = (g − ḡ_l − u · mean_l(g ∘ u)) / σ_l)."""
        ds = self.latent_dim
        pseudo = gradient[self.pseudo.latents].reshape(self.n_placements, ds + 1)
        g_latents = np.zeros((self.n_objects, ds))
        np.add.at(g_latents, self.placement_object, pseudo[:, :ds])
        g_u = pseudo[:, ds]
        u = self.standardised(free)
        spread = np.exp(self.log_spreads(free))[self.placement_object]
        g_free = (g_u - self._object_means(g_u) - u * self._object_means(g_u * u)) / spread
        return np.concatenate([g_latents.ravel(), g_free, gradient[self.pseudo.hyperparameters]])

    def unpack(self, vector: FloatArray) -> tuple[FloatArray, FloatArray, Hyperparameters]:
        """S (L, ds), u (P,; standardised per object) and the hyperparameters (ds + 1 latent
        length-scales)."""
        vector = as_float_array(vector, "parameter vector", (self.size,))
        latents, free, _ = self.split(vector)
        _, hyper = self.pseudo.unpack(self.expand(vector))
        return latents.copy(), self.standardised(free), hyper


class PlacementLatentLikelihood:
    """-log p(Y | S, u(v), X, γ) + ½ Σ_l (log σ_l)² and its gradient (module docstring).

    Args:
        data: Training touches that record their placements (at least two per object).
        latent_dim: ds ≥ 1 of the objects' latents.
        threads: Python threads for the features (:class:`ManifoldLikelihood`).
        placement_variance: σ_b,a², held fixed: an offset shared by a placement's touches
            beside u (:class:`ManifoldLikelihood`'s); the packed noise variance is then the
            within-placement one. ``None``: none. Shape (dy,).
    """

    def __init__(
        self,
        data: TrainingData,
        latent_dim: int,
        threads: int = 1,
        placement_variance: FloatArray | None = None,
    ) -> None:
        placements = placements_of(data)
        counts = np.bincount(placements.placement_object, minlength=data.n_objects)
        if np.any(counts < 2):
            few = [n for n, c in zip(data.object_names, counts, strict=True) if c < 2]
            raise InvalidInputError(
                f"placement_index: a latent per placement needs at least 2 placements of every "
                f"object; {', '.join(few)} had fewer."
            )
        self.placements = placements
        self.inner = ManifoldLikelihood(
            placements.data,
            int(latent_dim) + 1,
            threads=threads,
            placement_variance=placement_variance,
        )
        self.layout = PlacementLayout(
            n_objects=data.n_objects,
            latent_dim=int(latent_dim),
            placement_object=placements.placement_object,
            pseudo=self.inner.layout,
        )

    def value(self, vector: FloatArray) -> float:
        """The negative log-likelihood of the pseudo-objects plus ½ Σ_l (log σ_l)²."""
        _, free, _ = self.layout.split(vector)
        log_spread = self.layout.log_spreads(free)
        return self.inner.value(self.layout.expand(vector)) + 0.5 * float(log_spread @ log_spread)

    def value_and_gradient(self, vector: FloatArray) -> tuple[float, FloatArray]:
        """:meth:`value` and its gradient (same layout as ``vector``)."""
        _, free, _ = self.layout.split(vector)
        value, gradient = self.inner.value_and_gradient(self.layout.expand(vector))
        reduced = self.layout.reduce(gradient, free)
        log_spread = self.layout.log_spreads(free)
        _, g_free, _ = self.layout.split(reduced)
        # ∂/∂v_p of ½ (log σ_l)², l the object of p: log σ_l · u_p / (P_l σ_l).
        scale = log_spread / (self.layout.placement_counts * np.exp(log_spread))
        g_free += scale[self.layout.placement_object] * self.layout.standardised(free)
        return value + 0.5 * float(log_spread @ log_spread), reduced
