"""Hyperparameters with the latents held fixed: one small problem per feature.

With S fixed the negative log-likelihood of docs/method.md eq. (M2) is a sum of independent terms,

    -log p(Y | S, X, γ) = Σ_a -log p(y_a | S, X, γ_a),

one per feature a, each depending only on its own 2 + ds + dx log-hyperparameters γ_a. Optimising
them as dy separate L-BFGS-B problems is exact and much better conditioned than one joint problem
over every γ: each quasi-Newton model is built from its own feature's curvature, and one feature's
evaluation costs 1/dy of all of them. Because the terms are independent, several starting points
can be tried per feature and the best *per feature* kept — the combination is then at least as
good as every start.

The starts differ in the initial latent length-scale. From a long one (objects look alike) the
first quasi-Newton steps can overshoot into the flat corner where ℓ^s sits on its lower bound
(K^s = I: every object its own function, zero gradient), from which L-BFGS-B never returns; a
start at the latent spread avoids it, and the best of both wins, feature by feature. (Trying
the second start only when the first ends in the corner was measured worse: at L=100 × M=100
one feature kept a poorer optimum with a long length-scale and the fit ended 3,800 nats lower.)
"""

from __future__ import annotations

import concurrent.futures
from collections.abc import Callable, Generator, Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.optimize

from core.errors import NotPositiveDefiniteError
from core.gp.likelihood import feature_pool
from core.gp.parameters import ParameterLayout
from core.validation import FloatArray

#: A value returned to the optimiser where the Gram matrix stays singular even with jitter.
FAILED_VALUE = 1e30

#: L-BFGS-B correction pairs unless told otherwise (scipy's default ``maxcor``).
DEFAULT_LBFGS_MEMORY = 10

BoolArray = np.ndarray[Any, np.dtype[np.bool_]]


def minimize_free(
    objective: Any,
    base: FloatArray,
    free: BoolArray,
    lower: FloatArray,
    upper: FloatArray,
    max_iterations: int,
    ftol: float,
    gtol: float,
    callback: Callable[[Any], None] | None = None,
    stall_nats: float = 0.0,
    stall_iterations: int = 20,
    stall_relative: float = 0.0,
    memory: int = DEFAULT_LBFGS_MEMORY,
    reach: float = -np.inf,
    reach_iterations: int = 0,
) -> scipy.optimize.OptimizeResult:
    """L-BFGS-B with the analytic gradient over ``base[free]`` (the rest held fixed).

    Args:
        objective: Has ``value_and_gradient(vector) -> (value, gradient)``; a
            :class:`~core.errors.NotPositiveDefiniteError` counts as a failed point.
        base: The packed vector. Shape (P,).
        free: Which entries are optimised. Shape (P,), bool.
        lower, upper: Bounds of the packed vector. Shape (P,) each.
        max_iterations: L-BFGS-B iteration limit.
        ftol, gtol: L-BFGS-B tolerances.
        callback: Called by scipy after every iteration.
        stall_nats: Stop (successfully) once the value improved by less than this over the
            last ``stall_iterations`` iterations (0 = never). Log-likelihood differences far
            below one nat mean nothing statistically, and near an optimum on a ridge (the
            latents of a flat likelihood, a noise variance on its floor) L-BFGS-B can creep
            for hundreds of iterations gaining hundredths of a nat.
        stall_iterations: The window of ``stall_nats`` (≥ 1).
        stall_relative: Also stop once the improvement over the window is below
            ``stall_relative · stall_iterations · |value|`` (0 = never): a mean relative
            reduction per iteration, the windowed analogue of L-BFGS-B's ``ftol``.
        memory: Correction pairs L-BFGS-B keeps (scipy's ``maxcor``, ≥ 1).
        reach, reach_iterations: Give up (unsuccessfully) once the run cannot reach the value
            ``reach`` at its current pace: after at least ``reach_iterations`` iterations
            (0 = never give up), the improvement of the last ``reach_iterations``, repeated
            for every such window left before ``max_iterations``, would still end above
            ``reach``. L-BFGS-B's pace only slows, so such a run (a random start far behind
            the best start) would end behind it anyway.
    """
    vector = base.copy()
    history: list[float] = []
    stalled = False
    abandoned = False

    def watch(intermediate_result: scipy.optimize.OptimizeResult) -> None:
        nonlocal stalled, abandoned
        if stall_nats > 0 or stall_relative > 0 or reach_iterations > 0:
            history.append(float(intermediate_result.fun))
        if reach_iterations > 0 and len(history) > reach_iterations:
            pace = history[-1 - reach_iterations] - history[-1]
            windows_left = (max_iterations - len(history)) / reach_iterations
            if history[-1] - pace * windows_left > reach:
                abandoned = True
                raise StopIteration
        if stall_nats > 0 or stall_relative > 0:
            threshold = max(stall_nats, stall_relative * stall_iterations * abs(history[-1]))
            if (
                len(history) > stall_iterations
                and history[-1 - stall_iterations] - history[-1] < threshold
            ):
                stalled = True
                raise StopIteration
        if callback is not None:
            callback(intermediate_result)

    def fun(x: FloatArray) -> tuple[float, FloatArray]:
        vector[free] = x
        try:
            value, grad = objective.value_and_gradient(vector)
        except NotPositiveDefiniteError:
            return FAILED_VALUE, np.zeros(x.shape[0])
        return value, grad[free]

    x0 = np.clip(base[free], lower[free], upper[free])
    result = scipy.optimize.minimize(
        fun,
        x0,
        jac=True,
        method="L-BFGS-B",
        bounds=scipy.optimize.Bounds(lower[free], upper[free]),
        callback=watch,
        options={"maxiter": max_iterations, "ftol": ftol, "gtol": gtol, "maxcor": memory},
    )
    if abandoned:
        result.success = False
        result.message = (
            f"ABANDONED: at its pace over the last {reach_iterations} iterations the value "
            f"would stay above {reach:.6g} (the best start's)"
        )
    elif stalled:
        result.success = True
        result.message = (
            f"CONVERGENCE: value improved by < max({stall_nats:g}, {stall_relative:g}·"
            f"{stall_iterations}·|f|) over {stall_iterations} iterations"
        )
    return result


def feature_indices(layout: ParameterLayout, feature: int) -> FloatArray:
    """Positions in ``layout``'s packed vector of the latents and feature ``feature``'s
    log-hyperparameters, in the order of a dy = 1 layout's packed vector."""
    ds, dx = layout.latent_dim, layout.action_dim
    parts = [
        np.arange(layout.latents.start, layout.latents.stop),
        np.array([layout.log_signal_variance.start + feature]),
        np.array([layout.log_noise_variance.start + feature]),
        layout.log_latent_lengthscales.start + feature * ds + np.arange(ds),
        layout.log_action_lengthscales.start + feature * dx + np.arange(dx),
    ]
    return np.concatenate(parts).astype(np.intp)


@dataclass(frozen=True)
class SeparableProgress:
    """Progress of :func:`iter_fit_separately` after one feature.

    Attributes:
        feature: The feature just finished.
        iterations: L-BFGS-B iterations so far, over every feature and start.
        value: Σ_a -log p(y_a) with the features done so far at their optimum and the others
            at their starting values.
    """

    feature: int
    iterations: int
    value: float


@dataclass(frozen=True)
class SeparableResult:
    """Result of :func:`iter_fit_separately`.

    Attributes:
        vector: The packed vector with every feature's best hyperparameters. Shape (P,).
        value: -log p at ``vector`` (Σ over features).
        iterations: L-BFGS-B iterations over every feature and start.
        converged: Whether every kept per-feature optimum converged.
        message: The first non-converged message, or that of the last feature.
    """

    vector: FloatArray
    value: float
    iterations: int
    converged: bool
    message: str


def iter_fit_separately(
    feature_objectives: Sequence[Any],
    layout: ParameterLayout,
    vector: FloatArray,
    lower: FloatArray,
    upper: FloatArray,
    max_iterations: int,
    ftol: float,
    gtol: float,
    latent_lengthscale_starts: Sequence[float] = (),
    stall_nats: float = 0.0,
    stall_iterations: int = 20,
    stall_relative: float = 0.0,
    memory: int = DEFAULT_LBFGS_MEMORY,
    threads: int = 1,
) -> Generator[SeparableProgress, None, SeparableResult]:
    """Optimise every feature's hyperparameters separately, S fixed (see the module docstring).

    Args:
        feature_objectives: One objective per feature, each on a dy = 1 layout of the same L,
            ds, dx (e.g. ``make_likelihood(feature_data(data, a), ds, structure)``).
        layout: The full (dy-feature) layout of ``vector``.
        vector: Starting packed vector (its latents stay fixed). Shape (layout.size,).
        lower, upper: Bounds of the full packed vector. Shape (layout.size,) each.
        max_iterations: L-BFGS-B iteration limit per feature and start.
        ftol, gtol: L-BFGS-B tolerances.
        latent_lengthscale_starts: Extra starts per feature: the same hyperparameters with
            every latent length-scale set to each of these values (clipped to the bounds).
            The starting vector itself is always the first start; the best optimum is kept.
        stall_nats, stall_iterations, stall_relative: Early stop of each L-BFGS-B run
            (:func:`minimize_free`).
        memory: L-BFGS-B correction pairs (:func:`minimize_free`).
        threads: Features optimised at once on this many threads (the likelihood's feature
            pool, :func:`core.gp.likelihood.feature_pool`): the problems are independent and
            each runs as it would alone, so the result is the same on any number of threads.

    Yields:
        :class:`SeparableProgress` after each feature, in feature order.

    Returns:
        :class:`SeparableResult` (the generator's return value).
    """
    run = _Lbfgs(max_iterations, ftol, gtol, stall_nats, stall_iterations, stall_relative, memory)
    out = vector.copy()
    per_feature = [feature_indices(layout, a) for a in range(layout.observation_dim)]
    pairs = list(zip(feature_objectives, per_feature, strict=True))
    values = [_value(obj, out[idx]) for obj, idx in pairs]
    total_iterations = 0
    converged = True
    message = ""
    ds = layout.latent_dim
    initial = [out[idx].copy() for _, idx in pairs]  # read before any feature is written

    def fit_feature(a: int) -> _Best:
        objective, idx = pairs[a]
        sub_lower, sub_upper = lower[idx], upper[idx]
        free = np.ones(idx.size, dtype=bool)
        free[: layout.n_objects * ds] = False
        ls = slice(layout.n_objects * ds + 2, layout.n_objects * ds + 2 + ds)
        starts = _lengthscale_starts(
            initial[a], ls, sub_lower, sub_upper, latent_lengthscale_starts
        )
        best = _Best(values[a], initial[a].copy())
        for start in starts:
            best.improve(start, free, run.minimise(objective, start, free, sub_lower, sub_upper))
        return best

    fitted: Iterable[_Best]
    if threads > 1 and len(pairs) > 1:
        # One-feature objectives never use the pool themselves, so this cannot deadlock.
        futures = [feature_pool(threads).submit(fit_feature, a) for a in range(len(pairs))]
        concurrent.futures.wait(futures)  # no feature still running when an error is raised
        fitted = (future.result() for future in futures)
    else:
        fitted = (fit_feature(a) for a in range(len(pairs)))
    for a, ((_, idx), best) in enumerate(zip(pairs, fitted, strict=True)):
        total_iterations += best.iterations
        out[idx] = best.vector
        values[a] = best.value
        best_result = best.result
        if best_result is not None:
            if not best_result.success and converged:
                converged, message = False, str(best_result.message)
            elif converged:
                message = str(best_result.message)
        yield SeparableProgress(feature=a, iterations=total_iterations, value=float(sum(values)))
    return SeparableResult(
        vector=out,
        value=float(sum(values)),
        iterations=total_iterations,
        converged=converged,
        message=message or "no start improved on the starting point",
    )


def _lengthscale_starts(
    vector: FloatArray,
    lengthscales: slice,
    lower: FloatArray,
    upper: FloatArray,
    lengths: Sequence[float],
) -> list[FloatArray]:
    """``vector``, then a copy with the latent length-scales (``lengthscales``, log) set to each of
    ``lengths`` (clipped to the bounds), skipping copies equal to ``vector``."""
    starts = [vector.copy()]
    for length in lengths:
        alternative = vector.copy()
        alternative[lengthscales] = np.clip(
            np.log(length), lower[lengthscales], upper[lengthscales]
        )
        if not np.allclose(alternative, starts[0]):
            starts.append(alternative)
    return starts


@dataclass(frozen=True)
class _Lbfgs:
    """One L-BFGS-B run's settings (:func:`minimize_free`)."""

    max_iterations: int
    ftol: float
    gtol: float
    stall_nats: float
    stall_iterations: int
    stall_relative: float
    memory: int

    def minimise(
        self, objective: Any, start: FloatArray, free: Any, lower: FloatArray, upper: FloatArray
    ) -> scipy.optimize.OptimizeResult:
        return minimize_free(
            objective,
            start,
            free,
            lower,
            upper,
            self.max_iterations,
            self.ftol,
            self.gtol,
            stall_nats=self.stall_nats,
            stall_iterations=self.stall_iterations,
            stall_relative=self.stall_relative,
            memory=self.memory,
        )


@dataclass
class _Best:
    """The best optimum over several starts (lowest value), and the iterations they took."""

    value: float
    vector: FloatArray
    result: scipy.optimize.OptimizeResult | None = None
    iterations: int = 0

    def improve(self, start: FloatArray, free: Any, result: scipy.optimize.OptimizeResult) -> None:
        """Count ``result``'s iterations; keep it if it is below the best so far."""
        self.iterations += int(result.nit)
        if float(result.fun) < self.value:
            self.value = float(result.fun)
            self.vector = start.copy()
            self.vector[free] = result.x
            self.result = result


def _value(objective: Any, vector: FloatArray) -> float:
    try:
        value, _ = objective.value_and_gradient(vector)
    except NotPositiveDefiniteError:
        return FAILED_VALUE
    return float(value)


def iter_fit_jointly(
    objective: Any,
    layout: ParameterLayout,
    vector: FloatArray,
    lower: FloatArray,
    upper: FloatArray,
    max_iterations: int,
    ftol: float,
    gtol: float,
    latent_lengthscale_starts: Sequence[float] = (),
    stall_nats: float = 0.0,
    stall_iterations: int = 20,
    stall_relative: float = 0.0,
    memory: int = DEFAULT_LBFGS_MEMORY,
) -> Generator[SeparableProgress, None, SeparableResult]:
    """Optimise every hyperparameter at once, S fixed: the stage of :func:`iter_fit_separately`
    for tied kernels (:mod:`core.gp.tied_likelihood`), whose shared length-scales couple the
    features, so the problem does not separate. The same starts (the starting vector, then the
    shared latent length-scales set to each of ``latent_lengthscale_starts``); the best
    optimum is kept.

    Args:
        objective: The tied likelihood (``value_and_gradient`` at vectors of ``layout``).
        layout: Its (tied) layout.
        vector, lower, upper, max_iterations, ftol, gtol, latent_lengthscale_starts,
        stall_nats, stall_iterations, stall_relative, memory: As for
            :func:`iter_fit_separately`.

    Yields:
        :class:`SeparableProgress` after each start (``feature`` is the last feature: every
        feature moved at once).

    Returns:
        :class:`SeparableResult` (the generator's return value).
    """
    free = np.zeros(layout.size, dtype=bool)
    free[layout.hyperparameters] = True
    run = _Lbfgs(max_iterations, ftol, gtol, stall_nats, stall_iterations, stall_relative, memory)
    starts = _lengthscale_starts(
        vector, layout.log_latent_lengthscales, lower, upper, latent_lengthscale_starts
    )
    best = _Best(_value(objective, vector), vector.copy())
    for start in starts:
        best.improve(start, free, run.minimise(objective, start, free, lower, upper))
        yield SeparableProgress(
            feature=layout.observation_dim - 1, iterations=best.iterations, value=best.value
        )
    return SeparableResult(
        vector=best.vector,
        value=best.value,
        iterations=best.iterations,
        converged=best.result is None or bool(best.result.success),
        message="no start improved on the starting point"
        if best.result is None
        else str(best.result.message),
    )
