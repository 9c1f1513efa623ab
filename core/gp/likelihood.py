"""Negative log marginal likelihood of the object manifold and its analytic gradient (M2).

    -log p(Y | S, X, γ) = Σ_a ½ y_aᵀ K_a⁻¹ y_a + ½ log det K_a + (N/2) log 2π   docs/method.md (M2)

with K_a = σ_f,a² K^s_a[obj, obj] ∘ K^x_a + σ_n,a² I (eq. (M1)) and y_a centred on the
per-feature observation mean (as :func:`core.gp.posterior.condition` does). With a placement
variance σ_b,a² (held fixed) the noise part is σ_b,a² Z Zᵀ + σ_n,a² I instead: touches sharing a
placement share an offset (:mod:`core.gp.placement_groups`), every touch meets one, and the
fitted σ_n,a² is then the within-placement noise σ_w,a².

Gradient. With W_a = K_a⁻¹ - β_a β_aᵀ, ∂(-log p)/∂K_a = ½ W_a. Writing M_a = W_a ∘ K_f,a for the
noise-free part K_f,a = K_a - σ_n,a² I, every derivative is a weighted sum of M_a:

* log σ_f²:   ½ Σ_ij M_ij
* log σ_n²:   ½ σ_n² tr W
* log ℓ^x_d:  ½ Σ_ij M_ij (x_id - x_jd)² / ℓ_d²  =  (Σ_i r_i x_id² - x_dᵀ M x_d) / ℓ_d², r = M 1
* log ℓ^s_d:  ½ Σ_ll' B_ll' (s_ld - s_l'd)² / ℓ_d²
* s_ld:       -Σ_l' B_ll' (s_ld - s_l'd) / ℓ_d²

where B = Pᵀ M P (P the N × L object indicator) holds the L × L block sums of M: the latent is
shared by an object's touches, so its gradient sums theirs. Everything is O(N² dx) per
feature on top of the Cholesky factor and the inverse (computed once, from the factor).

Cost. M is symmetric, so only one triangle of W is formed (K⁻¹ by
:func:`core.gp.linalg.inverse_from_cholesky`, ββᵀ subtracted by a rank-1 ``dsyr``) and multiplied
into K_f in place; with X that triangle, M = X + Xᵀ - diag(X) and every sum above is a sum over
X. At N = 400 an evaluation costs about the factor and the inverse of each K_a (``dpotrf`` +
``dpotri`` timed alone: ``python -m bench.eval_speed``).

Threads. Each feature's factor, solve, inverse and product are independent LAPACK/BLAS calls
that release the GIL, so with ``threads`` > 1 the features run on a pool of Python threads
(BLAS itself stays on one thread per Python thread: run under ``threadpoolctl``'s limit of one,
as the ``activetouch`` commands do). Each feature's numbers are computed by the same calls on
whichever thread, and the terms are summed in feature order afterwards, so the value and the
gradient are bit-identical to one thread's.
"""

from __future__ import annotations

import concurrent.futures
import copy
import functools
import threading
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import TypeVar

import numpy as np
import scipy.linalg.blas
import scipy.linalg.lapack

from core.errors import InvalidInputError
from core.gp.factor_inverse import spd_inverse
from core.gp.linalg import cholesky_with_jitter, inverse_from_cholesky
from core.gp.parameters import ParameterLayout
from core.gp.placement_groups import checked_placement_variance, shared_groups
from core.gp.unlocked_lapack import potrf_upper
from core.types import Hyperparameters, TrainingData
from core.validation import FloatArray, as_float_array

_LOG_2PI = float(np.log(2.0 * np.pi))

_T = TypeVar("_T")

#: Kernel values below e^LOG_KERNEL_FLOOR · σ_f² (10⁻⁵⁰ of the signal variance) are set to exact
#: zeros. Objects far apart in a short latent length-scale give entries down to 10⁻³²⁴; the
#: factor and inverse of such a matrix then compute with subnormal numbers, which this
#: processor handles ~100 times slower than normal ones: an evaluation at ds = 1 took twice
#: as long as at ds = 5 (docs/fitting.md, "Subnormal numbers"). The change to K is 10⁻⁵⁰
#: relative, 34 orders of magnitude below the rounding of its factorisation.
LOG_KERNEL_FLOOR = -50.0 * float(np.log(10.0))

#: Rows per block of :func:`lower_blocks`: each block costs a few ufunc calls (~µs each) and
#: exponentiates ½ · block · N entries above the diagonal that nobody reads (8 % more than the
#: triangle at N = 800).
LOWER_BLOCK_ROWS = 64


@functools.lru_cache(maxsize=16)
def lower_blocks(n: int) -> tuple[tuple[int, int, int], ...]:
    """Row blocks (first, stop, width) whose [first:stop, :width] parts cover the lower
    triangle and the diagonal of an n × n matrix (width = stop)."""
    return tuple(
        (first, min(first + LOWER_BLOCK_ROWS, n), min(first + LOWER_BLOCK_ROWS, n))
        for first in range(0, n, LOWER_BLOCK_ROWS)
    )


#: One pool of feature threads per thread count, shared by every likelihood of the process.
_POOLS: dict[int, ThreadPoolExecutor] = {}
_POOLS_LOCK = threading.Lock()


def feature_pool(threads: int) -> ThreadPoolExecutor:
    """The process's pool of ``threads`` feature threads (created on first use)."""
    with _POOLS_LOCK:
        pool = _POOLS.get(threads)
        if pool is None:
            pool = ThreadPoolExecutor(threads, thread_name_prefix="likelihood-feature")
            _POOLS[threads] = pool
        return pool


def check_threads(threads: object) -> int:
    """``threads`` as an int ≥ 1.

    Raises:
        InvalidInputError: Not an integer ≥ 1.
    """
    if isinstance(threads, bool) or not isinstance(threads, int | np.integer) or threads < 1:
        raise InvalidInputError(f"threads: expected an integer ≥ 1, received {threads!r}.")
    return int(threads)


@dataclass(frozen=True)
class LikelihoodGradient:
    """∂(-log p)/∂ of every group of unknowns.

    Attributes:
        latents: With respect to S. Shape (L, ds).
        log_signal_variance: With respect to log σ_f². Shape (dy,).
        log_noise_variance: With respect to log σ_n². Shape (dy,).
        log_latent_lengthscales: With respect to log ℓ^s. Shape (dy, ds).
        log_action_lengthscales: With respect to log ℓ^x. Shape (dy, dx).
    """

    latents: FloatArray
    log_signal_variance: FloatArray
    log_noise_variance: FloatArray
    log_latent_lengthscales: FloatArray
    log_action_lengthscales: FloatArray


@dataclass(frozen=True)
class ProductSums:
    """The O(N²) sums of one row's X = tril(W) ∘ K_f behind the kernel gradient.

    Attributes:
        diagonal: X's diagonal, in the internal order. Shape (N,).
        lower_blocks: Pᵀ X P, X's block sums per pair of objects. Shape (L, L).
        action_terms: Σ_ij X_ij (x_id - x_jd)² per action dimension. Shape (dx,).
    """

    diagonal: FloatArray
    lower_blocks: FloatArray
    action_terms: FloatArray


class ManifoldLikelihood:
    """-log p(Y | S, X, γ) and its gradient at packed parameter vectors (see
    :mod:`core.gp.parameters`), with the data-only terms computed once.

    Internally the touches are sorted by object (the likelihood does not depend on their order),
    so that the L × L latent Gram matrix expands into contiguous blocks and the block sums of
    the gradient are two ``reduceat`` passes.

    Not a result type: it counts evaluations and remembers the largest jitter it needed
    (:attr:`max_jitter`), which a fit reports.

    Args:
        data: Training touches.
        latent_dim: ds ≥ 1.
        threads: Python threads the features of one evaluation run on (module docstring);
            the results do not depend on it.
        placement_variance: σ_b,a² ≥ 0 per feature, held fixed: the variance of the offset
            shared by the touches of one placement (module docstring); the packed noise
            variance is then the within-placement σ_w,a². Needs ``data.placement_index``.
            ``None``: independent noise. Shape (dy,).
    """

    def __init__(
        self,
        data: TrainingData,
        latent_dim: int,
        threads: int = 1,
        placement_variance: FloatArray | None = None,
    ) -> None:
        if isinstance(latent_dim, bool) or int(latent_dim) != latent_dim or latent_dim < 1:
            raise InvalidInputError(f"latent_dim: must be an integer ≥ 1, received {latent_dim}.")
        self.threads = check_threads(threads)
        self.data = data
        self.layout = ParameterLayout.for_data(data, int(latent_dim))
        self.placement_variance = _training_placement_variance(
            placement_variance, data, self.layout.observation_dim
        )
        placement = data.placement_index
        if self.placement_variance is not None and placement is not None:
            # Touches of one placement contiguous (inside their object's block).
            order = np.lexsort((placement, data.object_index))
            sorted_groups = shared_groups(data.object_index[order], placement[order])
            self._blocks = [(int(g[0]), int(g[-1]) + 1) for g in sorted_groups]
        else:
            order = np.argsort(data.object_index, kind="stable")
            self._blocks = []
        # Centred actions: squared distances are shift invariant and lose less precision.
        actions = data.actions[order] - data.actions.mean(axis=0)
        self._actions = np.ascontiguousarray(actions)
        self._order = order
        self._touch_object = data.object_index[order]
        self._centred = np.ascontiguousarray((data.observations[order] - data.observation_mean).T)
        self._counts = data.touches_per_object()
        self._starts = np.concatenate([[0], np.cumsum(self._counts)[:-1]]).astype(np.intp)
        n = actions.shape[0]
        self._diag = np.arange(n) * (n + 1)
        self.max_jitter = 0.0
        self.evaluations = 0

    def for_feature(self, feature: int) -> ManifoldLikelihood:
        """The likelihood of feature ``feature`` alone (dy = 1: its touches as
        ``TrainingData`` with that one column), sharing this one's action and object caches
        instead of building them again (the squared action differences are dx · N² numbers);
        its values are bit for bit those of a likelihood built from the one-feature data."""
        dy = self.layout.observation_dim
        if isinstance(feature, bool) or not 0 <= int(feature) < dy:
            raise InvalidInputError(f"feature: expected 0 … {dy - 1}, received {feature!r}.")
        a = int(feature)
        one = copy.copy(self)
        one.data = feature_data(self.data, a)
        one.layout = ParameterLayout.for_data(one.data, self.layout.latent_dim)
        # Centred on the one column's own mean, as a likelihood of the one-feature data is
        # (the mean of a column alone may differ from its entry of all columns' in the last bit).
        one._centred = np.ascontiguousarray(
            (one.data.observations[self._order] - one.data.observation_mean).T
        )
        if self.placement_variance is not None:
            one.placement_variance = self.placement_variance[a : a + 1]
        one.max_jitter = 0.0
        one.evaluations = 0
        return one

    def noise_free_gram(self, vector: FloatArray) -> FloatArray:
        """K_f,a = σ_f,a² K^s_a[obj, obj] ∘ K^x_a for every feature, docs/method.md eq. (M1).

        Rows and columns are in the internal (object-sorted) order (:meth:`gram_rows`).
        Shape (dy, N, N).
        """
        latents, log_sf, _, log_ls, log_lx = self.layout.split(vector)
        return self.gram_rows(latents, log_sf, log_ls, log_lx)

    def gram_rows(
        self,
        latents: FloatArray,
        log_sf: FloatArray,
        log_ls: FloatArray,
        log_lx: FloatArray,
        lower_only: bool = False,
    ) -> FloatArray:
        """σ_f,r² K^s_r[obj, obj] ∘ K^x_r for every row r of length-scales (the noise-free Gram
        matrix of each feature, or the one unit-variance K of tied kernels), in the internal
        order.

        Each touch i gets its scaled coordinates z_i = [x_i / ℓ^x_r, s_obj(i) / ℓ^s_r] (actions
        and latents centred: differences are shift invariant), and the exponent
        log σ_f² - ½ |z_i - z_j|² = (log σ_f² - ½|z_i|²) + z_i·z_j - ½|z_j|² is one GEMM of
        the augmented rows [z_i, log σ_f² - ½|z_i|², 1] and [z_j, 1, -½|z_j|²]: a single
        pass that writes the N × N matrix, then the exponentials. Cheaper than adding
        cached per-dimension squared differences and the latent blocks (several passes over
        N² numbers: docs/fitting.md, "The Gram matrix in one GEMM"). The expanded form loses
        ~ε|z|² absolutely, so the diagonal is set exactly and no exponent is let above
        log σ_f².

        With ``lower_only`` the exponentials are taken on the lower triangle alone (in row
        blocks of :data:`LOWER_BLOCK_ROWS`, so a little above it too): every evaluation reads
        only that triangle (the factor, the inverse and the gradient's products), and on a
        processor without a vector exponential for float64 (AVX2: NumPy's is AVX-512 only)
        the exponentials are a fifth of an evaluation (docs/fitting.md, "Half the
        exponentials"). Entries above the diagonal are then unspecified, finite for finite
        inputs.

        Args:
            latents: S. Shape (L, ds).
            log_sf: log σ_f² per row. Shape (R,).
            log_ls: log ℓ^s per row. Shape (R, ds).
            log_lx: log ℓ^x per row. Shape (R, dx).
            lower_only: Only the lower triangle (and the diagonal) is the kernel.

        Returns:
            Shape (R, N, N).
        """
        rows = log_sf.shape[0]
        n = self._actions.shape[0]
        centred_latents = self._touch_latents(latents)
        exponent = np.empty((rows, n, n))

        def row(r: int) -> None:
            self._gram_row(
                exponent[r], centred_latents, log_sf[r], log_ls[r], log_lx[r], lower_only
            )

        # A row each on the feature threads (a fifth of an evaluation at N = 800): the same
        # calls on any thread, so the same numbers on any number of threads.
        self._per_feature(row, rows)
        return exponent

    def _touch_latents(self, latents: FloatArray) -> FloatArray:
        """Each touch's latent, S centred (differences are shift invariant), in the internal
        order. Shape (N, ds)."""
        centred: FloatArray = (latents - latents.mean(axis=0))[self._touch_object]
        return centred

    def _feature_gram(
        self, vector: FloatArray, lower_only: bool = True
    ) -> Callable[[int], FloatArray]:
        """A function of feature a giving K_f,a (:meth:`gram_rows`'s row a; by default only
        its lower triangle, what an evaluation reads), for the feature thread that factorises
        it. The rows share one (dy, N, N) array allocated here: glibc then serves the
        per-feature N × N copies from its heap, where N × N arrays of their own would each be
        a fresh ``mmap`` faulted in page by page (a tenth of an evaluation at N = 800)."""
        latents, log_sf, _, log_ls, log_lx = self.layout.split(vector)
        touch_latents = self._touch_latents(latents)
        n = self._actions.shape[0]
        grams = np.empty((log_sf.shape[0], n, n))

        def gram(a: int) -> FloatArray:
            out: FloatArray = grams[a]
            self._gram_row(out, touch_latents, log_sf[a], log_ls[a], log_lx[a], lower_only)
            return out

        return gram

    def _gram_row(
        self,
        out: FloatArray,
        centred_latents: FloatArray,
        log_sf: float,
        log_ls: FloatArray,
        log_lx: FloatArray,
        lower_only: bool,
    ) -> None:
        """One row of :meth:`gram_rows` into ``out`` (N, N): the exponent by one GEMM of the
        augmented rows, the diagonal set exactly, then the exponentials."""
        n, dx = self._actions.shape
        ds = centred_latents.shape[1]
        left = np.empty((n, dx + ds + 2))
        right = np.empty((n, dx + ds + 2))
        left[:, -1] = 1.0
        right[:, -2] = 1.0
        z = left[:, : dx + ds]
        np.multiply(self._actions, np.exp(-log_lx), out=z[:, :dx])
        np.multiply(centred_latents, np.exp(-log_ls), out=z[:, dx:])
        half = -0.5 * np.einsum("nd,nd->n", z, z)
        right[:, : dx + ds] = z
        right[:, -1] = half
        left[:, -2] = half + log_sf
        np.matmul(left, right.T, out=out)
        cutoff = log_sf + LOG_KERNEL_FLOOR
        out.ravel()[self._diag] = log_sf
        for first, stop, width in lower_blocks(n) if lower_only else ((0, n, n),):
            part = out[first:stop, :width]
            np.minimum(part, log_sf, out=part)
            # Entries below the floor become exact zeros (exp(-inf)), not subnormal numbers.
            np.copyto(part, -np.inf, where=part < cutoff)
            np.exp(part, out=part)

    def _noisy(self, gram_free: FloatArray, noise: float, feature: int) -> FloatArray:
        """K_a: a copy of K_f,a plus σ_n² I, and with a placement variance σ_b² Z Zᵀ (on the
        diagonal and on the entries of touches sharing a placement)."""
        gram = gram_free.copy()
        if self.placement_variance is None:
            gram.ravel()[self._diag] += noise
            return gram
        shared = float(self.placement_variance[feature])
        gram.ravel()[self._diag] += noise + shared
        for first, stop in self._blocks:
            gram[first:stop, first:stop] += shared
            gram.ravel()[self._diag[first:stop]] -= shared
        return gram

    def _factor(
        self, gram_free: FloatArray, noise: float, feature: int
    ) -> tuple[FloatArray, float]:
        """Upper Cholesky factor U of K_a = UᵀU (:meth:`_noisy`), Fortran-ordered with a zero
        strictly lower triangle (what LAPACK reads without copying), and the jitter added
        (0 unless the plain factorisation failed). Reads only the lower triangle of
        ``gram_free`` (C order), both on the fast path and on the jitter ladder."""
        gram = self._noisy(gram_free, noise, feature)
        # Fast path: plain LAPACK in place on the symmetric matrix (its transpose is itself, so
        # the C-ordered copy is read as Fortran). Jitter ladder only on failure.
        # (core.gp.unlocked_lapack: without the GIL, so feature threads factorise at once.)
        upper = gram.T
        if potrf_upper(upper) == 0:
            return upper, 0.0
        gram = self._noisy(gram_free, noise, feature)
        factor, jitter = cholesky_with_jitter(gram, what=f"Gram matrix of feature {feature}")
        return np.asarray(factor.T, dtype=np.float64), float(jitter)

    def _log_det(self, upper: FloatArray) -> float:
        """log det K = 2 Σ log U_ii of an upper Cholesky factor (Fortran-ordered)."""
        return 2.0 * float(np.sum(np.log(upper.ravel(order="F")[self._diag])))

    def _inverse(
        self, gram_free: FloatArray, noise: float, feature: int
    ) -> tuple[FloatArray, FloatArray, float, float]:
        """K_a⁻¹ (upper triangle of a Fortran-ordered array, strictly lower triangle zero),
        β = K_a⁻¹ y_a, log det K_a and the jitter added (0 unless the plain factorisation
        failed). K_a⁻¹ in place of a copy of K_a by :func:`core.gp.factor_inverse.spd_inverse`
        and β from it; on failure the jitter ladder of :meth:`_factor`, and β by solves with
        its factor (the matrix is then nearly singular, where solves lose less)."""
        y = self._centred[feature]
        inverse = self._noisy(gram_free, noise, feature).T
        info, log_det = spd_inverse(inverse)
        if info == 0:
            beta = scipy.linalg.blas.dsymv(1.0, inverse, y, lower=0)
            return inverse, beta, log_det, 0.0
        upper, jitter = self._factor(gram_free, noise, feature)
        beta, info = scipy.linalg.lapack.dpotrs(upper, y, lower=0)
        if info:  # pragma: no cover - the factor came from a successful Cholesky
            raise InvalidInputError(f"dpotrs failed on feature {feature}.")
        log_det = self._log_det(upper)
        return inverse_from_cholesky(upper), beta, log_det, jitter

    def _per_feature(self, work: Callable[[int], _T], count: int | None = None) -> list[_T]:
        """``work(a)`` for every feature a (or every a < ``count``), in feature order; on the
        pool when ``threads`` > 1. The first error of any feature is raised (after every
        feature has ended)."""
        dy = self.layout.observation_dim if count is None else count
        if self.threads == 1 or dy == 1:
            return [work(a) for a in range(dy)]
        futures = [feature_pool(self.threads).submit(work, a) for a in range(dy)]
        concurrent.futures.wait(futures)  # no feature still running when an error is raised
        return [future.result() for future in futures]

    def value(self, vector: FloatArray) -> float:
        """-log p at a packed vector (no gradient: one Cholesky factor per feature)."""
        self.evaluations += 1
        _, _, log_sn, _, _ = self.layout.split(vector)
        gram = self._feature_gram(vector)
        n = self.data.n_touches

        def feature(a: int) -> tuple[float, float]:
            upper, jitter = self._factor(gram(a), float(np.exp(log_sn[a])), a)
            # α = U⁻ᵀ y, so yᵀ K⁻¹ y = |α|²
            alpha, info = scipy.linalg.lapack.dtrtrs(upper, self._centred[a], lower=0, trans=1)
            if info:  # pragma: no cover - the factor came from a successful Cholesky
                raise InvalidInputError(f"dtrtrs failed on feature {a}.")
            log_det = self._log_det(upper)
            # docs/method.md eq. (M2)
            return 0.5 * float(alpha @ alpha) + 0.5 * log_det + 0.5 * n * _LOG_2PI, jitter

        total = 0.0
        for term, jitter in self._per_feature(feature):  # summed in feature order
            total += term
            self.max_jitter = max(self.max_jitter, jitter)
        return total

    def value_and_gradient(self, vector: FloatArray) -> tuple[float, FloatArray]:
        """-log p and its gradient with respect to the packed vector (same layout).

        Only one triangle of W = K⁻¹ - ββᵀ is formed (K⁻¹ in place of a copy of K by
        :func:`core.gp.factor_inverse.spd_inverse`, β = K⁻¹ y, then a rank-1 ``dsyr`` update):
        with X its lower triangle times K_f, M = X + Xᵀ - diag(X), so Σ M = 2 Σ X - tr X,
        ½ Σ M ∘ Δ = Σ X ∘ Δ for the zero-diagonal squared action differences Δ, and the block
        sums are Pᵀ X P + (Pᵀ X P)ᵀ minus the diagonal's.
        """
        self.evaluations += 1
        layout = self.layout
        latents, _, log_sn, log_ls, log_lx = layout.split(vector)
        noise = np.exp(log_sn)
        inv_ls2 = np.exp(-2.0 * log_ls)  # (dy, ds)
        inv_lx2 = np.exp(-2.0 * log_lx)  # (dy, dx)
        gram = self._feature_gram(vector)
        n = self.data.n_touches
        dy = layout.observation_dim

        def feature(a: int) -> tuple[float, float, float, ProductSums]:
            """Feature a's term of -log p, its ∂/∂log σ_n², the jitter and the sums of
            X_a = tril(W_a) ∘ K_f,a: the whole of feature a's work, on one thread."""
            gram_free = gram(a)
            inverse, beta, log_det, jitter = self._inverse(gram_free, float(noise[a]), a)
            y = self._centred[a]
            # docs/method.md eq. (M2)
            term = 0.5 * float(y @ beta) + 0.5 * log_det + 0.5 * n * _LOG_2PI
            # Upper triangle (Fortran) of W = K⁻¹ - ββᵀ: ∂(-log p)/∂K = ½ W. Its C-ordered
            # transpose holds W in the lower triangle and zeros above.
            inverse = scipy.linalg.blas.dsyr(-1.0, beta, lower=0, a=inverse, overwrite_a=1)
            half = inverse.T
            g_sn_a = 0.5 * noise[a] * float(half.ravel()[self._diag].sum())
            gram_free *= half  # X_a = tril(W_a) ∘ K_f,a, in place of K_f,a
            return term, g_sn_a, jitter, self.product_sums(gram_free)

        g_sn = np.empty(dy)
        total = 0.0
        sums = []
        for a, (term, g_sn_a, jitter, sums_a) in enumerate(self._per_feature(feature)):
            total += term  # summed in feature order, whichever thread computed it
            g_sn[a] = g_sn_a
            sums.append(sums_a)
            self.max_jitter = max(self.max_jitter, jitter)
        g_latents, g_sf, g_ls, g_lx = self.gradient_from_sums(sums, latents, inv_ls2, inv_lx2)
        grad = layout.join(g_latents, g_sf, g_sn, g_ls, g_lx)
        return total, grad

    def kernel_gradient(
        self, products: FloatArray, latents: FloatArray, inv_ls2: FloatArray, inv_lx2: FloatArray
    ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        """The gradient's sums over M = W ∘ K_f (module docstring), per row r of length-scales.

        Args:
            products: X_r = tril(W_r) ∘ K_f,r. Shape (R, N, N).
            latents: S. Shape (L, ds).
            inv_ls2: 1/ℓ^s² per row. Shape (R, ds).
            inv_lx2: 1/ℓ^x² per row. Shape (R, dx).

        Returns:
            ∂/∂S (L, ds) summed over rows, ½ Σ M_r per row (R,) (∂/∂log σ_f² of a feature's
            own row), ∂/∂log ℓ^s (R, ds) and ∂/∂log ℓ^x (R, dx).
        """
        sums = self._per_feature(lambda r: self.product_sums(products[r]), products.shape[0])
        return self.gradient_from_sums(sums, latents, inv_ls2, inv_lx2)

    def product_sums(self, product: FloatArray) -> ProductSums:
        """The O(N²) sums of one row's X = tril(W) ∘ K_f that the gradient needs (on the
        feature thread that formed X, while X is still in its cache).

        Args:
            product: X. Shape (N, N).
        """
        partial = np.add.reduceat(product, self._starts, axis=1)  # X P, (N, L)
        # Σ_ij X_ij (x_id - x_jd)² = Σ_i (r_i + c_i) x_id² - 2 x_dᵀ X x_d, r and c the row and
        # column sums of X (zero diagonal of Δ: X's diagonal adds nothing).
        x = self._actions
        line_sums = np.sum(partial, axis=1) + np.sum(product, axis=0)
        quadratic = np.einsum("nd,nd->d", product @ x, x)
        return ProductSums(
            diagonal=product.ravel()[self._diag],
            lower_blocks=np.add.reduceat(partial, self._starts, axis=0),  # Pᵀ X P
            action_terms=line_sums @ x**2 - 2.0 * quadratic,
        )

    def gradient_from_sums(
        self,
        sums: list[ProductSums],
        latents: FloatArray,
        inv_ls2: FloatArray,
        inv_lx2: FloatArray,
    ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        """:meth:`kernel_gradient` from every row's :meth:`product_sums` (in row order)."""
        diagonals = np.stack([row.diagonal for row in sums])  # (R, N)
        lower_blocks = np.stack([row.lower_blocks for row in sums])  # (R, L, L)
        g_sf = np.sum(lower_blocks, axis=(1, 2)) - 0.5 * np.sum(diagonals, axis=1)
        g_lx = np.stack([row.action_terms for row in sums]) * inv_lx2
        blocks = lower_blocks + np.swapaxes(lower_blocks, 1, 2)  # B = Pᵀ M P
        diagonal_blocks = np.add.reduceat(diagonals, self._starts, axis=1)  # (R, L)
        blocks -= diagonal_blocks[:, :, None] * np.eye(self.layout.n_objects)
        sq_pair = (latents[:, None, :] - latents[None, :, :]) ** 2  # (L, L, ds)
        g_ls = 0.5 * np.einsum("alm,lmd->ad", blocks, sq_pair) * inv_ls2
        row_sums = blocks.sum(axis=2)  # (R, L)
        # ∂/∂s_l = -Σ_a Σ_l' B_a[l,l'] (s_l - s_l') / ℓ_a²
        g_latents = -(
            latents * (row_sums.T @ inv_ls2) - np.einsum("ald,ad->ld", blocks @ latents, inv_ls2)
        )
        return g_latents, g_sf, g_ls, g_lx


def feature_data(data: TrainingData, feature: int) -> TrainingData:
    """The touches with only feature ``feature`` observed (dy = 1)."""
    return TrainingData(
        object_names=data.object_names,
        object_index=data.object_index,
        actions=data.actions,
        observations=data.observations[:, feature : feature + 1],
        placement_index=data.placement_index,
        min_touches_per_object=data.min_touches_per_object,
    )


def _training_placement_variance(
    variance: FloatArray | None, data: TrainingData, observation_dim: int
) -> FloatArray | None:
    """σ_b² as dy values ≥ 0, or ``None``.

    Raises:
        InvalidInputError: Wrong length, negative, or given for data without placements.
    """
    if variance is None:
        return None
    value = checked_placement_variance(variance, None, observation_dim)
    if data.placement_index is None:
        raise InvalidInputError(
            "placement_variance: the training touches record no placements to share an offset."
        )
    return value


def negative_log_likelihood(
    data: TrainingData, latents: FloatArray, hyperparameters: Hyperparameters
) -> float:
    """-Σ_a log p(y_a | S, X, γ_a), docs/method.md eq. (M2).

    Args:
        data: Training touches (N of them, L objects).
        latents: Object latents. Shape (L, ds).
        hyperparameters: Per-feature hyperparameters.

    Returns:
        The negative log marginal likelihood; equals ``-condition(...).log_likelihood``.
    """
    likelihood, vector = _prepare(data, latents, hyperparameters)
    return likelihood.value(vector)


def negative_log_likelihood_and_gradient(
    data: TrainingData, latents: FloatArray, hyperparameters: Hyperparameters
) -> tuple[float, LikelihoodGradient]:
    """-log p and its analytic gradient with respect to S and the log-hyperparameters.

    Args:
        data: Training touches.
        latents: Object latents. Shape (L, ds).
        hyperparameters: Per-feature hyperparameters.

    Returns:
        The value and a :class:`LikelihoodGradient` (gradients with respect to the logs of
        σ_f², σ_n² and of the length-scales themselves, not of their squares).
    """
    likelihood, vector = _prepare(data, latents, hyperparameters)
    value, grad = likelihood.value_and_gradient(vector)
    s, sf, sn, ls, lx = likelihood.layout.split(grad)
    return value, LikelihoodGradient(
        latents=s.copy(),
        log_signal_variance=sf.copy(),
        log_noise_variance=sn.copy(),
        log_latent_lengthscales=ls.copy(),
        log_action_lengthscales=lx.copy(),
    )


def _prepare(
    data: TrainingData, latents: FloatArray, hyperparameters: Hyperparameters
) -> tuple[ManifoldLikelihood, FloatArray]:
    h = hyperparameters
    latents = as_float_array(latents, "latents", (data.n_objects, h.latent_dim))
    likelihood = ManifoldLikelihood(data, h.latent_dim)
    return likelihood, likelihood.layout.pack(latents, h)
