"""The run manager: background runs (simulated/rig trials, collections) and the rig's one owner.

Each run is a thread driven through a :class:`RunHandle` (pause, resume, stop, abort). Steps are
recorded under the run's lock, so a control request and a step never interleave. Only one run may
hold the rig at a time; a second gets a 409 naming the holder.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Literal

from app.errors import ConflictError

logger = logging.getLogger(__name__)

RunKind = Literal["trial", "collection"]
StopKind = Literal["stopped", "aborted", "shutdown"]


class RunCancelled(Exception):  # noqa: N818 - a control-flow signal, not an error
    """Raised at a checkpoint of a run that was stopped, aborted or shut down.

    Attributes:
        kind: ``stopped``, ``aborted`` or ``shutdown``.
    """

    def __init__(self, kind: StopKind) -> None:
        super().__init__(kind)
        self.kind: StopKind = kind


class RunHandle:
    """Control of one background run.

    Args:
        kind: ``trial`` or ``collection``.
        run_id: The row id.
        holds_rig: Whether the run owns the rig while it is active.
    """

    def __init__(self, kind: RunKind, run_id: int, holds_rig: bool) -> None:
        self.kind = kind
        self.run_id = run_id
        self.holds_rig = holds_rig
        self._condition = threading.Condition()
        self._paused = False
        self._stop: StopKind | None = None
        self.thread: threading.Thread | None = None

    @property
    def label(self) -> str:
        """``trial 3``, ``collection 5``."""
        return f"{self.kind} {self.run_id}"

    @property
    def stop_requested(self) -> StopKind | None:
        """Why the run was asked to end, if it was."""
        return self._stop

    def pause(self) -> None:
        """Hold the run at its next checkpoint."""
        with self._condition:
            self._paused = True

    def resume(self) -> None:
        """Let a paused run continue."""
        with self._condition:
            self._paused = False
            self._condition.notify_all()

    def request_stop(self, kind: StopKind) -> None:
        """End the run at its next checkpoint (the step in flight is finished and recorded)."""
        with self._condition:
            if self._stop is None:
                self._stop = kind
            self._condition.notify_all()

    def checkpoint(self) -> None:
        """Block while paused; raise :class:`RunCancelled` once a stop was requested."""
        with self._condition:
            while self._paused and self._stop is None:
                self._condition.wait()
            if self._stop is not None:
                raise RunCancelled(self._stop)

    def sleep(self, seconds: float) -> None:
        """Wait ``seconds`` (woken early by a stop), then pass a checkpoint."""
        if seconds > 0:
            with self._condition:
                self._condition.wait_for(lambda: self._stop is not None, timeout=seconds)
        self.checkpoint()


class RunManager:
    """Owns background runs, their locks and the rig."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._handles: dict[tuple[str, int], RunHandle] = {}
        self._locks: dict[tuple[str, int], threading.RLock] = {}
        self._rig_holder: str | None = None
        self._closing = False

    @property
    def rig_holder(self) -> str | None:
        """Label of the run (or operation) holding the rig, if any."""
        return self._rig_holder

    @contextmanager
    def run_lock(self, kind: str, run_id: int) -> Iterator[None]:
        """The lock that serialises a run's steps and control requests."""
        with self._lock:
            lock = self._locks.setdefault((kind, run_id), threading.RLock())
        with lock:
            yield

    def handle(self, kind: str, run_id: int) -> RunHandle | None:
        """The live handle of a run, if it is running in this process."""
        with self._lock:
            return self._handles.get((kind, run_id))

    def reserve_rig(self, label: str) -> None:
        """Take the rig for ``label``.

        Raises:
            ConflictError: Another run holds it (``held_by`` names it).
        """
        with self._lock:
            if self._rig_holder is not None and self._rig_holder != label:
                raise ConflictError(
                    f"The rig is in use by {self._rig_holder}; stop it or wait for it to finish.",
                    held_by=self._rig_holder,
                )
            self._rig_holder = label

    def release_rig(self, label: str) -> None:
        """Give the rig back (no-op unless ``label`` holds it)."""
        with self._lock:
            if self._rig_holder == label:
                self._rig_holder = None

    def start(
        self,
        kind: RunKind,
        run_id: int,
        work: Callable[[RunHandle], None],
        holds_rig: bool,
    ) -> RunHandle:
        """Start ``work(handle)`` in a thread; reserve the rig first when ``holds_rig``.

        Raises:
            ConflictError: The rig is held by another run, or the server is shutting down.
        """
        handle = RunHandle(kind, run_id, holds_rig)
        if holds_rig:
            self.reserve_rig(handle.label)
        with self._lock:
            if self._closing:
                if holds_rig:
                    self._rig_holder = None
                raise ConflictError("The server is shutting down.", current_state="shutdown")
            self._handles[(kind, run_id)] = handle

        def main() -> None:
            try:
                work(handle)
            except Exception:  # the work function records failures; this is a last resort
                logger.exception("%s crashed", handle.label)
            finally:
                with self._lock:
                    self._handles.pop((kind, run_id), None)
                    if self._rig_holder == handle.label:
                        self._rig_holder = None

        handle.thread = threading.Thread(target=main, name=handle.label, daemon=True)
        handle.thread.start()
        return handle

    def close(self, timeout_s: float = 10.0) -> None:
        """Ask every run to end (``shutdown``) and wait for the threads."""
        with self._lock:
            self._closing = True
            handles = list(self._handles.values())
        for handle in handles:
            handle.request_stop("shutdown")
        for handle in handles:
            if handle.thread is not None:
                handle.thread.join(timeout=timeout_s)
