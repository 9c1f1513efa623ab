"""The request audit: every mutating ``/api/v1`` request recorded in the database.

:class:`AuditMiddleware` notes each ``POST``/``PUT``/``PATCH``/``DELETE`` under the API once its
response is complete (refusals by the gate included) and hands it to an :class:`AuditRecorder`,
which writes in batches from its own thread. The request never waits for the database and is
never failed by it: a full queue or a failed write drops the entry and logs it (an e-stop stays
as immediate as before).
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from datetime import UTC, datetime
from typing import Any

from starlette.types import ASGIApp, Message, Receive, Scope, Send

from app import crud
from app.db import Database
from app.security.gate import MUTATING_METHODS, identity_of, is_under

logger = logging.getLogger(__name__)

#: Entries waiting to be written at most; beyond, new ones are dropped (and counted).
MAX_PENDING = 10_000
#: Entries written per transaction at most.
BATCH_SIZE = 200
#: Seconds the writer gathers entries before a transaction.
GATHER_S = 0.25


@dataclass(frozen=True)
class AuditEntry:
    """One recorded request (the columns of :class:`app.db.tables.RequestAudit`)."""

    time: datetime
    client: str | None
    method: str
    path: str
    route: str | None
    status_code: int
    authenticated: bool
    auth_method: str | None
    duration_ms: float


Writer = Callable[[list[dict[str, Any]]], None]


#: Rows kept in the table; older ones are deleted (refused requests are recorded too, so a flood
#: of them must not fill the disk).
KEEP_ROWS = 200_000
#: Rows written between two prunings.
PRUNE_EVERY = 1000


def database_writer(database: Database, keep: int = KEEP_ROWS) -> Writer:
    """A writer that inserts entries into ``database`` in one transaction and, every
    :data:`PRUNE_EVERY` rows, keeps only the newest ``keep``."""
    written = 0

    def write(rows: list[dict[str, Any]]) -> None:
        nonlocal written
        with database.session() as session:
            crud.add_request_audits(session, rows)
            written += len(rows)
            if written >= PRUNE_EVERY:
                written = 0
                crud.prune_request_audits(session, keep)

    return write


class AuditRecorder:
    """A bounded queue of entries and the thread that writes them.

    Args:
        write: Stores a batch of rows (:func:`database_writer`).
        max_pending: Queue bound.
        gather_s: How long the writer gathers entries after the first before it writes.
    """

    def __init__(
        self, write: Writer, max_pending: int = MAX_PENDING, gather_s: float = GATHER_S
    ) -> None:
        self._write = write
        self._gather_s = gather_s
        self._queue: queue.Queue[AuditEntry | None] = queue.Queue(maxsize=max_pending)
        self._thread = threading.Thread(target=self._run, name="request-audit", daemon=True)
        self.dropped = 0
        self.failed = 0
        self._closed = False

    def start(self) -> AuditRecorder:
        """Start the writer thread."""
        self._thread.start()
        return self

    def submit(self, entry: AuditEntry) -> bool:
        """Queue an entry without waiting; returns whether it was queued."""
        if self._closed:
            return False
        try:
            self._queue.put_nowait(entry)
        except queue.Full:
            self.dropped += 1
            if self.dropped == 1 or self.dropped % 1000 == 0:
                logger.warning("request audit: queue full, %d entries dropped", self.dropped)
            return False
        return True

    def flush(self, timeout_s: float = 5.0) -> bool:
        """Wait until every queued entry is written (or failed); returns whether it was."""
        deadline = time.monotonic() + timeout_s
        while self._queue.unfinished_tasks:
            if time.monotonic() > deadline or not self._thread.is_alive():
                return False
            time.sleep(0.005)
        return True

    def close(self, timeout_s: float = 5.0) -> None:
        """Write what is queued, then stop the thread (idempotent)."""
        if self._closed:
            return
        self._closed = True
        if self._thread.is_alive():
            self._queue.put(None)
            self._thread.join(timeout=timeout_s)

    def _run(self) -> None:
        while True:
            first = self._queue.get()
            batch = [first]
            # Gather for a moment: fewer, larger transactions leave SQLite's write lock to the
            # requests themselves (an e-stop's own event, say) most of the time.
            deadline = time.monotonic() + self._gather_s
            while len(batch) < BATCH_SIZE and batch[-1] is not None:
                try:
                    batch.append(self._queue.get(timeout=max(0.0, deadline - time.monotonic())))
                except queue.Empty:
                    break
            entries = [entry for entry in batch if entry is not None]
            try:
                if entries:
                    self._write([asdict(entry) for entry in entries])
            except Exception:
                self.failed += len(entries)
                logger.exception("request audit: %d entries could not be written", len(entries))
            finally:
                for _ in batch:
                    self._queue.task_done()
            if len(entries) < len(batch):
                return


class AuditMiddleware:
    """ASGI middleware recording every mutating request under ``api_prefix``.

    The recorder is looked up on the app (``app.state.audit``, set by the lifespan); while
    there is none (start-up, tests without a lifespan) nothing is recorded.
    """

    def __init__(self, app: ASGIApp, api_prefix: str) -> None:
        self.app = app
        self.api_prefix = api_prefix

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if (
            scope["type"] != "http"
            or scope["method"] not in MUTATING_METHODS
            or not is_under(scope["path"], self.api_prefix)
        ):
            await self.app(scope, receive, send)
            return
        started_at = datetime.now(UTC)
        started = time.perf_counter()
        status = 500  # if the app fails before answering, the server answers 500

        async def noting_send(message: Message) -> None:
            nonlocal status
            if message["type"] == "http.response.start":
                status = int(message["status"])
            await send(message)

        try:
            await self.app(scope, receive, noting_send)
        finally:
            self._record(scope, status, started_at, time.perf_counter() - started)

    def _route_of(self, scope: Scope) -> str | None:
        """The matched route's template, with the API prefix (routes of included routers may
        carry only their own part)."""
        template = str(getattr(scope.get("route"), "path", "") or "")
        if not template:
            return None
        if not is_under(template, self.api_prefix):
            template = self.api_prefix + template
        return template[:200]

    def _record(self, scope: Scope, status: int, started_at: datetime, elapsed_s: float) -> None:
        try:
            app = scope.get("app")
            recorder = getattr(getattr(app, "state", None), "audit", None)
            if not isinstance(recorder, AuditRecorder):
                return
            identity = identity_of(scope.get("state") or {})
            client = scope.get("client")
            recorder.submit(
                AuditEntry(
                    time=started_at,
                    client=str(client[0])[:100] if client else None,
                    method=str(scope["method"]),
                    path=str(scope["path"])[:500],
                    route=self._route_of(scope),
                    status_code=status,
                    authenticated=identity.authenticated,
                    auth_method=identity.method,
                    duration_ms=elapsed_s * 1000.0,
                )
            )
        except Exception:  # recording must never break the request it records
            logger.exception("request audit: could not record %s", scope.get("path"))
