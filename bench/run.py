"""``activetouch bench``: every performance figure in one run, side by side.

Sections (Experiment-2-like world: ds = 2, dx = 6, dy = 5; see :mod:`bench.scenarios`):

a. **Log-likelihood + gradient** at L = 4, N = 400: ours (dense path on the paper's random
   design; Kronecker path on a shared design of M = 100 actions) vs GPy (five ``GPRegression``
   models, RBF ARD over the same 8 input dimensions, latents given) vs a direct dense numpy
   evaluation (:mod:`bench.direct_likelihood`). At 1 and 2 BLAS threads.
b. **A fit** at that shape. GPy cannot learn latents: its fit is ``optimize()`` of the five
   models on inputs [S; x] with S given. *Like for like*: S = our fitted latents held fixed,
   the same initial hyperparameters, one L-BFGS-B start each with GPy's stopping rule (ours:
   :func:`core.gp.manifold.fit_hyperparameters`; also with our default, tighter rule). *Full*:
   our one-start :func:`core.gp.manifold.fit_manifold` (``restarts=0``), which learns S too,
   against the same GPy time.
c. **Mutual information per candidate**: ours (fresh action statistics + moments + MI for 256
   candidates, divided by 256; and with the statistics reused) vs the direct appendix formula
   (:mod:`bench.reference_moments`), and vs a floor: the FLOP count of the structured evaluation
   (:func:`structured_mi_flops`) divided by the GEMM rate, timed alternately with ours (the
   ratio is the median over the pairs).
d. **One planning step and one belief update** at L = 4 / N = 400 and L = 100 / N = 10,000.
e. **Scaling** of one likelihood evaluation, one fit (one start), one planning step and the peak
   memory (``ru_maxrss`` of a fresh process per point) against N = L·M for L ∈ {4, 20, 100, 400},
   dense vs structured (Kronecker) on shared designs; a PNG plot.
f. **Sparse accuracy** (full runs): the sparse inducing-point path against the exact dense path
   on a random design (fit, latents, predictive, MI).

Timings are medians of repeats, wall clock, BLAS threads pinned (``threadpoolctl``).
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import scipy.stats

from bench import gpy_models, scenarios
from bench.direct_likelihood import direct_value_and_gradient
from bench.harness import (
    blas_threads,
    gemm_product,
    machine,
    measure,
    paired_times,
    ratio,
    run_child,
)
from bench.reference_moments import direct_moments_batch
from core.evaluation import procrustes_r2
from core.evaluation.worlds import RandomFeatureWorld
from core.gp import (
    FitOptions,
    Structure,
    condition,
    fit_hyperparameters,
    fit_manifold,
    make_likelihood,
    predict,
)
from core.gp.initialisation import pca_latents
from core.gp.parameters import initial_hyperparameters
from core.recognition import RecognitionSession
from core.recognition.moments import (
    action_statistics,
    belief_terms,
    moments_from_terms,
    mutual_information,
)
from core.recognition.planning import ActionBox, ActivePolicy, Planner, sobol_candidates
from core.types import GaussianBelief, ManifoldModel, TrainingData

Progress = Callable[[str], None]

#: L values and touches per object of the scaling section.
SCALING_OBJECTS = (4, 20, 100, 400)
SCALING_PER_OBJECT = (25, 50, 100)
#: Dense measurements stop at these sizes (the dense path is O(N³) time, O(N²) memory).
DENSE_EVALUATE_MAX_N = 2000
DENSE_FIT_MAX_N = 400
#: Runs of each like-for-like fit in (b) (one in --quick); the median is reported.
FIT_REPEATS = 5
#: Alternating (GEMM, mutual information) timings in (c); the median ratio is reported.
MI_PAIRS = 10


@dataclass
class Options:
    """What to run.

    Attributes:
        quick: A reduced run (< 2 minutes): fewer repeats, one run of each fit comparison
            (on both designs), no sparse planning case or sparse accuracy section, scaling for
            L ∈ {4, 20} and M ∈ {25, 50} with the fits up to N = 500.
        threads: BLAS thread counts for the timing sections.
        plot: Where to write the scaling plot (``None``: no plot).
        seed: Seed of the worlds and data.
    """

    quick: bool = False
    threads: tuple[int, ...] = (1, 2)
    plot: Path | None = Path("artifacts/bench/scaling.png")
    seed: int = 0
    progress: Progress = field(default=lambda message: None)


# -- FLOP model of the structured evaluation ---------------------------------------------------


def structured_mi_flops(
    n_support: int, n_objects: int, dx: int, dy: int, ds: int, kronecker_design: int = 0
) -> float:
    """Floating-point operations of one candidate's mutual information by the structured form.

    Per candidate and feature (exp counted as one operation; multiply-add as two):

    * kernels e_a(x): 2·n·dx (differences, squares) + 2·n·dx (the Λ⁻¹ contraction) + n (exp);
    * u_a = Σ_{i∈l} β_ai e_ai: 2·n·L;
    * T_a: Y = E K⁻¹ restricted to the blocks, 2·n²; then T[l, l'] = Σ_{i∈l} e_i Y[i, l'], 2·n·L;
    * the moments: 2·dy·L² per feature pair (u_aᵀ G_ab u_b), 2·L² (the trace), 3·L·ds (C);
    * the MI: dy³/3 + 2·ds·dy² + ds³ (Cholesky, solves, eigenvalues) per candidate.

    With ``kronecker_design = M`` the statistics are those of :mod:`core.gp.kronecker` instead:
    kernels against the M design actions (4·M·dx + M), u = B e^x (2·L·M), ẽ = U_xᵀ e^x (2·M²),
    t = D⁻¹ ẽ² (2·L·M + M), and the trace is a dot product of length L.

    Returns:
        The count per candidate (belief terms, O(dy² L² ds), are amortised over the candidates
        and left out).
    """
    n, l = float(n_support), float(n_objects)  # noqa: E741
    if kronecker_design:
        m = float(kronecker_design)
        statistics = dy * (4 * m * dx + m + 2 * l * m + 2 * m * m + 2 * l * m + m)
        trace = dy * 2 * l
    else:
        statistics = dy * (4 * n * dx + n + 2 * n * l + 2 * n * n + 2 * n * l)
        trace = dy * 2 * l * l
    moments = dy * dy * 2 * l * l + dy * dy * 2 * l + trace + dy * 3 * l * ds
    information = dy**3 / 3 + 2 * ds * dy**2 + ds**3
    return float(statistics + moments + information)


# -- sections ----------------------------------------------------------------------------------


def _problem(
    design: scenarios.DesignName, seed: int, n_objects: int = 4, per_object: int = 100
) -> tuple[RandomFeatureWorld, TrainingData]:
    world = scenarios.world(seed, n_objects)
    data = scenarios.dataset(world, design, per_object, seed + 1)
    return world, data


def _per_design(
    designs: tuple[scenarios.DesignName, ...],
    row: Callable[[scenarios.DesignName], dict[str, Any]],
    label: str,
    options: Options,
) -> dict[str, Any]:
    """A section's ``row(design)`` for each design in turn, each reported done under ``label``."""
    out: dict[str, Any] = {}
    for design in designs:
        out[design] = row(design)
        options.progress(f"{label}, {design} design done")
    return out


def section_likelihood(options: Options, gpy: Any) -> dict[str, Any]:
    """(a) one value + gradient at L = 4, N = 400."""
    return _per_design(
        ("random", "shared"),
        lambda design: _likelihood_row(design, options, gpy),
        "(a) likelihood",
        options,
    )


def _likelihood_row(design: scenarios.DesignName, options: Options, gpy: Any) -> dict[str, Any]:
    repeats = 5 if options.quick else 15
    _, data = _problem(design, options.seed)
    rng = np.random.default_rng(options.seed + 5)
    latents = pca_latents(data, 2, rng)
    hyper = initial_hyperparameters(data, 2)
    likelihood = make_likelihood(data, 2)
    vector = likelihood.layout.pack(latents, hyper)
    ours_value, ours_grad = likelihood.value_and_gradient(vector)
    row: dict[str, Any] = {"structure": type(likelihood).__name__}
    direct_value, direct_grad = direct_value_and_gradient(data, latents, hyper)
    row["agreement_direct"] = {
        "value_rel": abs(ours_value - direct_value) / abs(direct_value),
        "gradient_rel": float(
            np.max(np.abs(ours_grad - direct_grad)) / np.max(np.abs(direct_grad))
        ),
    }
    models = gpy_models.build_models(gpy, data, latents, hyper) if gpy is not None else None
    if models is not None:
        gpy_value, _ = gpy_models.value_and_gradient(models)
        row["agreement_gpy"] = {"value_rel": abs(ours_value - gpy_value) / abs(gpy_value)}
    for threads in options.threads:
        with blas_threads(threads):
            ours = measure(lambda: likelihood.value_and_gradient(vector), repeats, 2)
            direct = measure(
                lambda: direct_value_and_gradient(data, latents, hyper), max(2, repeats // 5), 1
            )
            gpy_s = None
            if models is not None:
                gpy_s = measure(lambda: gpy_models.value_and_gradient(models), repeats, 2).median_s
        row[f"threads_{threads}"] = {
            "ours_ms": 1e3 * ours.median_s,
            "gpy_ms": None if gpy_s is None else 1e3 * gpy_s,
            "direct_ms": 1e3 * direct.median_s,
            "speedup_vs_gpy": ratio(gpy_s, ours.median_s),
            "speedup_vs_direct": ratio(direct.median_s, ours.median_s),
        }
    return row


def section_fit(options: Options, gpy: Any) -> dict[str, Any]:
    """(b) fits at L = 4, N = 400 against GPy's fit of the same data.

    GPy cannot learn latents, so its fit is the hyperparameters of five ``GPRegression``
    models on [S; x] with S given. Two comparisons:

    * **like for like** — the same problem on both sides: S = our fitted latents held fixed,
      the same initial hyperparameters (ℓ^s = the latent spread), one L-BFGS-B start each
      (ours: :func:`core.gp.manifold.fit_hyperparameters` with no fallback starts; GPy:
      ``optimize()``) and the same stopping rule, GPy's (factr 1e7, pgtol 1e-5, at most 1000
      iterations; ours also without the stall test). Ours with our default, tighter rule
      (ftol 1e-12, gtol 1e-6, stall test) is reported beside it. The log-likelihoods reached
      are reported beside the times, which are medians of :data:`FIT_REPEATS` alternating
      runs; the speed-ups are medians of the run-by-run ratios;
    * **full fit** — ours learns S too: one start of :func:`core.gp.manifold.fit_manifold`
      (``restarts=0``: PCA start, screening, hyperparameters, joint), against the same GPy time.
    """
    return _per_design(
        ("shared", "random"), lambda design: _fit_row(design, options, gpy), "(b) fit", options
    )


def _fit_row(design: scenarios.DesignName, options: Options, gpy: Any) -> dict[str, Any]:
    world, data = _problem(design, options.seed)
    row: dict[str, Any] = {}
    with blas_threads(1):
        started = time.perf_counter()
        fitted = fit_manifold(
            data, 2, np.random.default_rng(options.seed + 6), FitOptions(restarts=0)
        )
        row["full_s"] = time.perf_counter() - started
        diagnostics = fitted.diagnostics
        row.update(
            {
                "full_log_likelihood": fitted.log_likelihood,
                "full_iterations": diagnostics.iterations if diagnostics else None,
                "full_at_bounds": (
                    len(diagnostics.hyperparameters_at_bounds) if diagnostics else None
                ),
                "full_r2_truth": procrustes_r2(world.truth, fitted.latents),
                "structure": fitted.posterior.structure,
            }
        )
        # Like for like: the same start and GPy's own L-BFGS-B stopping rule on our side
        # (ours_default_*: our default, tighter rule, from the same start).
        same_rule = FitOptions(
            initial_latent_lengthscale=1.0,
            hyperparameter_latent_lengthscales=(),
            max_iterations=gpy_models.GPY_MAX_ITERATIONS,
            ftol=gpy_models.GPY_FTOL,
            gtol=gpy_models.GPY_GTOL,
            stall_nats=0.0,
            stall_relative=0.0,
        )
        default_rule = FitOptions(
            initial_latent_lengthscale=1.0, hyperparameter_latent_lengthscales=()
        )
        # Every side: the median of FIT_REPEATS runs from the same start, alternating ours and
        # GPy's so that a busy spell of the shared machine hits all of them.
        # As a user's fit runs: the same rule with the features on as many threads as the
        # machine's cores (`activetouch fit` and the server use the cores; BLAS stays on one
        # thread in each), against GPy at its faster BLAS thread count.
        cores = max(options.threads)
        threaded_rule = dataclasses.replace(same_rule, threads=cores)
        runs: dict[str, list[tuple[float, ManifoldModel]]] = {
            "same": [],
            "default": [],
            "threaded": [],
        }
        gpy_runs: list[gpy_models.GPyFit] = []
        gpy_threaded_runs: list[gpy_models.GPyFit] = []
        hyper = initial_hyperparameters(data, 2, latent_lengthscale=1.0)
        for _ in range(FIT_REPEATS if not options.quick else 1):
            for key, rule in (
                ("same", same_rule),
                ("default", default_rule),
                ("threaded", threaded_rule),
            ):
                started = time.perf_counter()
                ours = fit_hyperparameters(data, fitted.latents, rule)
                runs[key].append((time.perf_counter() - started, ours))
            if gpy is not None:
                models = gpy_models.build_models(gpy, data, fitted.latents, hyper)
                gpy_runs.append(gpy_models.fit(models))
                if cores > 1:
                    models = gpy_models.build_models(gpy, data, fitted.latents, hyper)
                    with blas_threads(cores):
                        gpy_threaded_runs.append(gpy_models.fit(models))
        for key, prefix in (
            ("same", "ours"),
            ("default", "ours_default"),
            ("threaded", "ours_threaded"),
        ):
            seconds = [elapsed for elapsed, _ in runs[key]]
            model = runs[key][-1][1]
            row[f"{prefix}_s"] = float(np.median(seconds))
            row[f"{prefix}_s_runs"] = seconds
            row[f"{prefix}_log_likelihood"] = model.log_likelihood
            row[f"{prefix}_iterations"] = (
                model.diagnostics.iterations if model.diagnostics else None
            )
        if gpy_runs:
            gpy_seconds = np.array([run.seconds for run in gpy_runs])
            gpy_s = float(np.median(gpy_seconds))
            # GPy's time over ours run by run (they alternate), then the median: a busy spell
            # of the shared machine slows both runs of a pair.
            same = gpy_seconds / np.array(row["ours_s_runs"])
            default = gpy_seconds / np.array(row["ours_default_s_runs"])
            row.update(
                {
                    "gpy_s": gpy_s,
                    "gpy_s_runs": gpy_seconds.tolist(),
                    "gpy_log_likelihood": gpy_runs[-1].log_likelihood,
                    "gpy_evaluations": gpy_runs[-1].evaluations,
                    "speedup_vs_gpy": float(np.median(same)),
                    "speedup_vs_gpy_runs": same.tolist(),
                    "default_rule_speedup_vs_gpy": float(np.median(default)),
                    "full_speedup_vs_gpy": ratio(gpy_s, row["full_s"]),
                }
            )
            # GPy's better thread count, run by run, over ours on the cores.
            best = gpy_seconds
            if gpy_threaded_runs:
                threaded_seconds = np.array([run.seconds for run in gpy_threaded_runs])
                row["gpy_threaded_s_runs"] = threaded_seconds.tolist()
                best = np.minimum(gpy_seconds, threaded_seconds)
            row["threads"] = cores
            row["threaded_speedup_vs_gpy_best"] = float(
                np.median(best / np.array(row["ours_threaded_s_runs"]))
            )
    return row


def _fresh_mi(model: ManifoldModel, actions: np.ndarray, belief: Any) -> np.ndarray:
    stats = action_statistics(model, actions)
    return mutual_information(moments_from_terms(model, belief_terms(model, belief), stats), belief)


def section_mutual_information(options: Options) -> dict[str, Any]:
    """(c) mutual information per candidate: ours vs the direct formula vs the FLOP floor."""
    return _per_design(
        ("random", "shared"),
        lambda design: _mutual_information_row(design, options),
        "(c) mutual information",
        options,
    )


def _mutual_information_row(design: scenarios.DesignName, options: Options) -> dict[str, Any]:
    n_candidates = 256
    n_direct = 2 if options.quick else 8
    world, data = _problem(design, options.seed)
    model = scenarios.reference_model(world, data)
    belief = scenarios.beliefs(model, 1, options.seed + 7)[0]
    candidates = sobol_candidates(ActionBox.from_model(model), n_candidates, 0)
    ours_mi = _fresh_mi(model, candidates, belief)
    started = time.perf_counter()
    _, _, _, direct_mi = direct_moments_batch(model, belief, candidates[:n_direct])
    direct_s = (time.perf_counter() - started) / n_direct
    factors = model.posterior.kronecker
    flops = structured_mi_flops(
        data.n_touches,
        data.n_objects,
        data.action_dim,
        data.observation_dim,
        model.latent_dim,
        kronecker_design=factors.n_design if factors is not None else 0,
    )
    row: dict[str, Any] = {
        "structure": model.posterior.structure,
        "direct_ms_per_candidate": 1e3 * direct_s,
        "max_rel_error_vs_direct": float(
            np.max(np.abs(ours_mi[:n_direct] - direct_mi)) / np.max(np.abs(direct_mi))
        ),
        "flops_per_candidate": flops,
    }
    stats = action_statistics(model, candidates)

    def reused() -> None:
        terms = belief_terms(model, belief)
        mutual_information(moments_from_terms(model, terms, stats), belief)

    for threads in options.threads:
        with blas_threads(threads):
            # The GEMM that sets the floor and our evaluation alternate, and the ratio is
            # taken pair by pair: both see the same state of the shared machine.
            product, product_flops = gemm_product()
            gemm_s, fresh_runs = paired_times(
                product, lambda: _fresh_mi(model, candidates, belief), MI_PAIRS
            )
            reused_s = measure(reused, 20, 2).median_s
        rate = product_flops / float(np.median(gemm_s))
        fresh_s = float(np.median(fresh_runs))
        per_candidate = fresh_s / n_candidates
        floor = flops / rate
        pair_ratios = (fresh_runs / n_candidates) / (flops * gemm_s / product_flops)
        row[f"threads_{threads}"] = {
            "gemm_gflops": rate / 1e9,
            "ours_us_per_candidate": 1e6 * per_candidate,
            "ours_reused_us_per_candidate": 1e6 * reused_s / n_candidates,
            "floor_us_per_candidate": 1e6 * floor,
            "ours_over_floor": float(np.median(pair_ratios)),
            "ours_over_floor_range": [float(pair_ratios.min()), float(pair_ratios.max())],
            "speedup_vs_direct": direct_s / per_candidate,
            "reused_speedup_vs_direct": direct_s / (reused_s / n_candidates),
        }
    return row


def section_planning(options: Options) -> dict[str, Any]:
    """(d) one planning step and one belief update."""
    out: dict[str, Any] = {}
    cases: list[tuple[str, int, scenarios.DesignName]] = [
        ("L4_random", 4, "random"),
        ("L4_shared", 4, "shared"),
        ("L100_M100_shared", 100, "shared"),
    ]
    if not options.quick:
        cases.append(("L100_N10000_random", 100, "random"))
    for name, n_objects, design in cases:
        out[name] = _planning_row(n_objects, design, options)
        options.progress(f"(d) planning, {name} done")
    return out


def _planning_row(n_objects: int, design: scenarios.DesignName, options: Options) -> dict[str, Any]:
    world, data = _problem(design, options.seed, n_objects, 100)
    started = time.perf_counter()
    model = scenarios.reference_model(world, data)
    condition_s = time.perf_counter() - started
    started = time.perf_counter()
    planner = Planner(model, ActivePolicy())
    setup_s = time.perf_counter() - started
    beliefs = scenarios.beliefs(model, 10, options.seed + 8)
    rng = np.random.default_rng(options.seed + 9)
    action = planner.plan(beliefs[0], rng).action
    observation = world.observe(0, action[None, :], rng)[0]
    cursor = iter(range(10**9))
    repeats = 5 if options.quick else 20

    def plan() -> None:
        planner.plan(beliefs[next(cursor) % len(beliefs)], rng)

    def update() -> None:
        RecognitionSession(model, planner).observe(action, observation)

    row: dict[str, Any] = {
        "structure": model.posterior.structure,
        "touches": data.n_touches,
        "condition_s": condition_s,
        "candidate_statistics_s": setup_s,
    }
    for threads in options.threads:
        with blas_threads(threads):
            plan_timing = measure(plan, repeats, 1)
            update_timing = measure(update, repeats, 1)
        row[f"threads_{threads}"] = {
            "plan_ms": 1e3 * plan_timing.median_s,
            "plan_p90_ms": 1e3 * plan_timing.p90_s,
            "update_ms": 1e3 * update_timing.median_s,
        }
    return row


def section_scaling(options: Options) -> list[dict[str, Any]]:
    """(e) scaling against N for L ∈ {4, 20, 100, 400}, dense vs Kronecker (child processes)."""
    points: list[dict[str, Any]] = []
    objects = SCALING_OBJECTS[:2] if options.quick else SCALING_OBJECTS
    per_object = SCALING_PER_OBJECT[:2] if options.quick else SCALING_PER_OBJECT
    for n_objects in objects:
        for m in per_object:
            n = n_objects * m
            # Structured fits everywhere up to L = 20, at M = 100 (the targets) above.
            kron_fit = n_objects <= 20 or m == SCALING_PER_OBJECT[-1]
            if options.quick:
                kron_fit = n <= 500
            configurations = [("kronecker", kron_fit, True)]
            if n <= DENSE_EVALUATE_MAX_N:
                configurations.append(("dense", n <= DENSE_FIT_MAX_N and not options.quick, True))
            for structure, fit, plan in configurations:
                arguments = {
                    "objects": n_objects,
                    "per_object": m,
                    "structure": structure,
                    "fit": fit,
                    "plan": plan,
                    "evaluate": True,
                    "seed": options.seed,
                }
                try:
                    result = run_child("bench.worker", arguments, timeout_s=1800)
                except RuntimeError as exc:
                    result = {**arguments, "touches": n, "error": str(exc)}
                points.append(result)
                options.progress(
                    f"(e) scaling L={n_objects} M={m} {structure}: "
                    + ", ".join(
                        f"{key} {result[key]:.3g}"
                        for key in ("evaluate_s", "fit_s", "plan_ms", "peak_mb")
                        if isinstance(result.get(key), float)
                    )
                )
    if not options.quick:
        # Large data without a shared design: the sparse path (random design, 512 inducing points).
        for n_objects in (20, 100):
            arguments = {
                "objects": n_objects,
                "per_object": 100,
                "structure": "sparse",
                "design": "random",
                "fit": False,
                "plan": True,
                "evaluate": True,
                "repeats": 2,
                "seed": options.seed,
            }
            try:
                result = run_child("bench.worker", arguments, timeout_s=1800)
            except RuntimeError as exc:
                result = {**arguments, "touches": n_objects * 100, "error": str(exc)}
            points.append(result)
            options.progress(f"(e) scaling L={n_objects} M=100 sparse (random design) done")
    return points


def section_sparse(options: Options) -> dict[str, Any]:
    """(f) the sparse path against the exact dense path, random design, L = 20, N = 2,000.

    Both are conditioned on the same (true, normalised) latents and reference hyperparameters,
    so the differences are the approximation's alone: the bound's gap to the exact
    log-likelihood, the predictive mean RMSE and standard-deviation ratio at 300 random
    (object, action) queries, and the mutual information of 64 candidates under one belief
    (median relative error, Spearman rank correlation, whether the best candidate is the same);
    with the time to condition, to build the candidate statistics and to plan one step.
    """
    world, data = _problem("random", options.seed, 20, 100)
    latents = scenarios.true_latents(world)
    hyper = scenarios.reference_hyperparameters(world, data)
    rng = np.random.default_rng(options.seed + 11)
    objects = rng.integers(data.n_objects, size=300)
    queries = latents[objects]
    actions = rng.standard_normal((300, data.action_dim))
    belief = GaussianBelief(mean=latents[1] + 0.1, cov=0.3 * np.eye(latents.shape[1]))
    out: dict[str, Any] = {"touches": data.n_touches, "objects": data.n_objects}

    def evaluate(structure: Structure, m: int) -> tuple[ManifoldModel, dict[str, Any]]:
        started = time.perf_counter()
        model = condition(data, latents, hyper, structure=structure, n_inducing=m)
        condition_s = time.perf_counter() - started
        started = time.perf_counter()
        planner = Planner(model, ActivePolicy())
        setup_s = time.perf_counter() - started
        plan_s = measure(lambda: planner.plan(belief, rng), 3, 1).median_s
        return model, {
            "condition_s": condition_s,
            "candidate_statistics_s": setup_s,
            "plan_ms": 1e3 * plan_s,
            "log_likelihood": model.log_likelihood,
        }

    with blas_threads(1):
        exact, out["exact"] = evaluate("dense", 0)
        candidates = sobol_candidates(ActionBox.from_model(exact), 64, 0)
        mean_exact, var_exact = predict(exact, queries, actions)
        mi_exact = _fresh_mi(exact, candidates, belief)
        for m in (128, 256, 512, 1024):
            model, row = evaluate("sparse", m)
            mean_sparse, var_sparse = predict(model, queries, actions)
            mi_sparse = _fresh_mi(model, candidates, belief)
            row.update(
                {
                    "bound_gap": model.log_likelihood - exact.log_likelihood,
                    "predictive_mean_rmse": float(
                        np.sqrt(np.mean((mean_sparse - mean_exact) ** 2))
                    ),
                    "predictive_sd_ratio": float(np.median(np.sqrt(var_sparse / var_exact))),
                    "mi_median_rel_error": float(
                        np.median(np.abs(mi_sparse - mi_exact) / np.abs(mi_exact))
                    ),
                    "mi_rank_correlation": float(
                        scipy.stats.spearmanr(mi_sparse, mi_exact).statistic
                    ),
                    "same_best_candidate": bool(np.argmax(mi_sparse) == np.argmax(mi_exact)),
                }
            )
            out[f"m{m}"] = row
            options.progress(f"(f) sparse m={m} done")
    return out


# -- the run -----------------------------------------------------------------------------------


def headline(figures: dict[str, Any]) -> dict[str, Any]:
    """The JSON keys of the figures (``None`` when not measured in this run)."""

    def get(*path: str) -> Any:
        node: Any = figures
        for key in path:
            if not isinstance(node, dict) or key not in node:
                return None
            node = node[key]
        return node

    scaling = {
        (p.get("objects"), p.get("per_object"), p.get("structure")): p
        for p in figures.get("scaling", [])
    }
    l100 = scaling.get((100, 100, "kronecker"), {})
    l400 = scaling.get((400, 100, "kronecker"), {})
    return {
        "mi_speedup_vs_direct": get(
            "mutual_information", "random", "threads_1", "speedup_vs_direct"
        ),
        "mi_over_floor": get("mutual_information", "random", "threads_1", "ours_over_floor"),
        "mi_us_per_candidate": get(
            "mutual_information", "random", "threads_1", "ours_us_per_candidate"
        ),
        "fit_speedup_vs_gpy": get("fit", "shared", "speedup_vs_gpy"),
        "fit_speedup_vs_gpy_random": get("fit", "random", "speedup_vs_gpy"),
        "fit_speedup_vs_gpy_default_rule": get("fit", "shared", "default_rule_speedup_vs_gpy"),
        "fit_speedup_vs_gpy_random_default_rule": get(
            "fit", "random", "default_rule_speedup_vs_gpy"
        ),
        "fit_speedup_vs_gpy_random_cores": get("fit", "random", "threaded_speedup_vs_gpy_best"),
        "fit_speedup_vs_gpy_shared_cores": get("fit", "shared", "threaded_speedup_vs_gpy_best"),
        "full_fit_speedup_vs_gpy": get("fit", "shared", "full_speedup_vs_gpy"),
        "full_fit_speedup_vs_gpy_random": get("fit", "random", "full_speedup_vs_gpy"),
        "loglik_speedup_vs_gpy": get("likelihood", "random", "threads_1", "speedup_vs_gpy"),
        "loglik_speedup_vs_gpy_shared": get("likelihood", "shared", "threads_1", "speedup_vs_gpy"),
        "plan_ms_L4": get("planning", "L4_random", "threads_1", "plan_ms"),
        "plan_ms_L4_shared": get("planning", "L4_shared", "threads_1", "plan_ms"),
        "plan_ms_L100_M100": get("planning", "L100_M100_shared", "threads_1", "plan_ms"),
        "plan_ms_L100_N10000_random_sparse": get(
            "planning", "L100_N10000_random", "threads_1", "plan_ms"
        ),
        "update_ms_L4": get("planning", "L4_random", "threads_1", "update_ms"),
        "update_ms_L100_M100": get("planning", "L100_M100_shared", "threads_1", "update_ms"),
        "fit_s_L100_M100": l100.get("fit_s"),
        "fit_s_L400_M100": l400.get("fit_s"),
        "peak_mb_L400_M100": l400.get("peak_mb"),
        "fit_gap_nats_L100_M100": fit_gap(l100),
        "fit_gap_nats_L400_M100": fit_gap(l400),
    }


def run(options: Options) -> dict[str, Any]:
    """Run every section; return all figures (``figures["headline"]`` has the JSON keys)."""
    started = time.perf_counter()
    gpy, gpy_note = gpy_models.load_gpy()
    figures: dict[str, Any] = {
        "machine_before": machine(),
        "quick": options.quick,
        "threads": list(options.threads),
        "gpy": gpy_note,
    }
    options.progress(f"GPy: {gpy_note}")
    figures["likelihood"] = section_likelihood(options, gpy)
    figures["fit"] = section_fit(options, gpy)
    figures["mutual_information"] = section_mutual_information(options)
    figures["planning"] = section_planning(options)
    figures["scaling"] = section_scaling(options)
    if not options.quick:
        figures["sparse"] = section_sparse(options)
    if options.plot is not None:
        figures["plot"] = str(plot_scaling(figures["scaling"], options.plot))
    figures["machine_after"] = machine()
    figures["seconds"] = time.perf_counter() - started
    figures["headline"] = headline(figures)
    return figures


def plot_scaling(points: list[dict[str, Any]], path: Path) -> Path:
    """Write the scaling curves (fit/evaluation time, planning time, peak memory vs N)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = [
        ("evaluate_s", "likelihood + gradient (s)"),
        ("fit_s", "fit, one start (s)"),
        ("plan_ms", "planning step (ms)"),
        ("peak_mb", "peak RSS (MB)"),
    ]
    figure, axes = plt.subplots(1, len(panels), figsize=(18, 4.2))
    colours = dict(zip(SCALING_OBJECTS, ("C0", "C1", "C2", "C3"), strict=True))
    for axis, (key, label) in zip(axes, panels, strict=True):
        for n_objects in SCALING_OBJECTS:
            for structure, style in (("kronecker", "-o"), ("dense", "--s"), ("sparse", ":^")):
                series = sorted(
                    (p["touches"], p[key])
                    for p in points
                    if p.get("objects") == n_objects
                    and p.get("structure") == structure
                    and isinstance(p.get(key), int | float)
                )
                if series:
                    n, value = zip(*series, strict=True)
                    axis.plot(
                        n,
                        value,
                        style,
                        color=colours[n_objects],
                        label=f"L={n_objects} {structure}",
                        markersize=4,
                    )
        axis.set_xscale("log")
        axis.set_yscale("log")
        axis.set_xlabel("N = L·M touches")
        axis.set_title(label)
        axis.grid(True, which="both", alpha=0.3)
    axes[0].legend(fontsize=7)
    figure.suptitle(
        "ActiveTouch scaling: Kronecker (solid) vs dense (dashed) on shared designs; "
        "sparse, 512 inducing points (dotted), on random designs"
    )
    figure.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path, dpi=110)
    plt.close(figure)
    return path


# -- the report --------------------------------------------------------------------------------


def _fmt(value: Any, spec: str = ".3g") -> str:
    if value is None:
        return "-"
    if isinstance(value, float):
        return format(value, spec)
    return str(value)


def fit_gap(point: dict[str, Any]) -> float | None:
    """Nats by which the optimum reached from the true latents beats a scaling fit."""
    truth, fitted = point.get("truth_log_likelihood"), point.get("fit_log_likelihood")
    if truth is None or fitted is None:
        return None
    return float(truth) - float(fitted)


def _thread_table(
    add: Callable[[str], None],
    title: list[str],
    header: str,
    section: dict[str, Any],
    threads: list[int],
    line: Callable[[str, dict[str, Any], int, dict[str, Any]], str],
    after_row: Callable[[dict[str, Any]], str] | None = None,
) -> None:
    """A table of a section measured at every BLAS thread count: a blank line, the title and
    the header, then ``line(name, row, threads, figures at that count)`` for each of the
    section's rows and thread counts, and ``after_row(row)`` after each row's lines."""
    add("")
    for text in title:
        add(text)
    add(header)
    for name, row in section.items():
        for t in threads:
            add(line(name, row, t, row[f"threads_{t}"]))
        if after_row is not None:
            add(after_row(row))


def report(figures: dict[str, Any]) -> str:
    """The human-readable tables of a run."""
    lines: list[str] = []
    add = lines.append
    before, after = figures["machine_before"], figures.get("machine_after", {})
    add(
        f"machine: {before['cpus']} CPUs, {', '.join(before['blas'])}; load average "
        f"{before['load_average_1_5_15']} before, {after.get('load_average_1_5_15')} after; "
        f"{figures['gpy']}; run took {figures.get('seconds', 0):.0f} s"
        + (" (quick)" if figures["quick"] else "")
    )
    threads = figures["threads"]
    _thread_table(
        add,
        ["(a) log-likelihood + gradient, L=4 N=400 dx=6 dy=5 ds=2 (median ms)"],
        f"  {'design':8s} {'path':22s} {'thr':>3s} {'ours':>8s} {'GPy':>8s} {'direct':>8s} "
        f"{'GPy/ours':>9s} {'direct/ours':>11s}",
        figures["likelihood"],
        threads,
        lambda design, row, t, r: (
            f"  {design:8s} {row['structure']:22s} {t:3d} {_fmt(r['ours_ms'], '8.2f')} "
            f"{_fmt(r['gpy_ms'], '8.2f'):>8s} {_fmt(r['direct_ms'], '8.1f')} "
            f"{_fmt(r['speedup_vs_gpy'], '9.1f'):>9s} {_fmt(r['speedup_vs_direct'], '11.0f')}"
        ),
        lambda row: (
            f"  {'':8s} agreement with direct: value {row['agreement_direct']['value_rel']:.1e}, "
            f"gradient {row['agreement_direct']['gradient_rel']:.1e}"
            + (
                f"; with GPy: value {row['agreement_gpy']['value_rel']:.1e}"
                if "agreement_gpy" in row
                else ""
            )
        ),
    )
    add("")
    add("(b) fits, L=4 N=400, 1 thread. Like for like: S = our fitted latents held fixed, the")
    add("    same initial hyperparameters, one L-BFGS-B start each (GPy: 5 GPRegression models),")
    add("    the same stopping rule (GPy's: factr 1e7, pgtol 1e-5). 'default': ours with our")
    add("    default, tighter rule. Full: our one-start fit of S and the hyperparameters.")
    add("    'cores': ours with the same rule, its features on the machine's cores (as")
    add("    `activetouch fit` runs), against GPy at its faster BLAS thread count.")
    add(
        f"  {'design':8s} {'path':10s} {'ours s':>7s} {'GPy s':>7s} {'GPy/ours':>8s} "
        f"{'ours ll':>10s} {'GPy ll':>10s} {'default s':>9s} {'GPy/dflt':>8s} "
        f"{'full s':>7s} {'GPy/full':>8s} {'full ll':>9s} {'R² truth':>8s} "
        f"{'cores s':>7s} {'GPy/cores':>9s}"
    )
    for design, row in figures["fit"].items():
        add(
            f"  {design:8s} {row['structure']:10s} {row['ours_s']:7.2f} "
            f"{_fmt(row.get('gpy_s'), '7.2f'):>7s} "
            f"{_fmt(row.get('speedup_vs_gpy'), '8.1f'):>8s} "
            f"{row['ours_log_likelihood']:10.3f} "
            f"{_fmt(row.get('gpy_log_likelihood'), '10.3f'):>10s} "
            f"{row['ours_default_s']:9.2f} "
            f"{_fmt(row.get('default_rule_speedup_vs_gpy'), '8.1f'):>8s} "
            f"{row['full_s']:7.2f} "
            f"{_fmt(row.get('full_speedup_vs_gpy'), '8.2f'):>8s} "
            f"{row['full_log_likelihood']:9.1f} {row['full_r2_truth']:8.3f} "
            f"{row['ours_threaded_s']:7.2f} "
            f"{_fmt(row.get('threaded_speedup_vs_gpy_best'), '9.1f'):>9s}"
        )
    _thread_table(
        add,
        ["(c) mutual information per candidate (256 candidates, fresh action statistics)"],
        f"  {'design':8s} {'thr':>3s} {'ours us':>8s} {'reused us':>9s} {'floor us':>8s} "
        f"{'ours/floor':>10s} {'direct ms':>9s} {'direct/ours':>11s} {'GEMM GF/s':>9s}",
        figures["mutual_information"],
        threads,
        lambda design, row, t, r: (
            f"  {design:8s} {t:3d} {r['ours_us_per_candidate']:8.2f} "
            f"{r['ours_reused_us_per_candidate']:9.3f} {r['floor_us_per_candidate']:8.2f} "
            f"{r['ours_over_floor']:10.2f} {row['direct_ms_per_candidate']:9.2f} "
            f"{r['speedup_vs_direct']:11.0f} {r['gemm_gflops']:9.1f}"
        ),
        lambda row: (
            f"  {'':8s} max rel. error vs direct {row['max_rel_error_vs_direct']:.1e}; "
            f"{row['flops_per_candidate']:.3g} flop per candidate ({row['structure']})"
        ),
    )
    _thread_table(
        add,
        [
            "(d) planning step and belief update (median ms; default Planner: 256 Sobol "
            "candidates,",
            "    1 L-BFGS-B refinement)",
        ],
        f"  {'case':20s} {'path':10s} {'thr':>3s} {'plan ms':>8s} {'p90':>7s} {'update ms':>9s} "
        f"{'cand. stats s':>13s}",
        figures["planning"],
        threads,
        lambda name, row, t, r: (
            f"  {name:20s} {row['structure']:10s} {t:3d} {r['plan_ms']:8.2f} "
            f"{r['plan_p90_ms']:7.2f} {r['update_ms']:9.2f} "
            f"{row['candidate_statistics_s']:13.3f}"
        ),
    )
    add("")
    add("(e) scaling (fresh process per point, 1 thread; fit = one L-BFGS start; kronecker and")
    add("    dense rows on shared designs, sparse rows on random designs)")
    add(
        f"  {'L':>4s} {'M':>4s} {'N':>6s} {'path':10s} {'eval s':>8s} {'fit s':>8s} "
        f"{'iters':>6s} {'gap nats':>9s} {'R²':>6s} {'plan ms':>8s} {'update ms':>9s} "
        f"{'peak MB':>8s}"
    )
    for p in figures["scaling"]:
        if "error" in p:
            add(
                f"  {p['objects']:4d} {p['per_object']:4d} {p['touches']:6d} "
                f"{p['structure']:10s} error: {p['error'][:60]}"
            )
            continue
        add(
            f"  {p['objects']:4d} {p['per_object']:4d} {p['touches']:6d} {p['structure']:10s} "
            f"{_fmt(p.get('evaluate_s'), '8.4f'):>8s} {_fmt(p.get('fit_s'), '8.2f'):>8s} "
            f"{_fmt(p.get('fit_iterations')):>6s} {_fmt(fit_gap(p), '9.1f'):>9s} "
            f"{_fmt(p.get('fit_r2'), '6.3f'):>6s} {_fmt(p.get('plan_ms'), '8.2f'):>8s} "
            f"{_fmt(p.get('update_ms'), '9.2f'):>9s} {_fmt(p.get('peak_mb'), '8.0f'):>8s}"
        )
    add("  gap nats: log-likelihood of the optimum reached from the true latents minus the")
    add("  fit's (≤ 0: the fit did as well); R²: Procrustes R² of the fitted latents to the truth")
    if "sparse" in figures:
        s = figures["sparse"]
        e = s["exact"]
        add("")
        add(
            f"(f) sparse (inducing points) vs exact dense, random design L={s['objects']} "
            f"N={s['touches']}, same latents and hyperparameters"
        )
        add(
            f"  {'path':8s} {'cond. s':>7s} {'stats s':>7s} {'plan ms':>8s} {'bound gap':>10s} "
            f"{'mean RMSE':>9s} {'sd ratio':>8s} {'MI rel err':>10s} {'MI rank r':>9s} "
            f"{'same best':>9s}"
        )
        add(
            f"  {'exact':8s} {e['condition_s']:7.2f} {e['candidate_statistics_s']:7.2f} "
            f"{e['plan_ms']:8.1f}"
        )
        for key, r in s.items():
            if not key.startswith("m"):
                continue
            add(
                f"  {key:8s} {r['condition_s']:7.2f} {r['candidate_statistics_s']:7.2f} "
                f"{r['plan_ms']:8.1f} {r['bound_gap']:10.3g} {r['predictive_mean_rmse']:9.3f} "
                f"{r['predictive_sd_ratio']:8.2f} {r['mi_median_rel_error']:10.3f} "
                f"{r['mi_rank_correlation']:9.3f} {r['same_best_candidate']!s:>9s}"
            )
    add("")
    add("headline:")
    for key, value in figures["headline"].items():
        add(f"  {key:36s} {_fmt(value, '.4g')}")
    if figures.get("plot"):
        add(f"plot: {figures['plot']}")
    return "\n".join(lines)
