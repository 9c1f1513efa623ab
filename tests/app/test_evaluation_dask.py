"""Evaluations on Dask distributed equal the in-process run, trial by trial."""

from __future__ import annotations

import socket
import threading

import numpy as np
import pytest

from app.documents.model import model_from_document
from app.errors import BadInputError
from app.evaluation.cluster import batches
from app.evaluation.report import EvaluationReport
from app.evaluation.runner import run_evaluation
from app.evaluation.spec import EvaluationSpec
from core.evaluation.worlds import sample_experiment1
from core.types import ManifoldModel
from tests.app.conftest import experiment1_document


@pytest.fixture(scope="module")
def model() -> ManifoldModel:
    return model_from_document(experiment1_document())


SPEC = EvaluationSpec(world="exp1", trials_per_target=3, steps=5)


@pytest.fixture(scope="module")
def serial(model) -> EvaluationReport:
    """The in-process run of :data:`SPEC` (read only)."""
    return run_evaluation(model, SPEC)


def test_a_cluster_run_equals_the_serial_run_trial_by_trial(model, serial, dask_cluster):
    seen = []
    distributed = run_evaluation(
        model, SPEC, scheduler=dask_cluster.scheduler_address, on_trial=seen.append
    )
    assert distributed.workers == 2
    assert len(distributed.records) == len(serial.records) == 2 * 4 * 3
    for ours, theirs in zip(serial.records, distributed.records, strict=True):
        assert ours == theirs
    assert sorted(r.key for r in seen) == [r.key for r in serial.records]
    expected, actual = serial.to_dict(), distributed.to_dict()
    for document in (expected, actual):
        del document["seconds"], document["workers"]
    assert actual == expected


def test_a_replay_on_the_cluster_equals_the_serial_replay(model, dask_cluster):
    held_out = sample_experiment1(np.random.default_rng(9), touches_per_object=4)
    spec = EvaluationSpec(world="replay", trials_per_target=2, steps=4)
    serial = run_evaluation(model, spec, replay=held_out)
    distributed = run_evaluation(
        model, spec, replay=held_out, scheduler=dask_cluster.scheduler_address
    )
    assert distributed.records == serial.records


def test_stopping_a_cluster_run_keeps_finished_trials(model, serial, dask_cluster):
    seen = []
    stopped = run_evaluation(
        model,
        SPEC,
        scheduler=dask_cluster.scheduler_address,
        on_trial=seen.append,
        should_stop=lambda: len(seen) >= 3,
    )
    assert stopped.stopped
    # Stop is polled as each task (a batch of trials) finishes: no new task starts after it.
    assert 3 <= len(stopped.records) < len(serial.records)
    assert len(seen) == len(stopped.records)
    by_key = {r.key: r for r in serial.records}
    assert all(by_key[r.key] == r for r in stopped.records)


def test_trials_are_batched_with_at_least_four_tasks_per_worker():
    keys = [("active", "O1", i) for i in range(100)]
    tasks = batches(keys, 2)
    assert [k for task in tasks for k in task] == keys
    assert {len(t) for t in tasks[:-1]} == {12}  # 100 // (4 · 2)
    assert len(batches(keys[:5], 2)) == 5
    assert max(len(t) for t in batches(keys * 10, 1)) == 16


def test_an_unreachable_scheduler_is_named(model):
    # Port 9 (discard) on the loopback: nothing listens, the connection is refused.
    with pytest.raises(BadInputError, match=r"scheduler: cannot reach .*tcp://127.0.0.1:9"):
        run_evaluation(model, SPEC, scheduler="tcp://127.0.0.1:9")
    with pytest.raises(BadInputError, match="missing port number in address 'nonsense'"):
        run_evaluation(model, SPEC, scheduler="nonsense")


def test_a_server_that_is_not_dask_is_named(model):
    listener = socket.socket()
    listener.bind(("127.0.0.1", 0))
    listener.listen(1)
    port = listener.getsockname()[1]

    def answer_garbage() -> None:
        connection, _ = listener.accept()
        with connection:
            connection.sendall(b"HTTP/1.1 400 Bad Request\r\n\r\n" * 4)

    thread = threading.Thread(target=answer_garbage, daemon=True)
    thread.start()
    try:
        with pytest.raises(BadInputError, match=rf"scheduler: .*tcp://127.0.0.1:{port}"):
            run_evaluation(model, SPEC, scheduler=f"tcp://127.0.0.1:{port}")
    finally:
        listener.close()
        thread.join(timeout=5)


def test_a_scheduler_without_workers_is_named(model):
    from distributed import LocalCluster

    with (
        LocalCluster(n_workers=0, processes=False, dashboard_address=":0") as empty,
        pytest.raises(BadInputError, match=r"has no worker.*dask worker"),
    ):
        run_evaluation(model, SPEC, scheduler=empty.scheduler_address)
