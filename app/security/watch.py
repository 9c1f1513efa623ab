"""Open streams end with their session: the event stream and the 3D view's websocket.

The gate checks a session when a request arrives; an event stream or a websocket then stays open.
:func:`watch_session` wraps such a connection so that, after a sign-out (or the session's
expiry), nothing more is sent on it: before each chunk (the event stream also sends a keep-alive
comment every few seconds) the session is checked, and once it is gone the response is ended
cleanly (the last, empty chunk; or a websocket close 1008) and the application is told that the
client has disconnected, so it stops.
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable

from starlette.types import ASGIApp, Message, Receive, Scope, Send

#: Close code of a websocket whose session ended (policy violation).
SESSION_ENDED_CODE = 1008


async def watch_session(
    app: ASGIApp, scope: Scope, receive: Receive, send: Send, alive: Callable[[], bool]
) -> None:
    """Run ``app`` on an HTTP stream or websocket that ends as soon as ``alive()`` is false."""
    websocket = scope["type"] == "websocket"
    ended = asyncio.Event()
    finished = False
    pending: asyncio.Future[Message] | None = None
    lock = asyncio.Lock()

    async def end() -> None:
        nonlocal finished
        finished = True
        ended.set()
        if websocket:
            await send({"type": "websocket.close", "code": SESSION_ENDED_CODE})
        else:
            await send({"type": "http.response.body", "body": b"", "more_body": False})

    async def guarded_send(message: Message) -> None:
        nonlocal finished
        async with lock:
            if finished:
                return  # the response was ended for the app: drop what it still sends
            carries_data = message["type"] == "websocket.send" or (
                message["type"] == "http.response.body" and message.get("body")
            )
            if carries_data and not alive():
                await end()
                return
            if message["type"] == "websocket.close" or (
                message["type"] == "http.response.body" and not message.get("more_body", False)
            ):
                finished = True
            await send(message)

    async def watched_receive() -> Message:
        nonlocal pending
        if ended.is_set():
            return _disconnect(websocket)
        if pending is None:
            pending = asyncio.ensure_future(receive())
        waiter: asyncio.Future[object] = asyncio.ensure_future(ended.wait())
        racing: set[asyncio.Future[object]] = {pending, waiter}  # type: ignore[arg-type]
        try:
            await asyncio.wait(racing, return_when=asyncio.FIRST_COMPLETED)
        finally:
            waiter.cancel()
        if pending.done():
            message, pending = pending.result(), None
            return message
        return _disconnect(websocket)

    try:
        await app(scope, watched_receive, guarded_send)
    finally:
        if pending is not None:
            pending.cancel()


def _disconnect(websocket: bool) -> Message:
    if websocket:
        return {"type": "websocket.disconnect", "code": SESSION_ENDED_CODE}
    return {"type": "http.disconnect"}
