"""The event log behind ``GET /events``: persisted, with sequence ids, resumable.

Publishers (request handlers and worker threads) call :meth:`EventBus.publish` after their own
transaction has committed. Every event is stored (the table keeps the newest ``keep``), so a
client reconnecting with ``Last-Event-ID`` gets what it missed, even across a server restart.
Subscribers are async generators in the server's event loop, woken thread-safely.

:meth:`EventBus.close` ends every open stream (and any opened later) after what it has sent, so
a server that is shutting down sees its SSE responses complete instead of having to cancel them
(uvicorn logs each cancelled response as an error with a traceback). The server calls it when
its shutdown begins (:class:`app.cli.serve.GracefulServer`), before it waits for connections.
"""

from __future__ import annotations

import asyncio
import contextlib
import threading
from collections import deque
from collections.abc import AsyncIterator
from dataclasses import dataclass
from typing import Any

from app import crud
from app.db import Database
from app.db.tables import utc_now


@dataclass(frozen=True)
class Event:
    """One event: sequence ``id``, ``type`` (e.g. ``trial.step``), JSON ``data``, ISO ``time``."""

    id: int
    type: str
    data: dict[str, Any]
    time: str

    def payload(self) -> dict[str, Any]:
        """What a client receives as the event's JSON data."""
        return {"id": self.id, "type": self.type, "time": self.time, "data": self.data}


class EventBus:
    """Persist events and fan them out to SSE subscribers.

    Args:
        database: Where events are stored.
        keep: How many events the table keeps for resume.
        recent: How many events are also kept in memory for fast catch-up.
    """

    def __init__(self, database: Database, keep: int = 10_000, recent: int = 1000) -> None:
        self._database = database
        self._keep = keep
        self._lock = threading.Lock()
        self._recent: deque[Event] = deque(maxlen=recent)
        self._waiters: set[tuple[asyncio.AbstractEventLoop, asyncio.Event]] = set()
        self._published = 0
        self._closed = False
        with database.session() as session:
            self._last_id = crud.last_event_id(session)

    @property
    def last_id(self) -> int:
        """Sequence id of the newest event."""
        return self._last_id

    @property
    def closed(self) -> bool:
        """Whether :meth:`close` was called (streams end; events are still stored)."""
        return self._closed

    def close(self) -> None:
        """End the open streams (and any later one) once they are idle. Thread-safe, idempotent.

        Publishing still works (background runs finishing during shutdown are recorded); clients
        catch up with ``Last-Event-ID`` when they reconnect to the next server.
        """
        with self._lock:
            self._closed = True
            waiters = list(self._waiters)
        self._wake(waiters)

    @staticmethod
    def _wake(waiters: list[tuple[asyncio.AbstractEventLoop, asyncio.Event]]) -> None:
        for loop, flag in waiters:
            # RuntimeError: the loop was closed (a client gone at shutdown).
            with contextlib.suppress(RuntimeError):
                loop.call_soon_threadsafe(flag.set)

    def publish(self, type_: str, data: dict[str, Any]) -> Event:
        """Store an event and wake the subscribers. Call outside any open write transaction."""
        now = utc_now()
        with self._lock:
            with self._database.session() as session:
                event_id = crud.add_event(session, type_, data, now)
                self._published += 1
                if self._published % 500 == 0:
                    crud.prune_events(session, self._keep)
            event = Event(id=event_id, type=type_, data=data, time=now.isoformat())
            self._recent.append(event)
            self._last_id = event_id
            waiters = list(self._waiters)
        self._wake(waiters)
        return event

    def after(self, after_id: int, limit: int = 1000) -> list[Event]:
        """Events with id > ``after_id``, oldest first (from memory when possible)."""
        with self._lock:
            recent = list(self._recent)
        if recent and recent[0].id <= after_id + 1:
            return [e for e in recent if e.id > after_id][:limit]
        with self._database.session() as session:
            rows = crud.events_after(session, after_id, limit)
            return [
                Event(id=r.id, type=r.type, data=r.data, time=r.created_at.isoformat())
                for r in rows
            ]

    async def stream(
        self, after_id: int, follow: bool, heartbeat_s: float = 15.0
    ) -> AsyncIterator[Event]:
        """Yield events after ``after_id``; then, if ``follow``, new ones as they come.

        A following stream ends (returns) once the bus is closed and the backlog is sent.
        """
        loop = asyncio.get_running_loop()
        flag = asyncio.Event()
        waiter = (loop, flag)
        with self._lock:
            self._waiters.add(waiter)
        try:
            cursor = after_id
            while True:
                flag.clear()
                batch = await asyncio.to_thread(self.after, cursor)
                for event in batch:
                    cursor = event.id
                    yield event
                if batch and not self._closed:
                    continue
                if not follow or self._closed:
                    return
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(flag.wait(), timeout=heartbeat_s)
        finally:
            with self._lock:
                self._waiters.discard(waiter)
