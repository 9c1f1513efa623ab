"""One evaluation trial: seeds, worlds, the model-sampled world and replay without replacement."""

from __future__ import annotations

import numpy as np
import pytest

from core.errors import InvalidInputError
from core.evaluation_records import trial_seed
from core.evaluation_trial import (
    POLICIES,
    ReplayPool,
    TrialSettings,
    model_observer,
    policy_entry,
    replay_pools,
    run_replay_trial,
    run_trial,
    world_observer,
)
from core.planning import Planner
from core.posterior import predict
from core.recognition import default_prior
from core.reference_model import experiment1_at_true_latents
from core.types import ManifoldModel
from core.worlds import Experiment1World, sample_experiment1


@pytest.fixture(scope="module")
def model() -> ManifoldModel:
    """Experiment 1 conditioned at the true θ (normalised) with fixed hyperparameters."""
    return experiment1_at_true_latents()


SETTINGS = TrialSettings(steps=6)


def trial(model, planner, policy, target, index, seed=0):
    return run_trial(
        model,
        planner,
        policy=policy,
        target=target,
        trial=index,
        seed=trial_seed(seed, target, index),
        observe=world_observer(Experiment1World(), target),
        settings=SETTINGS,
    )


@pytest.mark.parametrize("policy", ["active", "passive"])
def test_a_trial_rerun_alone_equals_the_same_trial_after_others(model, policy):
    shared = Planner(model, policy_entry(policy).make())
    batch = [trial(model, shared, policy, target, i) for target in ("O1", "O3") for i in range(3)]
    alone = trial(model, Planner(model, policy_entry(policy).make()), policy, "O3", 1)
    assert batch[4] == alone
    assert alone.trial == 1
    assert alone.target == "O3"
    # Different trials of a cell draw different noise.
    assert batch[3].probabilities != batch[4].probabilities


def test_policies_share_the_world_noise_of_a_trial(model):
    # Same actions would give the same observations: the fixed policy repeats one action, so
    # two runs with different policy names but the same (target, trial) see the same noise.
    from core.planning import FixedPolicy

    fixed = Planner(model, FixedPolicy(np.array([0.3])))
    first = trial(model, fixed, "x", "O2", 0)
    second = trial(model, fixed, "y", "O2", 0)
    assert first.probabilities == second.probabilities
    assert trial(model, fixed, "x", "O2", 0, seed=1).probabilities != first.probabilities


def test_record_holds_every_touch(model):
    record = trial(model, Planner(model, policy_entry("active").make()), "active", "O2", 0)
    assert 1 <= record.touches <= SETTINGS.steps
    assert len(record.answers) == len(record.actions) == record.touches
    assert all(len(p) == 4 and abs(sum(p) - 1.0) < 1e-9 for p in record.probabilities)
    assert record.correct == (record.answers[-1] == "O2")
    assert record.stop_reason in ("max_steps", "converged")


def test_model_world_samples_the_predictive_distribution(model):
    observe = model_observer(model, "O3")
    action = np.array([0.4])
    rng = np.random.default_rng(3)
    draws = np.array([observe(action, rng) for _ in range(4000)])
    mean, variance = predict(model, model.latents[2][None, :], action[None, :])
    # Standard error of a mean of 4000 draws: sqrt(v / 4000); 5 standard errors.
    assert np.all(np.abs(draws.mean(axis=0) - mean[0]) < 5 * np.sqrt(variance[0] / 4000))
    assert np.allclose(draws.var(axis=0), variance[0], rtol=0.1)


def test_unknown_policy_and_target_are_named(model):
    allowed = r"\['active', 'discriminative', 'passive'\]"
    with pytest.raises(InvalidInputError, match=rf"'greedy'.*{allowed}"):
        policy_entry("greedy")
    with pytest.raises(InvalidInputError, match="'O9'"):
        world_observer(Experiment1World(), "O9")
    with pytest.raises(InvalidInputError, match="'O9'"):
        model_observer(model, "O9")
    assert set(POLICIES) >= {"active", "passive"}


@pytest.fixture(scope="module")
def held_out():
    return sample_experiment1(np.random.default_rng(11), touches_per_object=8)


def replay(model, held_out, policy, target="O2", index=0, steps=None):
    pool = replay_pools(held_out)[target]
    return pool, run_replay_trial(
        model,
        Planner(model, policy_entry(policy).make()),
        policy=policy,
        target=target,
        trial=index,
        seed=trial_seed(0, target, index),
        pool=pool,
        settings=TrialSettings(steps=8, tolerance=0.0),
        steps=steps,
    )


@pytest.mark.parametrize("policy", ["active", "passive"])
def test_replay_draws_recorded_touches_without_replacement(model, held_out, policy):
    pool, record = replay(model, held_out, policy)
    assert record.touches == 8  # the whole pool, tolerance 0
    used = [int(np.flatnonzero(pool.actions[:, 0] == a[0])[0]) for a in record.actions]
    assert sorted(used) == list(range(8))  # each recorded touch once


def test_active_replay_picks_the_largest_information_first(model, held_out):
    pool, record = replay(model, held_out, "active")
    planner = Planner(model, policy_entry("active").make())
    scores = planner.mutual_information(default_prior(model, 5.0), pool.actions)
    assert record.actions[0] == tuple(pool.actions[int(np.argmax(scores))])
    assert record.mutual_information[0] == pytest.approx(float(scores.max()), rel=1e-9)


def test_passive_replay_order_depends_on_the_trial_seed(model, held_out):
    _, first = replay(model, held_out, "passive", index=0)
    _, again = replay(model, held_out, "passive", index=0)
    _, other = replay(model, held_out, "passive", index=1)
    assert first == again
    assert first.actions != other.actions


def test_replay_cap_and_dimensions_are_checked(model, held_out):
    _, capped = replay(model, held_out, "active", steps=3)
    assert capped.touches == 3
    with pytest.raises(InvalidInputError, match="only 8 recorded touches"):
        replay(model, held_out, "active", steps=9)
    wrong = ReplayPool(actions=np.zeros((4, 2)), observations=np.zeros((4, 3)))
    with pytest.raises(InvalidInputError, match="dx=2, dy=3; the model has dx=1, dy=3"):
        run_replay_trial(
            model,
            Planner(model, policy_entry("active").make()),
            policy="active",
            target="O1",
            trial=0,
            seed=trial_seed(0, "O1", 0),
            pool=wrong,
            settings=TrialSettings(steps=2),
        )


def test_discriminative_replay_picks_the_most_label_informative_touch_first(model, held_out):
    from core.evaluation_trial import label_information_score

    pool, record = replay(model, held_out, "discriminative")
    planner = Planner(model, policy_entry("discriminative").make())
    uniform = np.full(4, 0.25)
    scores = label_information_score(planner, default_prior(model, 5.0), uniform, pool.actions)
    assert record.actions[0] == tuple(pool.actions[int(np.argmax(scores))])
    assert np.all((scores >= 0) & (scores <= np.log(4) + 1e-12))  # 0 ≤ I(l; y) ≤ H(p)


def test_discriminative_trials_run_in_a_world(model):
    planner = Planner(model, policy_entry("discriminative").make())
    record = trial(model, planner, "discriminative", "O2", 0)
    assert record.policy == "discriminative"
    assert trial(model, planner, "discriminative", "O2", 0) == record
