"""One scaling measurement in a fresh process (for a clean peak-memory figure).

Run: ``python -m bench.worker '{"objects": 100, "per_object": 100, "structure": "kronecker",
"fit": true, "plan": true, "evaluate": true, "seed": 0}'``; prints one JSON object:

* ``evaluate_s``: median seconds of one likelihood value + gradient;
* ``fit_s``, ``fit_iterations``, ``fit_log_likelihood``, ``fit_r2``: one L-BFGS start
  (:func:`core.gp.manifold.fit_manifold` with ``restarts=0``) and the Procrustes R² of its latents
  against the truth; ``truth_log_likelihood``: the joint optimum reached from the true latents
  (hyperparameters fitted with them held fixed first), what the fit should reach — measured
  after ``peak_mb``;
* ``plan_setup_s`` (the candidate statistics, once per model), ``plan_ms`` (median of one
  active planning step, default :class:`core.recognition.planning.Planner` settings);
* ``peak_mb`` (``ru_maxrss`` of this process) and ``baseline_mb`` (after the imports).
"""

from __future__ import annotations

import json
import sys
import time
from typing import Any

import numpy as np

from bench import scenarios
from bench.harness import measure, peak_rss_mb
from bench.reference_fit import joint_optimum
from core.evaluation import procrustes_r2
from core.gp import FitOptions, fit_hyperparameters, fit_manifold, make_likelihood
from core.recognition import ActivePolicy, Planner, RecognitionSession
from core.types import TrainingData


def run(arguments: dict[str, Any]) -> dict[str, Any]:
    """Measure one configuration (see the module docstring)."""
    baseline = peak_rss_mb()
    n_objects = int(arguments["objects"])
    per_object = int(arguments["per_object"])
    structure = arguments.get("structure", "auto")
    seed = int(arguments.get("seed", 0))
    design = arguments.get("design", "shared")
    world = scenarios.world(seed, n_objects)
    data = scenarios.dataset(world, design, per_object, seed + 1)
    out: dict[str, Any] = {
        "objects": n_objects,
        "per_object": per_object,
        "touches": data.n_touches,
        "structure": structure,
        "design": design,
        "baseline_mb": baseline,
    }
    if arguments.get("evaluate", True):
        likelihood = make_likelihood(data, 2, structure)
        vector = likelihood.layout.pack(
            scenarios.true_latents(world), scenarios.reference_hyperparameters(world, data)
        )
        timing = measure(
            lambda: likelihood.value_and_gradient(vector),
            repeats=int(arguments.get("repeats", 3)),
            warmup=1,
            budget_s=20.0,
        )
        out["evaluate_s"] = timing.median_s
    if arguments.get("fit", False):
        options = FitOptions(restarts=0, structure=structure)
        started = time.perf_counter()
        model = fit_manifold(data, 2, np.random.default_rng(seed + 2), options)
        out["fit_s"] = time.perf_counter() - started
        out["fit_iterations"] = model.diagnostics.iterations if model.diagnostics else None
        out["fit_log_likelihood"] = model.log_likelihood
        out["fit_r2"] = procrustes_r2(world.truth, model.latents)
        out["fit_structure"] = model.posterior.structure
    if arguments.get("plan", False):
        model = scenarios.reference_model(world, data, structure)
        started = time.perf_counter()
        planner = Planner(model, ActivePolicy())
        out["plan_setup_s"] = time.perf_counter() - started
        beliefs = scenarios.beliefs(model, 8, seed + 3)
        rng = np.random.default_rng(seed + 4)
        cursor = iter(range(10**9))

        def plan() -> None:
            planner.plan(beliefs[next(cursor) % len(beliefs)], rng)

        out["plan_ms"] = 1e3 * measure(plan, repeats=8, warmup=1, budget_s=30.0).median_s
        action = planner.plan(beliefs[0], rng).action
        observation = world.observe(0, action[None, :], rng)[0]

        def update() -> None:
            RecognitionSession(model, planner).observe(action, observation)

        out["update_ms"] = 1e3 * measure(update, repeats=5, warmup=1, budget_s=20.0).median_s
    out["peak_mb"] = peak_rss_mb()
    if arguments.get("fit", False):
        out["truth_log_likelihood"] = truth_optimum(scenarios.true_latents(world), data, structure)
    return out


def truth_optimum(truth: np.ndarray, data: TrainingData, structure: Any) -> float:
    """Log-likelihood of the joint optimum reached from the true latents ``truth`` (L, 2), with
    hyperparameters fitted to them first (:func:`bench.reference_fit.joint_optimum`)."""
    options = FitOptions(structure=structure)
    log_likelihood, _ = joint_optimum(data, fit_hyperparameters(data, truth, options), options)
    return log_likelihood


def main() -> None:
    """Parse the JSON argument, run, print the JSON result."""
    arguments = json.loads(sys.argv[1])
    sys.stdout.write(json.dumps(run(arguments)) + "\n")


if __name__ == "__main__":
    main()
