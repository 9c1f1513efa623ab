"""Experiment 1 end to end: the learned manifold recovers θ and every object is recognised."""

from __future__ import annotations

import numpy as np
import pytest

from core.evaluation.metrics import abs_correlation
from core.evaluation.trial_engine import PlannedTouches, WorldTouches, iter_trial
from core.evaluation.worlds import Experiment1World, sample_dataset
from core.gp.manifold import FitOptions, fit_manifold
from core.recognition.planning import ActivePolicy, Planner
from core.recognition.session import RecognitionSession, RecognitionSettings, default_prior


@pytest.fixture(scope="module")
def fitted():
    world = Experiment1World(noise_std=0.1)
    data = sample_dataset(world, np.random.default_rng(0), touches_per_object=100)
    model = fit_manifold(data, 1, np.random.default_rng(0), FitOptions(restarts=2))
    return world, model


def test_learned_manifold_is_theta_up_to_scale(fitted):
    world, model = fitted
    # The paper reports 0.9995; the reference implementation 0.998-0.9999 over seeds.
    assert abs_correlation(world.truth, model.latents) > 0.995


def test_every_object_is_recognised_actively_within_ten_touches(fitted):
    world, model = fitted
    planner = Planner(model, ActivePolicy())
    settings = RecognitionSettings(max_steps=10)
    rng = np.random.default_rng(7)  # one stream for every trial, planner and noise alike
    per_object = []
    for target, name in enumerate(model.object_names):
        correct = []
        for _ in range(3):
            session = RecognitionSession(model, planner, default_prior(model, 5.0), settings)
            touches = PlannedTouches(WorldTouches(world, name))
            *_, (last, _) = iter_trial(session, touches, rng, rng)
            correct.append(last.answer == target)
        per_object.append(float(np.mean(correct)))
    assert per_object == [1.0, 1.0, 1.0, 1.0]
