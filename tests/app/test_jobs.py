"""The job runner: limits per kind, a first-in first-out queue with positions, stops, the rig's
lease given back, and a shutdown that lets every job (queued ones too) record its end; the run
states the dashboard reads are the server's."""

from __future__ import annotations

import threading

import pytest

from app import states
from app.errors import ConflictError
from app.services.jobs import Job, JobCancelled, JobRunner
from hardware.sim.rig import in_process_rig

TIMEOUT_S = 30.0


class Recorder:
    """Work functions that wait at a gate and note how each job ended."""

    def __init__(self) -> None:
        self.gates: dict[int, threading.Event] = {}
        self.ended: dict[int, str] = {}
        self.started: list[int] = []
        self.done = threading.Condition()

    def work(self, job_id: int) -> tuple[int, object]:
        self.gates[job_id] = threading.Event()

        def run(job: Job) -> None:
            self.started.append(job.job_id)
            try:
                while not self.gates[job.job_id].wait(0.01):
                    job.checkpoint()
                outcome = "completed"
            except JobCancelled as cancelled:
                outcome = cancelled.kind
            with self.done:
                self.ended[job.job_id] = outcome
                self.done.notify_all()

        return job_id, run

    def wait_ended(self, *job_ids: int) -> None:
        with self.done:
            assert self.done.wait_for(lambda: all(i in self.ended for i in job_ids), TIMEOUT_S)


def test_jobs_over_the_limit_wait_in_order_and_start_as_others_end() -> None:
    runner, recorder = JobRunner({"fit": 1}), Recorder()
    for job_id in (1, 2, 3):
        runner.start("fit", *recorder.work(job_id))  # type: ignore[arg-type]
    first = runner.handle("fit", 1)
    assert first is not None
    assert not first.waiting
    assert [runner.queue_position("fit", i) for i in (1, 2, 3)] == [None, 1, 2]
    runner.handle("fit", 2).request_stop("stopped")  # type: ignore[union-attr]
    assert runner.queue_position("fit", 3) == 1  # a stopped job is not counted
    # Other kinds are not limited.
    runner.start("trial", *recorder.work(9))  # type: ignore[arg-type]
    assert runner.queue_position("trial", 9) is None
    recorder.gates[1].set()
    recorder.gates[3].set()
    recorder.gates[9].set()
    recorder.wait_ended(1, 2, 3, 9)
    assert recorder.ended == {1: "completed", 2: "stopped", 3: "completed", 9: "completed"}
    assert recorder.started.index(2) < recorder.started.index(3)  # first in, first out
    runner.close()


def test_close_stops_running_and_queued_jobs_and_refuses_new_ones() -> None:
    runner, recorder = JobRunner({"fit": 1}), Recorder()
    runner.check_open()
    runner.start("fit", *recorder.work(1))  # type: ignore[arg-type]
    runner.start("fit", *recorder.work(2))  # type: ignore[arg-type]
    runner.close(timeout_s=TIMEOUT_S)
    assert recorder.ended == {1: "shutdown", 2: "shutdown"}
    with pytest.raises(ConflictError, match="shutting down"):
        runner.start("fit", *recorder.work(3))  # type: ignore[arg-type]
    with pytest.raises(ConflictError, match="shutting down"):
        runner.check_open()


def test_the_rig_lease_of_a_job_is_given_back_when_it_ends() -> None:
    rig = in_process_rig().rig
    runner, recorder = JobRunner(), Recorder()
    lease = rig.acquire("collection 4")
    runner.start("collection", *recorder.work(4), lease=lease)  # type: ignore[arg-type]
    job = runner.rig_job()
    assert job is not None
    assert job.label == "collection 4"
    assert rig.status().lease_owner == "collection 4"
    recorder.gates[4].set()
    recorder.wait_ended(4)
    runner.close()
    assert rig.status().lease_owner is None
    assert runner.rig_job() is None
    assert not lease.active


def test_the_dashboard_reads_the_server_states() -> None:
    # frontend/js/states.js is generated from app/states.py (python -m app.states).
    assert states.FRONTEND_MODULE.read_text(encoding="utf-8") == states.javascript_module()
    assert set(states.ACTIVE).isdisjoint(states.FINISHED)
    assert set(states.MODEL_ACTIVE).isdisjoint(states.MODEL_FINISHED)
