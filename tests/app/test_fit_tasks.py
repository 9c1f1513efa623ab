"""The fits and folds of ``--latent-dim auto`` and the starts of a fit as Dask tasks
(app/services/fit_tasks.py) equal the serial run, and a stop cancels them."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from app.services.fit_tasks import FitEngine, FoldFit
from core.evaluation.worlds import random_experiment2_world, sample_dataset
from core.gp.manifold import FitOptions, fit_manifold
from core.selection.latent_selection import select_latent_dim, serial_warm_map
from core.types import TrainingData
from tests.dask_fixtures import keys_left

FIT = FoldFit(FitOptions(restarts=1, max_iterations=150), "independent")


def small_world() -> TrainingData:
    rng = np.random.default_rng(3)
    world = random_experiment2_world(
        rng, n_objects=6, latent_dim=2, action_dim=1, observation_dim=2
    )
    return sample_dataset(world, rng, touches_per_object=8)


def test_the_folds_on_a_cluster_give_the_serial_choice_and_scores(dask_cluster: Any) -> None:
    data = small_world()

    def choose(**options: Any) -> tuple[Any, list[tuple[int, int, float]]]:
        seen: list[tuple[int, int, float]] = []
        choice = select_latent_dim(
            data,
            FIT,
            np.random.default_rng(1),
            (1, 2),  # two candidates are a choice; the warm test below goes to ds = 3
            n_folds=3,
            callback=lambda *a: seen.append(a),
            **options,
        )
        return choice, seen

    serial, serial_seen = choose()
    with FitEngine(None, dask_cluster.scheduler_address) as engine:
        distributed, seen = choose(map=engine.fold_map)
    assert distributed == serial  # the same choice, scores and training log-likelihoods
    assert sorted(seen) == sorted(serial_seen)  # every (ds, fold, score), in finishing order
    assert len(seen) == 2 * 3


def test_warm_folds_on_a_cluster_give_the_serial_choice_scores_and_models(
    dask_cluster: Any,
) -> None:
    data = small_world()

    def choose(engine: FitEngine | None) -> tuple[Any, list[tuple[int, float]]]:
        rungs: list[tuple[int, float]] = []
        choice = select_latent_dim(
            data,
            FIT,
            np.random.default_rng(1),
            (1, 2, 3),
            n_folds=3,
            refit=FIT.refit,
            rung_callback=lambda *a: rungs.append(a),
            warm_map=serial_warm_map if engine is None else engine.warm_map,
        )
        return choice, rungs

    serial, serial_rungs = choose(None)
    with FitEngine(None, dask_cluster.scheduler_address) as engine:
        distributed, rungs = choose(engine)
    assert distributed == serial  # the same choice, scores and training log-likelihoods
    assert sorted(rungs) == sorted(serial_rungs)  # every fit on all the touches
    assert [m.latent_dim for m in distributed.models] == [1, 2, 3]
    for ours, theirs in zip(distributed.models, serial.models, strict=True):
        assert ours.log_likelihood == theirs.log_likelihood
        np.testing.assert_array_equal(ours.latents, theirs.latents)


def test_a_stop_cancels_the_pending_folds(dask_cluster: Any) -> None:
    class StoppedError(Exception):
        pass

    def stop() -> None:
        raise StoppedError

    with (
        pytest.raises(StoppedError),
        FitEngine(None, dask_cluster.scheduler_address, stop) as engine,
    ):
        select_latent_dim(
            small_world(),
            FIT,
            np.random.default_rng(1),
            (1, 2, 3),
            n_folds=3,
            map=engine.fold_map,
        )
    # Nothing of the run stays: not its folds, their fits' starts nor the plans they scattered.
    assert keys_left(dask_cluster.scheduler_address, ("fold-", "start-", "StartPlan")) == []


def test_workers_or_a_scheduler_is_needed() -> None:
    with pytest.raises(ValueError, match="workers"):
        FitEngine(None, None)
    with pytest.raises(ValueError, match="workers"):
        FitEngine(0, None)


@pytest.mark.parametrize("kernels", ["per_feature", "tied"])
def test_the_starts_of_a_fit_on_a_cluster_give_the_serial_model(
    dask_cluster: Any, kernels: Any
) -> None:
    rng = np.random.default_rng(5)
    world = random_experiment2_world(
        rng, n_objects=5, latent_dim=2, action_dim=1, observation_dim=2
    )
    data = sample_dataset(world, rng, touches_per_object=16)
    # Screened on 6 touches per object: data-driven and random starts, then a polish.
    options = FitOptions(
        restarts=2, screen_touches_per_object=6, max_iterations=200, kernels=kernels
    )
    serial = fit_manifold(data, 2, np.random.default_rng(2), options, noise_model="correlated")
    phases: list[str] = []
    with FitEngine(None, dask_cluster.scheduler_address) as engine:
        distributed = fit_manifold(
            data,
            2,
            np.random.default_rng(2),
            options,
            lambda event: phases.append(event.phase),
            noise_model="correlated",
            start_map=engine.start_map,
        )
    assert distributed.log_likelihood == serial.log_likelihood
    np.testing.assert_array_equal(distributed.latents, serial.latents)
    for name in ("signal_variance", "noise_variance", "latent_lengthscales", "action_lengthscales"):
        np.testing.assert_array_equal(
            getattr(distributed.hyperparameters, name), getattr(serial.hyperparameters, name)
        )
    assert distributed.diagnostics == serial.diagnostics
    assert distributed.diagnostics is not None
    assert distributed.diagnostics.kernels == kernels
    # One event per start from the cluster; the correlated refit is one warm joint run here.
    assert phases.count("independent: screen done") == 3
    assert "independent: screen" not in phases
    assert "correlated: screen done" not in phases
    assert phases.count("correlated: joint done") == 1


def test_a_stop_cancels_the_pending_starts(dask_cluster: Any) -> None:
    class StoppedError(Exception):
        pass

    def stop() -> None:
        raise StoppedError

    rng = np.random.default_rng(5)
    world = random_experiment2_world(
        rng, n_objects=5, latent_dim=2, action_dim=1, observation_dim=2
    )
    data = sample_dataset(world, rng, touches_per_object=16)
    with (
        pytest.raises(StoppedError),
        FitEngine(None, dask_cluster.scheduler_address, stop) as engine,
    ):
        fit_manifold(
            data, 2, np.random.default_rng(2), FitOptions(restarts=3), start_map=engine.start_map
        )
    assert keys_left(dask_cluster.scheduler_address, ("start-", "StartPlan")) == []


def test_the_cli_takes_workers_or_a_scheduler_not_both(tmp_path: Any) -> None:
    from typer.testing import CliRunner

    from app.cli.main import app
    from tests.app.conftest import experiment1_csv

    csv = tmp_path / "train.csv"
    csv.write_text(experiment1_csv())
    runner = CliRunner()
    both = runner.invoke(
        app, ["fit", str(csv), "--latent-dim", "auto", "--workers", "2", "--scheduler", "x"]
    )
    assert both.exit_code == 2
    assert "--workers and --scheduler" in both.output
    nowhere = runner.invoke(
        app, ["fit", str(csv), "--latent-dim", "auto", "--scheduler", "tcp://127.0.0.1:9"]
    )
    assert nowhere.exit_code == 2
    assert "cannot reach a Dask scheduler" in nowhere.output


def test_the_server_runs_the_folds_of_an_auto_fit_on_its_scheduler(
    tmp_path: Any, dask_cluster: Any
) -> None:
    from app.main import create_app
    from tests.app.conftest import TestClient, make_settings
    from tests.app.test_fit_jobs import API, upload, wait_for

    settings = make_settings(tmp_path, dask_scheduler=dask_cluster.scheduler_address)
    with TestClient(create_app(settings)) as client:
        dataset_id = upload(client)
        body = {
            "dataset_id": dataset_id,
            "latent_dim": "auto",
            "restarts": 0,
            "max_iterations": 100,
            "seed": 0,
            "noise_model": "independent",
        }
        response = client.post(f"{API}/models", json=body)
        assert response.status_code == 202, response.text
        model = wait_for(client, response.json()["id"], lambda m: m["status"] != "fitting")
        assert model["status"] == "ready", model
        selection = model["latent_selection"]
        assert [c["latent_dim"] for c in selection["candidates"]] == [1, 2, 3]
        assert model["latent_dim"] == selection["chosen"]
        refused = client.post(f"{API}/models", json={**body, "workers": 0})
        assert refused.status_code == 422
        assert "workers" in refused.text
