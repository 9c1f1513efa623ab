"""The scalable approximate path for large data without a shared design: a sparse
variational (VFE, Titsias 2009) GP with inducing points tied to the object latents.

**Model.** Each feature keeps the exact model of docs/method.md eq. (M1); only the posterior is
approximated. The m inducing points are training inputs z_u = (s_obj(u), x_u) of chosen touches
(:func:`select_inducing_points`), so their latents *are* object latents: they move with S
during the fit and the gradient flows through them; their actions stay fixed. With
K_uu = K(Z_u, Z_u) (+ a small jitter), K_uf = K(Z_u, Z_f), Q = K_fu K_uu⁻¹ K_uf and β_n = 1/σ_n²,
the fit maximises the collapsed variational lower bound

    F = log N(y | 0, Q + σ_n² I) - (β_n / 2) tr(K_ff - Q)  ≤  log p(y | S, X, γ)

per feature (summed over features), in place of the exact log-likelihood of eq. (M2). It costs
O(N m²) time and O(N m) memory per feature and evaluation instead of O(N³) and O(N²). When
the inducing points are all the touches (m = N), F equals the exact log-likelihood (up to the
jitter): the tests check that, the bound, and the analytic gradient.

**Predictive.** q(u) is Gaussian; the predictive of f at z* is

    mean = k_*uᵀ c,   var = σ_f² - k_*uᵀ (K_uu⁻¹ - A⁻¹) k_*u,
    A = K_uu + β_n K_uf K_fu,   c = β_n A⁻¹ K_uf y,

exactly the exact GP's form with the inducing points as support points, weights c for β and
K_uu⁻¹ - A⁻¹ for K⁻¹. The model carries it as a ``"sparse"`` :class:`core.types.GPPosterior`,
so prediction and the moment matching of docs/method.md (M3) (whose structured form only needs the
support points to take L distinct latents, which they do) run unchanged on it, at O(m²) per
candidate instead of O(N²).

**Accuracy trade-off** (measured by ``bench/run.py``'s sparse section against the exact dense
path, Experiment-2-like world, random design): see docs/results.md, "Performance". The bound is
below the exact log-likelihood by the KL gap, which shrinks as m grows; the latents, the
predictive and the mutual information approach the exact ones accordingly.

**Jitter.** K_uu gets ε σ_f² I with ε = ``jitter`` (default 1e-6, raised along 1e-5 … 1e-3
when the Cholesky factorisation fails); it is part of the model being differentiated.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg

from core.errors import InvalidInputError
from core.gp.linalg import cholesky_with_jitter
from core.gp.parameters import ParameterLayout, check_conditioning
from core.types import (
    FitDiagnostics,
    GPPosterior,
    Hyperparameters,
    InducingPoints,
    ManifoldModel,
    TrainingData,
)
from core.validation import FloatArray, IntArray

_LOG_2PI = float(np.log(2.0 * np.pi))

#: Default number of inducing points.
DEFAULT_INDUCING_POINTS = 512
#: Default relative jitter on K_uu (times σ_f²).
DEFAULT_JITTER = 1e-6
#: Relative jitters tried, in turn, above the requested one when K_uu is not positive definite.
_JITTER_STEPS = (1.0, 10.0, 100.0, 1000.0)


def select_inducing_points(data: TrainingData, n_inducing: int) -> InducingPoints:
    """Choose m training touches as inducing points, deterministically.

    Objects get ⌊m / L⌋ points each and the remainder goes one each to the objects with the
    most touches (ties: lower index); when m < L, m objects spread evenly over the index get one.
    Within an object the points are a farthest-point sample of its actions (scaled by the pooled
    standard deviation of each action dimension), starting at the touch nearest its mean action,
    so they cover its action cloud. With m ≥ N every touch is an inducing point.

    Args:
        data: Training touches.
        n_inducing: m ≥ 1.

    Returns:
        The inducing points, grouped by object.
    """
    if isinstance(n_inducing, bool) or not isinstance(n_inducing, int | np.integer):
        raise InvalidInputError(f"n_inducing: expected an integer, received {n_inducing!r}.")
    if n_inducing < 1:
        raise InvalidInputError(f"n_inducing: must be ≥ 1, received {n_inducing}.")
    n_objects = data.n_objects
    counts = data.touches_per_object()
    m = min(int(n_inducing), data.n_touches)
    quota = np.zeros(n_objects, dtype=np.int64)
    if m < n_objects:
        quota[np.unique(np.linspace(0, n_objects - 1, m).round().astype(np.int64))] = 1
    else:
        quota[:] = m // n_objects
        order = np.lexsort((np.arange(n_objects), -counts))
        quota[order[: m - int(quota.sum())]] += 1
    # Objects with fewer touches than their quota hand the rest to the others, in turn.
    while np.any(quota > counts):
        spare = int(np.sum(np.maximum(quota - counts, 0)))
        quota = np.minimum(quota, counts)
        room = np.flatnonzero(quota < counts)
        for obj in room[:spare]:
            quota[obj] += 1
    scale = np.std(data.actions, axis=0)
    scale = np.where(scale > 0, scale, 1.0)
    chosen: list[IntArray] = []
    for obj in range(n_objects):
        if quota[obj] == 0:
            continue
        rows = np.flatnonzero(data.object_index == obj)
        points = data.actions[rows] / scale
        first = int(np.argmin(np.sum((points - points.mean(axis=0)) ** 2, axis=1)))
        picked = [first]
        distance = np.sum((points - points[first]) ** 2, axis=1)
        for _ in range(int(quota[obj]) - 1):
            nxt = int(np.argmax(distance))
            picked.append(nxt)
            distance = np.minimum(distance, np.sum((points - points[nxt]) ** 2, axis=1))
        chosen.append(rows[np.sort(np.array(picked, dtype=np.int64))])
    touch_index = np.concatenate(chosen).astype(np.int64)
    object_index = data.object_index[touch_index].copy()
    actions = data.actions[touch_index].copy()
    for array in (touch_index, object_index, actions):
        array.flags.writeable = False
    return InducingPoints(object_index=object_index, actions=actions, touch_index=touch_index)


@dataclass(frozen=True)
class _FeatureState:
    """Factorisations of one feature at one parameter vector (internal)."""

    bound: float
    chol_uu: FloatArray  # L_u (m, m)
    chol_b: FloatArray  # L_B of B = I + β_n V Vᵀ (m, m)
    weights: FloatArray  # c (m,)
    jitter: float  # absolute jitter on K_uu


class SparseLikelihood:
    """-F (the negative VFE bound) and its gradient, drop-in for
    :class:`core.gp.likelihood.ManifoldLikelihood` (same packed vector; see the module docstring).

    Args:
        data: Training touches.
        latent_dim: ds ≥ 1.
        inducing: The inducing points (``select_inducing_points(data, n_inducing)`` when
            ``None``).
        n_inducing: m, used when ``inducing`` is ``None``.
        jitter: Relative jitter ε on K_uu (> 0).
    """

    def __init__(
        self,
        data: TrainingData,
        latent_dim: int,
        inducing: InducingPoints | None = None,
        n_inducing: int = DEFAULT_INDUCING_POINTS,
        jitter: float = DEFAULT_JITTER,
    ) -> None:
        if isinstance(latent_dim, bool) or int(latent_dim) != latent_dim or latent_dim < 1:
            raise InvalidInputError(f"latent_dim: must be an integer ≥ 1, received {latent_dim}.")
        if not np.isfinite(jitter) or jitter <= 0:
            raise InvalidInputError(f"jitter: must be finite and > 0, received {jitter}.")
        self.data = data
        self.layout = ParameterLayout.for_data(data, int(latent_dim))
        self.inducing = (
            inducing if inducing is not None else select_inducing_points(data, n_inducing)
        )
        if self.inducing.actions.shape[1] != data.action_dim:
            raise InvalidInputError(
                f"inducing: actions have dx={self.inducing.actions.shape[1]}, the data "
                f"dx={data.action_dim}."
            )
        self.relative_jitter = float(jitter)
        shift = data.actions.mean(axis=0)
        order = np.argsort(data.object_index, kind="stable")
        self._actions = np.ascontiguousarray(data.actions[order] - shift)  # (N, dx)
        self._objects = data.object_index[order]
        self._centred = np.ascontiguousarray((data.observations[order] - data.observation_mean).T)
        counts = data.touches_per_object()
        self._starts = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.intp)
        self._present = counts > 0
        self._z = np.ascontiguousarray(self.inducing.actions - shift)  # (m, dx)
        self._z_objects = self.inducing.object_index
        self._z_indicator = np.zeros((data.n_objects, self.inducing.size))
        self._z_indicator[self._z_objects, np.arange(self.inducing.size)] = 1.0
        self.max_jitter = 0.0
        self.evaluations = 0

    # -- kernels -----------------------------------------------------------------------------

    def _cross(self, latents: FloatArray, inv_ls2: FloatArray, inv_lx2: FloatArray) -> FloatArray:
        """k^s(s_u, s_f) k^x(z_u, x_f) without σ_f². Shape (m, N)."""
        z = self._z * np.sqrt(inv_lx2)
        x = self._actions * np.sqrt(inv_lx2)
        sq = np.sum(z**2, axis=1)[:, None] + np.sum(x**2, axis=1)[None, :] - 2.0 * z @ x.T
        np.maximum(sq, 0.0, out=sq)
        diff = latents[:, None, :] - latents[None, :, :]
        latent_sq = np.sum(diff**2 * inv_ls2, axis=2)  # (L, L)
        sq += latent_sq[self._z_objects][:, self._objects]
        sq *= -0.5
        np.exp(sq, out=sq)
        return np.asarray(sq, dtype=np.float64)

    def _inducing_gram(
        self, latents: FloatArray, inv_ls2: FloatArray, inv_lx2: FloatArray
    ) -> FloatArray:
        """k^s(s_u, s_u') k^x(z_u, z_u') without σ_f² or jitter. Shape (m, m)."""
        z = self._z * np.sqrt(inv_lx2)
        norms = np.sum(z**2, axis=1)
        sq = np.maximum(norms[:, None] + norms[None, :] - 2.0 * z @ z.T, 0.0)
        diff = latents[:, None, :] - latents[None, :, :]
        latent_sq = np.sum(diff**2 * inv_ls2, axis=2)
        sq += latent_sq[self._z_objects][:, self._z_objects]
        return np.asarray(np.exp(-0.5 * sq), dtype=np.float64)

    def _chol_uu(
        self, gram_uu: FloatArray, signal: float, feature: int
    ) -> tuple[FloatArray, float]:
        return cholesky_with_jitter(
            signal * gram_uu,
            tuple(self.relative_jitter * step for step in _JITTER_STEPS),
            f"K_uu of feature {feature}",
            scale=signal,
            scale_name="σ_f²",
            advice="Use fewer inducing points or check for duplicate actions.",
        )

    # -- the bound ---------------------------------------------------------------------------

    def _feature(
        self,
        y: FloatArray,
        k_uf: FloatArray,
        gram_uu: FloatArray,
        signal: float,
        noise: float,
        a: int,
    ) -> tuple[_FeatureState, FloatArray]:
        """F of one feature and V = L_u⁻¹ K_uf."""
        n = y.shape[0]
        m = gram_uu.shape[0]
        precision = 1.0 / noise
        chol_uu, jitter = self._chol_uu(gram_uu, signal, a)
        v = scipy.linalg.solve_triangular(chol_uu, k_uf, lower=True, check_finite=False)
        b = precision * (v @ v.T)
        trace_q = float(np.trace(b)) / precision  # tr(V Vᵀ) = tr(Q)
        b[np.diag_indices(m)] += 1.0
        chol_b = scipy.linalg.cholesky(b, lower=True, check_finite=False)
        gamma = scipy.linalg.solve_triangular(chol_b, v @ y, lower=True, check_finite=False)
        # Titsias (2009) bound; docs/method.md eq. (M2) with Q + σ_n² I for K_a
        bound = (
            -0.5 * n * (_LOG_2PI + np.log(noise))
            - float(np.sum(np.log(np.diag(chol_b))))
            - 0.5 * precision * float(y @ y)
            + 0.5 * precision**2 * float(gamma @ gamma)
            - 0.5 * precision * (n * signal - trace_q)
        )
        weights = precision * scipy.linalg.solve_triangular(
            chol_uu,
            scipy.linalg.solve_triangular(chol_b, gamma, lower=True, trans="T", check_finite=False),
            lower=True,
            trans="T",
            check_finite=False,
        )
        state = _FeatureState(
            bound=float(bound), chol_uu=chol_uu, chol_b=chol_b, weights=weights, jitter=jitter
        )
        return state, v

    def _split(self, vector: FloatArray) -> tuple[FloatArray, ...]:
        latents, log_sf, log_sn, log_ls, log_lx = self.layout.split(vector)
        return (
            latents,
            np.exp(log_sf),
            np.exp(log_sn),
            np.exp(-2.0 * log_ls),
            np.exp(-2.0 * log_lx),
        )

    def states(self, vector: FloatArray) -> list[_FeatureState]:
        """Per-feature factorisations at a packed vector (for conditioning)."""
        latents, signal, noise, inv_ls2, inv_lx2 = self._split(vector)
        out = []
        for a in range(self.layout.observation_dim):
            k_uf = signal[a] * self._cross(latents, inv_ls2[a], inv_lx2[a])
            gram_uu = self._inducing_gram(latents, inv_ls2[a], inv_lx2[a])
            state, _ = self._feature(
                self._centred[a], k_uf, gram_uu, float(signal[a]), float(noise[a]), a
            )
            out.append(state)
        self.max_jitter = max(self.max_jitter, max(s.jitter for s in out))
        return out

    def value(self, vector: FloatArray) -> float:
        """-F at a packed vector."""
        self.evaluations += 1
        return -sum(state.bound for state in self.states(vector))

    def value_and_gradient(self, vector: FloatArray) -> tuple[float, FloatArray]:
        """-F and its gradient with respect to the packed vector (same layout)."""
        self.evaluations += 1
        layout = self.layout
        latents, signal, noise, inv_ls2, inv_lx2 = self._split(vector)
        n_objects, ds = latents.shape
        dy, dx = inv_lx2.shape
        n = self.data.n_touches
        z, x = self._z, self._actions
        sq_pair = (latents[:, None, :] - latents[None, :, :]) ** 2  # (L, L, ds)
        total = 0.0
        g_sf = np.empty(dy)
        g_sn = np.empty(dy)
        g_ls = np.empty((dy, ds))
        g_lx = np.empty((dy, dx))
        g_latents = np.zeros((n_objects, ds))
        for a in range(dy):
            y = self._centred[a]
            k_uf = self._cross(latents, inv_ls2[a], inv_lx2[a])
            k_uf *= signal[a]
            gram_uu = self._inducing_gram(latents, inv_ls2[a], inv_lx2[a])
            state, v = self._feature(y, k_uf, gram_uu, float(signal[a]), float(noise[a]), a)
            self.max_jitter = max(self.max_jitter, state.jitter)
            total += state.bound
            precision = 1.0 / noise[a]
            m = gram_uu.shape[0]
            c = state.weights
            # K_uu⁻¹ = L_u⁻ᵀ L_u⁻¹; A⁻¹ = L_u⁻ᵀ B⁻¹ L_u⁻¹
            inv_lu = scipy.linalg.solve_triangular(
                state.chol_uu, np.eye(m), lower=True, check_finite=False
            )
            inv_b = scipy.linalg.cho_solve((state.chol_b, True), np.eye(m), check_finite=False)
            # K_uu⁻¹ - A⁻¹ - ccᵀ, with K_uu⁻¹ - A⁻¹ = L_u⁻ᵀ (I - B⁻¹) L_u⁻¹
            p1 = inv_lu.T @ (np.eye(m) - inv_b) @ inv_lu - np.outer(c, c)
            vvt = v @ v.T
            # ∂F/∂K_uu = ½ (K_uu⁻¹ - A⁻¹ - ccᵀ - β_n K_uu⁻¹ Ψ₂ K_uu⁻¹)
            g_uu = 0.5 * (p1 - precision * (inv_lu.T @ vvt @ inv_lu))
            # ∂F/∂K_uf = β_n (c yᵀ + (K_uu⁻¹ - A⁻¹ - ccᵀ) K_uf)
            g_uf = p1 @ k_uf
            g_uf += np.outer(c, y)
            g_uf *= precision
            # ∂F/∂β_n, then ∂F/∂log σ_n² = -β_n ∂F/∂β_n
            kfu_c = c @ k_uf  # (N,)
            trace_vvt = float(np.trace(vvt))
            d_precision = (
                0.5 * n / precision
                - 0.5 * (m - float(np.trace(inv_b))) / precision
                - 0.5 * float(y @ y)
                + float(kfu_c @ y)
                - 0.5 * float(kfu_c @ kfu_c)
                - 0.5 * n * signal[a]
                + 0.5 * trace_vvt
            )
            g_sn[a] = -precision * d_precision
            gram_full = signal[a] * gram_uu
            gram_full[np.diag_indices(m)] += state.jitter
            m_uu = g_uu * gram_full  # includes the jitter, ∝ σ_f² like the rest of K_uu
            m_uf = g_uf * k_uf
            g_sf[a] = float(m_uu.sum() + m_uf.sum()) - 0.5 * precision * n * signal[a]
            # Off the diagonal K_uu has no jitter; the diagonal has zero distances anyway.
            # Action length-scales: Σ_ij M_ij (z_id - x_jd)² / ℓ_d²
            r_uu = m_uu.sum(axis=1)
            r_uf, col_uf = m_uf.sum(axis=1), m_uf.sum(axis=0)
            lx_terms = (
                2.0 * (r_uu @ z**2 - np.sum(z * (m_uu @ z), axis=0))
                + r_uf @ z**2
                + col_uf @ x**2
                - 2.0 * np.sum(z * (m_uf @ x), axis=0)
            )
            g_lx[a] = lx_terms * inv_lx2[a]
            # Latent parts through the L × L block sums.
            blocks_uf = np.add.reduceat(m_uf, self._starts, axis=1)  # (m, L)
            blocks_uf[:, ~self._present] = 0.0
            blocks = self._z_indicator @ (blocks_uf + m_uu @ self._z_indicator.T)  # (L, L)
            g_ls[a] = np.einsum("lm,lmd->d", blocks, sq_pair) * inv_ls2[a]
            sym = blocks + blocks.T
            g_latents -= (latents * sym.sum(axis=1)[:, None] - sym @ latents) * inv_ls2[a]
        grad = layout.join(g_latents, g_sf, g_sn, g_ls, g_lx)
        return -total, -grad


def condition_sparse(
    data: TrainingData,
    latents: FloatArray,
    hyperparameters: Hyperparameters,
    diagnostics: FitDiagnostics | None = None,
    inducing: InducingPoints | None = None,
    n_inducing: int = DEFAULT_INDUCING_POINTS,
    jitter: float = DEFAULT_JITTER,
) -> ManifoldModel:
    """Build a :class:`ManifoldModel` with the sparse variational posterior.

    ``log_likelihood`` holds the bound F (≤ the exact log-likelihood); the posterior is
    ``"sparse"``: β = c over the inducing points and ``gram_inverse`` = K_uu⁻¹ - A⁻¹.

    Args:
        data: Training touches.
        latents: Object latents. Shape (L, ds).
        hyperparameters: Per-feature hyperparameters.
        diagnostics: Optional fit diagnostics.
        inducing: Inducing points (selected with :func:`select_inducing_points` when ``None``).
        n_inducing: m when ``inducing`` is ``None``.
        jitter: Relative jitter on K_uu.
    """
    h = hyperparameters
    latents = check_conditioning(data, latents, h)
    likelihood = SparseLikelihood(data, h.latent_dim, inducing, n_inducing, jitter)
    states = likelihood.states(likelihood.layout.pack(latents, h))
    m = likelihood.inducing.size
    beta = np.stack([s.weights for s in states])
    matrix = np.empty((h.observation_dim, m, m))
    for a, state in enumerate(states):
        inv_lu = scipy.linalg.solve_triangular(
            state.chol_uu, np.eye(m), lower=True, check_finite=False
        )
        inv_b = scipy.linalg.cho_solve((state.chol_b, True), np.eye(m), check_finite=False)
        core = np.eye(m) - inv_b  # K_uu⁻¹ - A⁻¹ = L_u⁻ᵀ (I - B⁻¹) L_u⁻¹
        matrix[a] = inv_lu.T @ core @ inv_lu
        matrix[a] = 0.5 * (matrix[a] + matrix[a].T)
    jitter_used = np.array([s.jitter for s in states])
    latents = latents.copy()
    for array in (latents, beta, matrix, jitter_used):
        array.flags.writeable = False
    return ManifoldModel(
        data=data,
        latents=latents,
        hyperparameters=h,
        posterior=GPPosterior(
            beta=beta, gram_inverse=matrix, jitter=jitter_used, inducing=likelihood.inducing
        ),
        log_likelihood=float(sum(s.bound for s in states)),
        diagnostics=diagnostics,
    )
