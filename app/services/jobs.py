"""The job runner: every piece of background work of the server (fits, collections, trials,
evaluations) runs here, and nowhere else.

A job is a thread running a *work function* ``work(job)`` that owns its records: it writes the
job's state to the database and publishes its events; the runner only starts, limits, stops and
waits. The work function passes :meth:`Job.checkpoint` between its steps, where a pause holds it
and a stop ends it with :class:`JobCancelled` (the step in flight is finished and recorded
first). Kinds may be given a limit of jobs running at once (fits: the server's
``max_concurrent_fits``); a job over the limit waits in a first-in, first-out queue
(:meth:`JobRunner.queue_position`) and starts when a job of its kind ends.

A job that drives the rig is started with the rig's lease (:meth:`app.services.rig.RigService.take`,
the one record of who holds the rig); the runner gives the lease back when the work function
returns, whatever happened, and :meth:`JobRunner.rig_job` names the job holding it (for the
emergency stop).

At shutdown (:meth:`JobRunner.close`) every job, running or queued, is stopped with kind
``shutdown``; its work function records it ``failed`` with reason :data:`INTERRUPTED`, keeping
what it recorded. The run states are :mod:`app.states`.
"""

from __future__ import annotations

import logging
import threading
from collections import deque
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager, suppress
from typing import Literal

from sqlalchemy.orm import Session

from app.errors import AppError, ConflictError
from app.states import INTERRUPTED, Action
from hardware.errors import HardwareError
from hardware.rig import RigLease

__all__ = ["INTERRUPTED", "Job", "JobCancelled", "JobKind", "JobRunner", "StopKind"]

logger = logging.getLogger(__name__)

JobKind = Literal["fit", "trial", "collection", "evaluation"]
StopKind = Literal["stopped", "aborted", "shutdown"]


class JobCancelled(Exception):  # noqa: N818 - a control-flow signal, not an error
    """Raised at a checkpoint of a job that was stopped, aborted or shut down.

    Attributes:
        kind: ``stopped``, ``aborted`` or ``shutdown``.
    """

    def __init__(self, kind: StopKind) -> None:
        super().__init__(kind)
        self.kind: StopKind = kind


class Job:
    """Control of one background job, handed to its work function.

    Args:
        kind: What the job does.
        job_id: The id of its row (model, trial, run or evaluation).
        lease: The rig's lease when the job drives the rig (given back when the job ends).
    """

    def __init__(self, kind: JobKind, job_id: int, lease: RigLease | None = None) -> None:
        self.kind: JobKind = kind
        self.job_id = job_id
        self.lease = lease
        self._condition = threading.Condition()
        self._paused = False
        self._stop: StopKind | None = None
        self.thread: threading.Thread | None = None

    @property
    def label(self) -> str:
        """``trial 3``, ``collection 5``, ``fit 2``: how the job is named to others."""
        return f"{self.kind} {self.job_id}"

    @property
    def waiting(self) -> bool:
        """Whether the job waits in its kind's queue (its work has not started)."""
        return self.thread is None

    @property
    def stop_requested(self) -> StopKind | None:
        """Why the job was asked to end, if it was."""
        return self._stop

    def pause(self) -> None:
        """Hold the job at its next checkpoint."""
        with self._condition:
            self._paused = True

    def resume(self) -> None:
        """Let a paused job continue."""
        with self._condition:
            self._paused = False
            self._condition.notify_all()

    def request_stop(self, kind: StopKind) -> None:
        """End the job at its next checkpoint (the first request's kind is kept)."""
        with self._condition:
            if self._stop is None:
                self._stop = kind
            self._condition.notify_all()

    def control(self, action: Action) -> None:
        """Carry out an operator's request: pause, resume, stop (``stopped``) or abort
        (``aborted``)."""
        if action == "pause":
            self.pause()
        elif action == "resume":
            self.resume()
        else:
            self.request_stop("stopped" if action == "stop" else "aborted")

    def checkpoint(self) -> None:
        """Block while paused; raise :class:`JobCancelled` once a stop was requested."""
        with self._condition:
            while self._paused and self._stop is None:
                self._condition.wait()
            if self._stop is not None:
                raise JobCancelled(self._stop)

    def sleep(self, seconds: float) -> None:
        """Wait ``seconds`` (woken early by a stop), then pass a checkpoint."""
        if seconds > 0:
            with self._condition:
                self._condition.wait_for(lambda: self._stop is not None, timeout=seconds)
        self.checkpoint()


class JobRunner:
    """Runs background jobs in threads, at most ``limits[kind]`` of a kind at once.

    Args:
        limits: Most jobs of a kind running at once (≥ 1); kinds not named are not limited.
    """

    def __init__(self, limits: Mapping[JobKind, int] | None = None) -> None:
        self._limits = dict(limits or {})
        for kind, limit in self._limits.items():
            if limit < 1:
                raise ValueError(f"limits[{kind!r}]: expected at least 1, received {limit}.")
        self._lock = threading.Lock()
        self._jobs: dict[tuple[str, int], Job] = {}
        self._running: dict[str, int] = {}
        self._queues: dict[str, deque[tuple[Job, Callable[[Job], None]]]] = {}
        self._locks: dict[tuple[str, int], threading.RLock] = {}
        self._closing = False

    @contextmanager
    def run_lock(self, kind: JobKind, job_id: int) -> Iterator[None]:
        """The lock that serialises a job's steps and the control requests made to it."""
        with self._lock:
            lock = self._locks.setdefault((kind, job_id), threading.RLock())
        with lock:
            yield

    def handle(self, kind: JobKind, job_id: int) -> Job | None:
        """The live job (running or queued in this process), if any."""
        with self._lock:
            return self._jobs.get((kind, job_id))

    def queue_position(self, kind: JobKind, job_id: int) -> int | None:
        """1 for the next job of its kind to start, 2 for the one after…; ``None`` when the job
        is not waiting (running, ended, or not of this process). Stopped jobs are not counted."""
        with self._lock:
            waiting = [job for job, _ in self._queues.get(kind, ()) if job.stop_requested is None]
        for position, job in enumerate(waiting, start=1):
            if job.job_id == job_id:
                return position
        return None

    def rig_job(self) -> Job | None:
        """The job holding the rig's lease, if any."""
        with self._lock:
            for job in self._jobs.values():
                if job.lease is not None and job.lease.active:
                    return job
        return None

    def check_open(self) -> None:
        """Refuse new work once the runner is closing (checked before a job's row is stored).

        Raises:
            ConflictError: (409) the server is shutting down.
        """
        with self._lock:
            if self._closing:
                raise ConflictError("The server is shutting down.", current_state="shutdown")

    def start(
        self,
        kind: JobKind,
        job_id: int,
        work: Callable[[Job], None],
        lease: RigLease | None = None,
    ) -> Job:
        """Run ``work(job)`` in a thread now, or queue it while its kind is at its limit.

        Args:
            kind: What the job does.
            job_id: The id of its row.
            work: The work function; it records the job's end itself.
            lease: The rig's lease, for a job that drives the rig (released when it ends, or
                here if the job cannot start).

        Raises:
            ConflictError: The server is shutting down.
        """
        job = Job(kind, job_id, lease)
        with self._lock:
            if self._closing:
                self._give_back(job)
                raise ConflictError("The server is shutting down.", current_state="shutdown")
            self._jobs[(kind, job_id)] = job
            limit = self._limits.get(kind)
            if limit is not None and self._running.get(kind, 0) >= limit:
                self._queues.setdefault(kind, deque()).append((job, work))
                return job
            self._launch(job, work)
        return job

    def commit_and_start(
        self,
        session: Session,
        kind: JobKind,
        job_id: int,
        work: Callable[[Job], None],
        *,
        announce: Callable[[], None],
        fail: Callable[[str], None],
        take_rig: Callable[[str], RigLease] | None = None,
    ) -> Job:
        """Keep a new job's row (added to ``session``, not yet committed) and start the job.

        A job that drives the rig takes its lease first, as ``kind job_id``: if the rig is
        refused, the row is rolled back (nothing of the refused job is kept). Then the row is
        committed and announced, and the job started; if the start is refused (the server is
        shutting down), the job's row is failed ("could not start: …") before the error goes on.

        Args:
            session: The request's session holding the job's new row.
            kind: What the job does.
            job_id: The id of its row.
            work: The work function.
            announce: Publishes the committed row.
            fail: Ends the row as failed with the reason given.
            take_rig: Takes the rig's lease for an owner (:meth:`app.services.rig.RigService.take`),
                for a job that drives the rig.

        Raises:
            AppError: The rig's lease was refused (409, 503), or the server is shutting down.
        """
        lease = None
        if take_rig is not None:
            try:
                lease = take_rig(f"{kind} {job_id}")
            except AppError:
                session.rollback()
                raise
        session.commit()
        announce()
        try:
            return self.start(kind, job_id, work, lease=lease)
        except AppError as exc:
            fail(f"could not start: {exc.message}")
            raise

    def _launch(self, job: Job, work: Callable[[Job], None]) -> None:
        """Start ``job``'s thread (the caller holds ``self._lock``)."""
        self._running[job.kind] = self._running.get(job.kind, 0) + 1

        def main() -> None:
            try:
                work(job)
            except Exception:  # the work function records failures; this is a last resort
                logger.exception("%s crashed", job.label)
            finally:
                self._give_back(job)
                with self._lock:
                    self._jobs.pop((job.kind, job.job_id), None)
                    self._running[job.kind] -= 1
                    queue = self._queues.get(job.kind)
                    if queue:
                        self._launch(*queue.popleft())

        job.thread = threading.Thread(target=main, name=job.label, daemon=True)
        job.thread.start()

    @staticmethod
    def _give_back(job: Job) -> None:
        if job.lease is not None:
            with suppress(HardwareError):
                job.lease.release()

    def close(self, timeout_s: float = 30.0) -> None:
        """Stop every job (kind ``shutdown``), start the queued ones so that each records its
        interruption, and wait for them all."""
        with self._lock:
            self._closing = True
            jobs = list(self._jobs.values())
            for job in jobs:
                job.request_stop("shutdown")
            for queue in self._queues.values():
                while queue:
                    self._launch(*queue.popleft())
        for job in jobs:
            if job.thread is not None:
                job.thread.join(timeout=timeout_s)
