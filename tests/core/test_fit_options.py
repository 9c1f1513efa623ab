"""The fit-cost settings: L-BFGS-B memory, the cap on the screening subsample, the stall
test of the final joint runs and the random restarts that give up."""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np
import pytest

from core.errors import InvalidInputError
from core.evaluation.worlds import random_experiment2_world, sample_dataset
from core.gp import fit_run
from core.gp.fit_options import FitOptions
from core.gp.fit_run import FitRun
from core.gp.hyperparameter_fit import minimize_free
from core.gp.likelihood import ManifoldLikelihood
from core.gp.manifold import fit_manifold
from core.types import TrainingData
from tests.core.badly_scaled import minimize_quadratic


def test_more_joint_lbfgs_memory_reaches_the_optimum_in_fewer_iterations() -> None:
    # A badly scaled quadratic (condition 1e4): with more correction pairs L-BFGS-B models
    # more of the curvature. Both runs must reach the optimum; the longer memory must be used.
    short = minimize_quadratic(memory=10)
    long = minimize_quadratic(memory=30)
    assert short.fun < 1e-10
    assert long.fun < 1e-10
    assert long.nit < 0.8 * short.nit


def test_a_run_that_cannot_reach_the_target_at_its_pace_gives_up() -> None:
    scales = np.logspace(0, 4, 30)

    class Quadratic:  # minimum 100 at 0
        def value_and_gradient(self, x: np.ndarray) -> tuple[float, np.ndarray]:
            return float(100.0 + 0.5 * np.sum(scales * x**2)), scales * x

    x0 = np.ones(30)
    free = np.ones(30, dtype=bool)
    bounds = (np.full(30, -10.0), np.full(30, 10.0))
    full = minimize_free(Quadratic(), x0, free, *bounds, 500, 1e-15, 1e-12)
    hopeless = minimize_free(
        Quadratic(), x0, free, *bounds, 500, 1e-15, 1e-12, reach=50.0, reach_iterations=5
    )
    assert not hopeless.success
    assert "ABANDONED" in hopeless.message
    assert hopeless.nit < full.nit
    # A reachable target changes nothing: the same path, to the end.
    reachable = minimize_free(
        Quadratic(), x0, free, *bounds, 500, 1e-15, 1e-12, reach=101.0, reach_iterations=5
    )
    assert reachable.nit == full.nit
    np.testing.assert_array_equal(reachable.x, full.x)


def test_random_restarts_give_up_behind_the_data_driven_starts() -> None:
    rng = np.random.default_rng(2)
    world = random_experiment2_world(
        rng, n_objects=8, latent_dim=2, action_dim=1, observation_dim=2
    )
    data = sample_dataset(world, rng, touches_per_object=20)
    runs = {}
    for reach in (0, 10):
        options = FitOptions(
            restarts=3, screen_touches_per_object=8, restart_reach_iterations=reach
        )
        run = FitRun(data, 2, np.random.default_rng(1), options)
        model = list(run.events())[-1].model
        assert model is not None
        runs[reach] = (run, model)
    (never, kept), (gives_up, model) = runs[0], runs[10]
    abandoned = [s for s in gives_up.starts if s.message.startswith("ABANDONED")]
    assert abandoned
    assert all(s.kind == "random" for s in abandoned)
    assert gives_up.screen is not None
    assert never.screen is not None
    assert gives_up.screen.likelihood.evaluations < never.screen.likelihood.evaluations
    # The data-driven start won both times, by the same path.
    assert model.log_likelihood == kept.log_likelihood
    np.testing.assert_array_equal(model.latents, kept.latents)
    assert model.diagnostics is not None
    assert kept.diagnostics is not None
    best = model.diagnostics.best_start
    assert best == kept.diagnostics.best_start
    assert gives_up.starts[best].kind == "data"


def _data(n_objects: int, touches: int) -> TrainingData:
    rng = np.random.default_rng(0)
    world = random_experiment2_world(rng, n_objects=n_objects, action_dim=1, observation_dim=2)
    return sample_dataset(world, rng, touches_per_object=touches)


@pytest.mark.parametrize(
    ("cap", "per_object"),
    [(0, 25), (400, 25), (100, 10), (60, 6), (5, 2)],  # 0 = no cap; a cap never goes below 2
)
def test_screening_subsample_is_capped_in_total(cap: int, per_object: int) -> None:
    data = _data(n_objects=10, touches=60)
    options = FitOptions(screen_touches_per_object=25, screen_max_touches=cap)
    run = FitRun(data, 1, np.random.default_rng(1), options)
    assert run.screen is not None
    assert run.screen is not run.full
    counts = run.screen.likelihood.data.touches_per_object()
    np.testing.assert_array_equal(counts, np.full(10, per_object))


def test_a_cap_above_the_data_leaves_screening_off() -> None:
    data = _data(n_objects=4, touches=20)  # 20 touches per object ≤ 25: no screening
    run = FitRun(data, 1, np.random.default_rng(1), FitOptions(screen_max_touches=1000))
    assert run.screen is None


@pytest.mark.parametrize(
    ("field", "value", "message"),
    [
        ("joint_lbfgs_memory", 0, "joint_lbfgs_memory: must be ≥ 1"),
        ("joint_lbfgs_memory", 2.5, "joint_lbfgs_memory: expected an integer"),
        ("screen_max_touches", -1, "screen_max_touches: must be ≥ 0"),
        ("screen_max_touches", True, "screen_max_touches: expected an integer"),
        ("joint_stall_nats", -0.5, "joint_stall_nats: must be a finite number ≥ 0"),
        ("joint_stall_nats", float("inf"), "joint_stall_nats: must be a finite number ≥ 0"),
        ("joint_stall_nats", "1", "joint_stall_nats: expected a number"),
        ("joint_stall_iterations", 0, "joint_stall_iterations: must be ≥ 1"),
        ("joint_stall_iterations", 2.5, "joint_stall_iterations: expected an integer"),
        ("polish_lbfgs_memory", 0, "polish_lbfgs_memory: must be ≥ 1"),
        ("threads", 0, "threads: must be ≥ 1"),
        ("threads", 1.5, "threads: expected an integer"),
    ],
)
def test_bad_cost_options_are_named(field: str, value: object, message: str) -> None:
    with pytest.raises(InvalidInputError, match=message):
        FitOptions(**{field: value})  # type: ignore[arg-type]


@pytest.mark.parametrize("screened", [True, False])
def test_the_joint_stall_test_and_polish_memory_apply_to_the_final_runs_only(
    monkeypatch: pytest.MonkeyPatch, screened: bool
) -> None:
    # Every L-BFGS-B run of FitRun goes through fit_run.minimize_free (the hyperparameter
    # stages call it from core.gp.hyperparameter_fit, unaffected). Screening runs must keep
    # stall_nats / stall_iterations and scipy's 10 pairs; the joint runs on all the data use
    # the joint stall test, with polish_lbfgs_memory after a subsample screening and
    # joint_lbfgs_memory without screening.
    data = _data(n_objects=4, touches=30)
    seen: list[tuple[int, float, int, int]] = []

    def recording(objective: Any, *args: Any) -> Any:
        # fit_run passes everything positionally:
        # ..., callback, stall_nats, stall_iterations, stall_relative, memory
        seen.append((objective.data.n_touches, args[8], args[9], args[11]))
        return minimize_free(objective, *args)

    monkeypatch.setattr(fit_run, "minimize_free", recording)
    options = FitOptions(
        restarts=1,
        screen_touches_per_object=10 if screened else 0,
        stall_nats=0.01,
        stall_iterations=7,
        joint_stall_nats=0.3,
        joint_stall_iterations=11,
        joint_lbfgs_memory=23,
        polish_lbfgs_memory=17,
    )
    for _ in FitRun(data, 1, np.random.default_rng(2), options).events():
        pass
    screening = {(nats, window, memory) for n, nats, window, memory in seen if n == 40}
    joint = [(nats, window, memory) for n, nats, window, memory in seen if n == 120]
    assert len(joint) >= 1
    assert len(seen) == len(joint) + (2 if screened else 0)  # PCA (no Isomap below 8) + 1
    assert screening == ({(0.01, 7, 10)} if screened else set())
    assert set(joint) == {(0.3, 11, 17 if screened else 23)}


def test_a_fit_on_feature_threads_is_the_one_thread_fit() -> None:
    rng = np.random.default_rng(4)
    world = random_experiment2_world(
        rng, n_objects=5, latent_dim=2, action_dim=1, observation_dim=3
    )
    data = sample_dataset(world, rng, touches_per_object=12)
    options = FitOptions(restarts=1, screen_touches_per_object=6)
    models = [
        fit_manifold(data, 2, np.random.default_rng(0), replace(options, threads=threads))
        for threads in (1, 2)
    ]
    np.testing.assert_array_equal(models[1].latents, models[0].latents)
    assert models[1].log_likelihood == models[0].log_likelihood
    assert models[1].diagnostics == models[0].diagnostics


def test_a_start_plan_for_a_worker_runs_on_one_thread() -> None:
    rng = np.random.default_rng(4)
    world = random_experiment2_world(
        rng, n_objects=4, latent_dim=2, action_dim=1, observation_dim=2
    )
    data = sample_dataset(world, rng, touches_per_object=6)
    run = FitRun(data, 2, np.random.default_rng(0), FitOptions(threads=2))
    assert isinstance(run.full.likelihood, ManifoldLikelihood)
    assert run.full.likelihood.threads == 2
    plan = fit_run.StartPlan(
        run.full, run.layout, run.options, 10, "joint", run._settings(run.full, "joint")
    )
    single = plan.on_one_thread()
    assert isinstance(single.problem.likelihood, ManifoldLikelihood)
    assert single.problem.likelihood.threads == 1
    assert single.options.threads == 1
    assert run.full.likelihood.threads == 2  # the fit's own problem is left as it was
    assert single.problem.likelihood.data is run.full.likelihood.data
