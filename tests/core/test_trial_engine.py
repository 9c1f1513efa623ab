"""The trial engine: seeds, worlds, the model-sampled world and replay without replacement."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from core.errors import InvalidInputError
from core.evaluation.records import (
    TrialRecord,
    outcome_from_dict,
    trial_generators,
    trial_seed,
)
from core.evaluation.reference_model import experiment1_at_true_latents
from core.evaluation.trial_engine import (
    ModelSamples,
    ModelTrial,
    PlannedTouches,
    ReplayPool,
    TrialSettings,
    WorldTouches,
    iter_trial,
    replay_offer,
    replay_pools,
    run_trial,
)
from core.evaluation.worlds import (
    DEFAULT_NOISE_STD,
    WORLD_NAMES,
    Experiment1World,
    make_world,
    sample_experiment1,
)
from core.gp.posterior import predict, predict_model_space
from core.recognition.planning import (
    EVALUATION_POLICIES,
    POLICIES,
    POLICY_NAMES,
    Planner,
    label_information_score,
    policy_entry,
)
from core.recognition.session import (
    RecognitionSession,
    RecognitionSettings,
    default_prior,
    objects_belief,
)
from core.types import ManifoldModel


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
        touches=WorldTouches(Experiment1World(), target),
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
    from core.recognition.planning import FixedPolicy

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
    touches = WorldTouches(ModelSamples(model), "O3")
    action = np.array([0.4])
    rng = np.random.default_rng(3)
    draws = np.array([touches.touch(action, rng).observation for _ in range(4000)])
    mean, variance = predict(model, model.latents[2][None, :], action[None, :])
    # Standard error of a mean of 4000 draws: sqrt(v / 4000); 5 standard errors.
    assert np.all(np.abs(draws.mean(axis=0) - mean[0]) < 5 * np.sqrt(variance[0] / 4000))
    assert np.allclose(draws.var(axis=0), variance[0], rtol=0.1)


def test_model_trial_without_a_placement_effect_draws_as_the_model_world(model):
    trial_touches = ModelTrial(model, "O2")
    world = WorldTouches(ModelSamples(model), "O2")
    first, second = np.random.default_rng(5), np.random.default_rng(5)
    for x in (0.1, -0.7, 1.2):
        action = np.array([x])
        np.testing.assert_array_equal(
            trial_touches.touch(action, first).observation, world.touch(action, second).observation
        )


@pytest.mark.parametrize(
    ("placement_share", "drift_share", "shared"),
    [(0.6, 0.0, True), (0.6, 0.0, False), (0.3, 0.4, True), (0.3, 0.4, False)],
)
def test_model_trial_shares_one_placement_offset_between_its_touches(
    model, placement_share, drift_share, shared
):
    # Moments vs Monte Carlo: two touches of a trial at different actions. Every draw keeps the
    # predictive variance v; the two share the placement's offset b (σ_b², 0 when the object is
    # placed anew before each touch) and the drift's d (σ_d², whatever the placement).
    noise = model.hyperparameters.noise_variance
    sigma_b, sigma_d = placement_share * noise, drift_share * noise
    placed = dataclasses.replace(
        model, placement_variance=sigma_b, drift_variance=sigma_d if drift_share else None
    )
    actions = [np.array([0.2]), np.array([-0.9])]
    rng = np.random.default_rng(8)
    pairs = []
    for _ in range(3000):
        source = ModelTrial(placed, "O3", shared_placement=shared)
        pairs.append(placed.to_model_space(np.array([source.touch(x, rng).observation
                                                     for x in actions])))  # fmt: skip
    draws = np.array(pairs)  # (trials, 2, dy)
    _, variance = predict_model_space(
        placed, np.repeat(placed.latents[2][None, :], 2, axis=0), np.array(actions)
    )
    for t in range(2):
        assert np.allclose(draws[:, t].var(axis=0), variance[t], rtol=0.1)
    centred = draws - draws.mean(axis=0)
    covariance = (centred[:, 0] * centred[:, 1]).mean(axis=0)
    expected = (sigma_b if shared else np.zeros_like(sigma_b)) + sigma_d
    # Standard error of the sample covariance ≈ sqrt(v_1 v_2 / n); 5 of them.
    tolerance = 5 * np.sqrt(variance[0] * variance[1] / len(pairs))
    assert np.all(np.abs(covariance - expected) < tolerance)


def test_unknown_policy_and_target_are_named(model):
    allowed = r"\['active', 'discriminative', 'passive'\]"
    with pytest.raises(InvalidInputError, match=rf"'greedy'.*{allowed}"):
        policy_entry("greedy", EVALUATION_POLICIES)
    with pytest.raises(InvalidInputError, match="'O9'"):
        WorldTouches(Experiment1World(), "O9")
    with pytest.raises(InvalidInputError, match="'O9'"):
        WorldTouches(ModelSamples(model), "O9")
    with pytest.raises(InvalidInputError, match="'O9'"):
        ModelTrial(model, "O9")
    assert set(POLICIES) >= {"active", "passive"}


@pytest.fixture(scope="module")
def held_out():
    return sample_experiment1(np.random.default_rng(11), touches_per_object=8)


def fresh_trial(model, policy, target, settings, index=0, **source):
    """Trial ``index`` of ``target`` by a fresh ``policy`` planner, seeded as an evaluation
    seeds it; ``source``: the observations (``touches=`` or ``replay=``, and ``steps=``)."""
    return run_trial(
        model,
        Planner(model, policy_entry(policy).make()),
        policy=policy,
        target=target,
        trial=index,
        seed=trial_seed(0, target, index),
        settings=settings,
        **source,
    )


def replay(model, held_out, policy, target="O2", index=0, steps=None):
    pool = replay_pools(held_out)[target]
    settings = TrialSettings(steps=8, tolerance=0.0)
    return pool, fresh_trial(model, policy, target, settings, index, replay=pool, steps=steps)


@pytest.mark.parametrize("policy", ["active", "passive"])
def test_replay_draws_recorded_touches_without_replacement(model, held_out, policy):
    pool, record = replay(model, held_out, policy)
    assert record.touches == 8  # the whole pool, tolerance 0
    used = [int(np.flatnonzero(pool.actions[:, 0] == a[0])[0]) for a in record.actions]
    assert sorted(used) == list(range(8))  # each recorded touch once


def test_active_replay_picks_the_largest_information_first(model, held_out):
    pool, record = replay(model, held_out, "active")
    planner = Planner(model, policy_entry("active").make())
    scores = planner.mutual_information(objects_belief(model), pool.actions)
    assert record.actions[0] == tuple(pool.actions[int(np.argmax(scores))])
    assert record.mutual_information[0] == pytest.approx(float(scores.max()), rel=1e-9)


def test_each_replay_trial_is_offered_its_own_half_of_the_pool(model, held_out):
    # 8 recorded touches, 3 steps: each trial may choose among 4, drawn from its world generator.
    pool = replay_pools(held_out)["O2"]
    planner = Planner(model, policy_entry("active").make())
    firsts, offers = set(), set()
    for index in range(6):
        _, record = replay(model, held_out, "active", index=index, steps=3)
        _, passive = replay(model, held_out, "passive", index=index, steps=3)
        _, world_rng = trial_generators(trial_seed(0, "O2", index))
        offer = replay_offer(pool.size, 3, world_rng)
        assert len(offer) == 4
        offered = {tuple(pool.actions[i]) for i in offer}
        assert set(record.actions) <= offered
        assert set(passive.actions) <= offered  # the same offer for every policy of a trial
        scores = planner.mutual_information(objects_belief(model), pool.actions[offer])
        assert record.actions[0] == tuple(pool.actions[offer[int(np.argmax(scores))]])
        firsts.add(record.actions[0])
        offers.add(tuple(offer))
    assert len(offers) > 1  # trials differ
    assert len(firsts) > 1
    assert len(replay_offer(8, 5, np.random.default_rng(0))) == 5  # at least T
    assert replay_offer(8, 8, np.random.default_rng(0)) == list(range(8))  # T = n: whole


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
        fresh_trial(model, "active", "O1", TrialSettings(steps=2), replay=wrong)


def test_discriminative_replay_picks_the_most_label_informative_touch_first(model, held_out):
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


# --- the engine's loop and the outcome's stop reason -------------------------------------------


def test_the_loop_yields_each_touch_and_stops_when_the_caller_stops(model):
    asked = []

    class Counting:
        def touch(self, action, rng):
            asked.append(action)
            return WorldTouches(Experiment1World(), "O2").touch(action, rng)

    session = RecognitionSession(
        model, Planner(model, policy_entry("passive").make()), None, RecognitionSettings(8, 0.0)
    )
    rng = np.random.default_rng(0)
    steps = iter_trial(session, PlannedTouches(Counting()), rng, rng)
    first = next(steps)
    assert (first.step.step, len(asked)) == (1, 1)  # nothing is touched ahead of the caller
    np.testing.assert_array_equal(first.touch.action, first.step.action)
    steps.close()
    assert len(session.steps) == 1
    rest = list(iter_trial(session, PlannedTouches(Counting()), rng, rng))  # resumes the session
    assert [s.step.step for s in rest] == list(range(2, 9))
    assert rest[-1].step.stop_reason == "max_steps"


@pytest.mark.parametrize(
    ("settings", "reason"),
    [
        (TrialSettings(steps=3, tolerance=0.0), "max_steps"),
        (TrialSettings(steps=10, tolerance=0.0, stop_confidence=0.9), "confident"),
        (TrialSettings(steps=10, tolerance=10.0), "converged"),
    ],
)
def test_the_outcome_records_why_the_trial_stopped(model, settings, reason):
    record = fresh_trial(
        model, "active", "O2", settings, touches=WorldTouches(Experiment1World(), "O2")
    )
    assert isinstance(record, TrialRecord)
    assert record.stop_reason == reason
    assert record.stopped_by_confidence == (reason == "confident")
    if reason == "confident":
        assert max(record.probabilities[-1]) >= 0.9
        assert all(max(p) < 0.9 for p in record.probabilities[:-1])
    assert TrialRecord.from_dict(record.to_dict()) == record


def test_a_record_written_without_a_stop_reason_still_reads(model):
    record = trial(model, Planner(model, policy_entry("active").make()), "active", "O2", 0)
    document = record.to_dict()
    del document["stop_reason"]
    old = outcome_from_dict(document)
    assert isinstance(old, TrialRecord)
    assert old.stop_reason is None
    assert not old.stopped_by_confidence
    assert old.answers == record.answers
    with pytest.raises(InvalidInputError, match="stop_reason"):
        TrialRecord.from_dict({**record.to_dict(), "stop_reason": "bored"})


def test_a_trial_has_exactly_one_observation_source(model, held_out):
    planner = Planner(model, policy_entry("active").make())
    common = {"policy": "active", "target": "O1", "trial": 0, "seed": trial_seed(0, "O1", 0)}
    with pytest.raises(InvalidInputError, match="exactly one"):
        run_trial(model, planner, settings=SETTINGS, **common)
    with pytest.raises(InvalidInputError, match="exactly one"):
        run_trial(
            model,
            planner,
            settings=SETTINGS,
            touches=WorldTouches(Experiment1World(), "O1"),
            replay=replay_pools(held_out)["O1"],
            **common,
        )


# --- the registries ----------------------------------------------------------------------------


def test_one_registry_names_the_policies_evaluations_may_run():
    assert tuple(POLICIES) == POLICY_NAMES
    assert EVALUATION_POLICIES == ("active", "discriminative", "passive")
    assert POLICIES["fixed"].needs_action
    with pytest.raises(InvalidInputError, match=r"'fixed'.*\['active', 'discriminative'"):
        policy_entry("fixed", EVALUATION_POLICIES)
    assert POLICIES["passive"].replay_score is None  # a replay picks at random


def test_one_registry_makes_the_worlds_with_their_noise_defaults():
    exp1 = make_world("exp1")
    assert isinstance(exp1, Experiment1World)
    assert exp1.noise_std == DEFAULT_NOISE_STD["exp1"] == 0.1
    assert make_world("exp1", noise_std=0.3).noise_std == 0.3
    exp2 = make_world("exp2", world_seed=3)
    assert (exp2.action_dim, exp2.observation_dim) == (6, 5)
    np.testing.assert_array_equal(exp2.noise_std, np.full(5, DEFAULT_NOISE_STD["exp2"]))
    np.testing.assert_array_equal(exp2.truth, make_world("exp2", world_seed=3).truth)
    assert set(WORLD_NAMES) == set(DEFAULT_NOISE_STD)
    with pytest.raises(InvalidInputError, match=r"'experiment1'.*\['exp1', 'exp2'\]"):
        make_world("experiment1")
