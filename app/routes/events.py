"""``GET /events``: server-sent events with sequence ids; resume with ``Last-Event-ID``."""

from __future__ import annotations

from collections.abc import AsyncIterator
from typing import Annotated

from fastapi import APIRouter, Depends, Header, Query
from fastapi.sse import EventSourceResponse, ServerSentEvent

from app.deps import ContextDep
from app.errors import BadInputError

router = APIRouter(tags=["events"])


def _start_id(
    context: ContextDep,
    last_event_id: Annotated[str | None, Header()] = None,
    after: Annotated[int | None, Query(ge=0, le=2**63 - 1)] = None,
) -> int:
    """Where the stream starts: ``Last-Event-ID``, else ``after``, else the newest event."""
    if last_event_id is not None and last_event_id.strip():
        try:
            value = int(last_event_id.strip())
        except ValueError:
            raise BadInputError(
                f"Last-Event-ID: expected an event sequence number, received {last_event_id!r}.",
                field="Last-Event-ID",
            ) from None
        if not 0 <= value < 2**63:
            raise BadInputError(
                "Last-Event-ID: must be a non-negative 64-bit integer.", field="Last-Event-ID"
            )
        return value
    if after is not None:
        return after
    return context.events.last_id


@router.get("/events", response_class=EventSourceResponse)
async def stream_events(
    context: ContextDep,
    start: Annotated[int, Depends(_start_id)],
    follow: bool = True,
) -> AsyncIterator[ServerSentEvent]:
    """Events as ``text/event-stream``; each ``data`` is ``{"id", "type", "time", "data"}``.

    Starts after ``Last-Event-ID`` (header, as browsers send it on reconnect) or ``after``
    (query); with neither, only new events are sent. ``follow=false`` ends the stream once the
    backlog is sent (for scripts and tests).
    """
    async for event in context.events.stream(start, follow=follow):
        yield ServerSentEvent(data=event.payload(), id=str(event.id))
