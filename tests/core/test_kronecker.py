"""The exact Kronecker path for shared designs matches the dense path (docs/method.md)."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import pytest

from core.errors import CoreError, InvalidInputError
from core.evaluation.designs import collect, shared_design
from core.evaluation.worlds import random_experiment2_world
from core.gp.fit_run import FitRun, evaluation_cost
from core.gp.kronecker import (
    KroneckerLikelihood,
    action_statistics_derivatives,
    action_statistics_spectral,
    condition_kronecker,
    find_shared_design,
    predict_kronecker,
    predictive_covariance_kronecker,
    require_shared_design,
)
from core.gp.manifold import FitOptions, fit_manifold
from core.gp.placement_effect import predictive_covariance
from core.gp.posterior import condition, predict, resolve_structure
from core.recognition.information_gradient import mutual_information_and_gradient
from core.recognition.moments import (
    ActionStatistics,
    action_statistics,
    mutual_information,
    predictive_moments,
)
from core.recognition.planning import ActivePolicy, Planner
from core.recognition.session import RecognitionSession
from core.types import GaussianBelief, Hyperparameters, ManifoldModel, TrainingData
from tests.core.agreement import (
    KRONECKER_TOLERANCE,
    assert_kronecker_matches_dense,
    assert_moments_match_direct,
    relative,
)
from tests.core.finite_differences import central_differences

TOLERANCE = KRONECKER_TOLERANCE


@dataclass(frozen=True)
class Case:
    """A small shared-design problem."""

    name: str
    n_objects: int
    n_actions: int
    action_dim: int
    observation_dim: int
    latent_dim: int


CASES = [
    Case("exp2-shape", 4, 10, 6, 5, 2),
    Case("ds1-dx1", 3, 8, 1, 2, 1),
    Case("many-objects", 12, 5, 2, 3, 2),
    Case("ds3", 3, 6, 2, 2, 3),
]


def make_problem(
    case: Case, seed: int, shuffle: bool = True
) -> tuple[TrainingData, np.ndarray, Hyperparameters]:
    """Shared-design data (rows shuffled), random latents and random hyperparameters."""
    rng = np.random.default_rng(seed)
    world = random_experiment2_world(
        rng,
        n_objects=case.n_objects,
        latent_dim=case.latent_dim,
        action_dim=case.action_dim,
        observation_dim=case.observation_dim,
    )
    design = shared_design(
        case.n_objects, case.n_actions, np.zeros(case.action_dim), np.eye(case.action_dim), rng
    )
    data = collect(world, design, rng)
    if shuffle:
        perm = rng.permutation(data.n_touches)
        data = TrainingData(
            data.object_names,
            data.object_index[perm],
            data.actions[perm],
            data.observations[perm],
        )
    dy, ds, dx = case.observation_dim, case.latent_dim, case.action_dim
    latents = rng.standard_normal((case.n_objects, ds))
    hyper = Hyperparameters(
        signal_variance=rng.uniform(0.3, 2.0, dy),
        noise_variance=rng.uniform(0.005, 0.1, dy),
        latent_lengthscales=rng.uniform(0.5, 2.0, (dy, ds)),
        action_lengthscales=rng.uniform(0.7, 2.5, (dy, dx)),
    )
    return data, latents, hyper


@pytest.mark.parametrize("case", CASES, ids=lambda c: c.name)
def test_value_and_gradient_match_the_dense_likelihood(case: Case) -> None:
    data, latents, hyper = make_problem(case, seed=1)
    kron, vector, value_k = assert_kronecker_matches_dense(data, case.latent_dim, latents, hyper)
    assert kron.value(vector) == pytest.approx(value_k, rel=1e-12)
    assert kron.evaluations == 2


def test_gradient_matches_finite_differences() -> None:
    data, latents, hyper = make_problem(CASES[2], seed=2)
    kron = KroneckerLikelihood(data, 2)
    vector = kron.layout.pack(latents, hyper)
    _, grad = kron.value_and_gradient(vector)
    numeric = central_differences(kron.value, vector)
    assert relative(grad, numeric) < 1e-6


@pytest.mark.parametrize("case", CASES[:2], ids=lambda c: c.name)
def test_conditioned_model_matches_dense_beta_inverse_and_predictions(case: Case) -> None:
    data, latents, hyper = make_problem(case, seed=3)
    dense = condition(data, latents, hyper, structure="dense")
    kron = condition_kronecker(data, latents, hyper)
    assert kron.posterior.structure == "kronecker"
    assert dense.posterior.structure == "dense"
    assert abs(kron.log_likelihood - dense.log_likelihood) <= TOLERANCE * abs(dense.log_likelihood)
    assert relative(kron.posterior.beta, dense.posterior.beta) <= TOLERANCE
    assert not kron.posterior.has_dense_inverse
    assert relative(kron.posterior.gram_inverse, dense.posterior.gram_inverse) <= TOLERANCE
    assert kron.posterior.has_dense_inverse
    rng = np.random.default_rng(4)
    queries = rng.standard_normal((7, case.latent_dim))
    actions = rng.standard_normal((7, case.action_dim))
    mean_k, var_k = predict_kronecker(kron, queries, actions)
    mean_d, var_d = predict(dense, queries, actions)
    assert relative(mean_k, mean_d) <= TOLERANCE
    assert relative(var_k, var_d) <= TOLERANCE
    # predict() dispatches to the structured path on a Kronecker model.
    assert relative(predict(kron, queries, actions)[0], mean_d) <= TOLERANCE


def test_action_statistics_and_mutual_information_match_the_dense_path() -> None:
    case = CASES[0]
    data, latents, hyper = make_problem(case, seed=5)
    dense = condition(data, latents, hyper, structure="dense")
    kron = condition_kronecker(data, latents, hyper)
    candidates = np.random.default_rng(6).standard_normal((9, case.action_dim))
    reference = action_statistics(dense, candidates)
    responses, spectrum = action_statistics_spectral(kron, candidates)
    basis = kron.posterior.kronecker.latent_eigenvectors  # type: ignore[union-attr]
    blocks = np.einsum("alj,caj,amj->calm", basis, spectrum, basis)
    assert relative(responses, reference.responses) <= TOLERANCE
    assert relative(blocks, reference.trace_blocks) <= TOLERANCE
    belief = GaussianBelief(mean=latents.mean(axis=0) + 0.2, cov=np.diag([0.8, 0.4]))
    stats = ActionStatistics(actions=candidates, responses=responses, trace_blocks=blocks)
    mi_kron = mutual_information(predictive_moments(kron, belief, stats), belief)
    mi_dense = mutual_information(predictive_moments(dense, belief, reference), belief)
    assert relative(mi_kron, mi_dense) <= TOLERANCE
    assert np.all(mi_dense > 0)


def test_action_statistic_derivatives_match_finite_differences() -> None:
    data, latents, hyper = make_problem(CASES[0], seed=7)
    kron = condition_kronecker(data, latents, hyper)
    x = np.random.default_rng(8).standard_normal(6)
    responses, d_responses, spectrum, d_spectrum = action_statistics_derivatives(kron, x)
    batch_u, batch_t = action_statistics_spectral(kron, x[None, :])
    assert relative(responses, batch_u[0]) <= 1e-12
    assert relative(spectrum, batch_t[0]) <= 1e-12
    step = 1e-6
    for d in range(6):
        up, down = x.copy(), x.copy()
        up[d] += step
        down[d] -= step
        u_up, _, t_up, _ = action_statistics_derivatives(kron, up)
        u_down, _, t_down, _ = action_statistics_derivatives(kron, down)
        assert relative(d_responses[:, d], (u_up - u_down) / (2 * step)) < 1e-6
        assert relative(d_spectrum[:, d], (t_up - t_down) / (2 * step)) < 1e-6


def test_shared_design_is_detected_in_any_row_order() -> None:
    data, _, _ = make_problem(CASES[0], seed=9)
    design = find_shared_design(data)
    assert design is not None
    assert design.size == CASES[0].n_actions
    grid = design.grid_index
    assert sorted(grid.tolist()) == list(range(data.n_touches))
    # The touch at grid position l·M + m is object l touched with design action m.
    m = design.size
    np.testing.assert_array_equal(data.object_index, grid // m)
    np.testing.assert_array_equal(data.actions, design.actions[grid % m])
    assert resolve_structure(data)[0] == "kronecker"


def test_a_missing_touch_falls_back_to_the_dense_path_exactly() -> None:
    data, latents, hyper = make_problem(CASES[0], seed=10, shuffle=False)
    keep = np.ones(data.n_touches, dtype=bool)
    keep[3] = False  # object 0 lacks one design action
    partial = TrainingData(
        data.object_names,
        data.object_index[keep],
        data.actions[keep],
        data.observations[keep],
    )
    assert find_shared_design(partial) is None
    assert resolve_structure(partial)[0] == "dense"
    model = condition(partial, latents, hyper)
    assert model.posterior.structure == "dense"
    expected = r"most objects have 10 touches but 'O1' \(9\) differ"
    with pytest.raises(InvalidInputError, match=expected):
        require_shared_design(partial)
    with pytest.raises(InvalidInputError, match="structure='kronecker'"):
        condition(partial, latents, hyper, structure="kronecker")


def test_different_actions_per_object_are_not_a_shared_design() -> None:
    data, _, _ = make_problem(CASES[1], seed=11, shuffle=False)
    actions = data.actions.copy()
    actions[data.object_index == 2] += 1e-9
    moved = TrainingData(data.object_names, data.object_index, actions, data.observations)
    assert find_shared_design(moved) is None
    with pytest.raises(InvalidInputError, match="'O3' was not touched with the same actions"):
        KroneckerLikelihood(moved, 1)


def test_a_repeated_design_action_still_matches_dense() -> None:
    data, latents, hyper = make_problem(CASES[1], seed=12, shuffle=False)
    actions = data.actions.copy()
    m = CASES[1].n_actions
    for obj in range(CASES[1].n_objects):
        actions[obj * m + 1] = actions[obj * m]  # design action 1 repeats action 0
    repeated = TrainingData(data.object_names, data.object_index, actions, data.observations)
    assert_kronecker_matches_dense(repeated, 1, latents, hyper)


def test_large_posterior_does_not_materialise_its_inverse() -> None:
    case = Case("wide", 61, 100, 2, 1, 2)
    data, latents, hyper = make_problem(case, seed=13, shuffle=False)
    model: ManifoldModel = condition(data, latents, hyper)
    assert model.posterior.structure == "kronecker"
    assert model.data.n_touches == 6100
    with pytest.raises(CoreError, match="not materialised above N = 6000"):
        _ = model.posterior.gram_inverse
    mean, variance = predict(model, latents[:3], data.actions[:3])
    assert mean.shape == (3, 1)
    assert np.all(variance > hyper.noise_variance)


def test_bad_latent_dim_is_rejected() -> None:
    data, _, _ = make_problem(CASES[1], seed=14)
    with pytest.raises(InvalidInputError, match="latent_dim"):
        KroneckerLikelihood(data, 0)


def test_moments_gradient_and_planning_run_on_the_structured_statistics() -> None:
    case = CASES[0]
    data, latents, hyper = make_problem(case, seed=15)
    dense = condition(data, latents, hyper, structure="dense")
    kron = condition(data, latents, hyper)
    assert kron.posterior.structure == "kronecker"
    candidates = np.random.default_rng(16).standard_normal((6, case.action_dim))
    stats = action_statistics(kron, candidates)
    assert stats.trace_basis is not None
    assert stats.trace_blocks.shape == (6, case.observation_dim, case.n_objects)
    reference = action_statistics(dense, candidates)
    assert relative(stats.dense_trace_blocks(), reference.trace_blocks) <= TOLERANCE
    belief = GaussianBelief(mean=latents.mean(axis=0), cov=np.diag([1.5, 0.7]))
    mi_kron = mutual_information(predictive_moments(kron, belief, stats), belief)
    mi_dense = mutual_information(predictive_moments(dense, belief, reference), belief)
    assert relative(mi_kron, mi_dense) <= TOLERANCE
    assert (
        relative(
            mutual_information(
                predictive_moments(kron, belief, stats.subset(np.array([2, 4]))), belief
            ),
            mi_dense[[2, 4]],
        )
        <= TOLERANCE
    )
    value_k, grad_k = mutual_information_and_gradient(kron, belief, candidates[0])
    value_d, grad_d = mutual_information_and_gradient(dense, belief, candidates[0])
    assert value_k == pytest.approx(value_d, rel=TOLERANCE)
    assert relative(grad_k, grad_d) <= 1e-7
    planned_k = Planner(kron, ActivePolicy(), n_candidates=64).plan(
        belief, np.random.default_rng(0)
    )
    planned_d = Planner(dense, ActivePolicy(), n_candidates=64).plan(
        belief, np.random.default_rng(0)
    )
    assert planned_k.mutual_information == pytest.approx(planned_d.mutual_information, rel=1e-6)
    np.testing.assert_allclose(planned_k.action, planned_d.action, atol=1e-5)


def test_recognition_runs_on_a_large_kronecker_model_without_a_dense_inverse() -> None:
    case = Case("large", 70, 100, 6, 5, 2)
    data, latents, hyper = make_problem(case, seed=17, shuffle=False)
    model = condition(data, latents, hyper)
    assert model.posterior.structure == "kronecker"
    planner = Planner(model, ActivePolicy(), n_candidates=32)
    session = RecognitionSession(model, planner)
    rng = np.random.default_rng(18)
    planned = session.suggest(rng)
    observation = model.data.observations[0] + 0.01 * rng.standard_normal(5)
    step = session.observe(planned.action, observation)
    assert step.probabilities.shape == (70,)
    assert np.isfinite(step.mutual_information)
    assert step.mutual_information > 0
    assert not model.posterior.has_dense_inverse


@pytest.mark.parametrize("case", CASES[:2], ids=lambda c: c.name)
def test_spectral_predictive_covariance_equals_the_dense_one(case: Case) -> None:
    data, latents, hyper = make_problem(case, seed=23)
    model = condition(data, latents, hyper)
    assert model.posterior.structure == "kronecker"
    rng = np.random.default_rng(24)
    s, x = rng.normal(size=case.latent_dim), rng.normal(size=(4, case.action_dim))
    spectral = predictive_covariance_kronecker(model, s, x)
    assert not model.posterior.has_dense_inverse
    np.testing.assert_array_equal(predictive_covariance(model, s, x), spectral)
    assert model.posterior.gram_inverse.shape[0] == case.observation_dim  # materialise K⁻¹
    assert model.posterior.has_dense_inverse
    np.testing.assert_allclose(spectral, predictive_covariance(model, s, x), atol=1e-9)


def test_a_fit_on_a_shared_design_runs_through_kronecker_and_matches_the_dense_fit() -> None:
    case = Case("fit", 3, 8, 2, 2, 1)
    data, _, _ = make_problem(case, seed=19)
    options = FitOptions(restarts=0, screen_touches_per_object=0, max_iterations=200)
    kron = fit_manifold(data, 1, np.random.default_rng(20), options)
    dense = fit_manifold(data, 1, np.random.default_rng(20), replace(options, structure="dense"))
    assert kron.posterior.structure == "kronecker"
    assert dense.posterior.structure == "dense"
    assert kron.log_likelihood == pytest.approx(dense.log_likelihood, rel=1e-6)
    np.testing.assert_allclose(np.abs(kron.latents), np.abs(dense.latents), atol=1e-3)


def test_screening_a_shared_design_keeps_it_shared() -> None:
    data, _, _ = make_problem(CASES[0], seed=21)  # 4 objects x 10 actions: M^3 dominates
    run = FitRun(data, 2, np.random.default_rng(22), FitOptions(screen_touches_per_object=3))
    assert isinstance(run.full.likelihood, KroneckerLikelihood)
    assert run.screen is not None
    assert run.screen is not run.full
    assert isinstance(run.screen.likelihood, KroneckerLikelihood)
    assert run.screen.likelihood.data.n_touches == CASES[0].n_objects * 3


def test_screening_that_would_not_save_runs_on_all_the_data() -> None:
    # 12 objects x 5 actions: the 12 x 12 latent factorisations dominate an evaluation, so a
    # 3-action subsample would save 1.25x (below SCREEN_MIN_SAVING) and only blur the starts.
    data, _, _ = make_problem(CASES[2], seed=21)
    assert evaluation_cost(data, "kronecker", 512) == 12**3 + 5**3 + 12 * 5 * (12 + 5)
    run = FitRun(
        data, 2, np.random.default_rng(22), FitOptions(screen_touches_per_object=3, restarts=1)
    )
    assert run.screen is run.full
    phases, model = [], None
    for event in run.events():
        phases.append((event.start, event.phase))
        model = event.model if event.model is not None else model
    assert model is not None
    assert np.isfinite(model.log_likelihood)
    # The winner goes on from its screened point on all the data: no fresh hyperparameters.
    first = next(i for i, (_, phase) in enumerate(phases) if phase.startswith("joint"))
    polish = phases[first:]
    assert all(phase in ("joint", "joint done", "done") for _, phase in polish)
    assert model.diagnostics is not None
    assert model.diagnostics.starts_log_likelihood[model.diagnostics.best_start] == pytest.approx(
        model.log_likelihood
    )
    with pytest.raises(InvalidInputError, match="structure: expected one of"):
        FitOptions(structure="banded")  # type: ignore[arg-type]


def test_many_objects_moments_match_the_direct_appendix_formula() -> None:
    case = Case(
        "forty", 40, 3, 2, 2, 2
    )  # above the element-wise threshold of core.recognition.moments
    data, latents, hyper = make_problem(case, seed=23)
    model = condition(data, latents, hyper)
    assert model.posterior.structure == "kronecker"
    belief = GaussianBelief(mean=latents[5] + 0.2, cov=np.array([[0.6, 0.1], [0.1, 0.4]]))
    actions = np.random.default_rng(24).standard_normal((3, case.action_dim))
    assert_moments_match_direct(model, belief, actions)
