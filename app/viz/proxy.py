"""The 3D view through the web app: ``/viser/`` forwarded to the viser server on loopback.

viser serves its client (one HTML file) over HTTP and talks to it over a websocket on the same
port, with no login of its own. So the view binds loopback only and the app forwards
``GET /viser/...`` (httpx) and the websocket ``/viser`` (the ``websockets`` client) to it. The
forwarding routes sit behind the app's gate (:mod:`app.security.gate`): off loopback a browser
reaches the view only with a signed-in session (or a script with the token). The client computes
its websocket address from its page address (``ws://host/viser``), so it works under the path.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Callable

import httpx
from starlette.routing import BaseRoute, Mount, Route, WebSocketRoute
from starlette.types import Receive, Scope, Send
from starlette.websockets import WebSocket, WebSocketDisconnect
from websockets.asyncio.client import ClientConnection, connect
from websockets.exceptions import ConnectionClosed
from websockets.typing import Subprotocol

from app.security.gate import VISER_PREFIX

logger = logging.getLogger(__name__)

#: Largest websocket message forwarded from viser (its own limit).
MAX_MESSAGE_BYTES = 50 * 1024 * 1024
#: Seconds to wait for the view's HTTP answer or websocket handshake.
UPSTREAM_TIMEOUT_S = 10.0
#: Request headers forwarded to viser (never the cookie or the token).
FORWARDED_HEADERS = ("accept", "accept-language", "if-none-match", "if-modified-since")


class ViserProxy:
    """An ASGI app forwarding HTTP ``GET``/``HEAD`` and websockets to a viser server.

    Args:
        host: The viser server's (loopback) address.
        port: Gives its port (it is known once the server has started).
    """

    def __init__(self, host: str, port: Callable[[], int]) -> None:
        self._host = f"[{host}]" if ":" in host else host
        self._port = port

    def upstream(self, scheme: str, path: str, query: bytes = b"") -> str:
        """The viser URL of a path below ``/viser``."""
        suffix = f"?{query.decode('latin-1')}" if query else ""
        return f"{scheme}://{self._host}:{self._port()}{path or '/'}{suffix}"

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        path = str(scope["path"])[len(VISER_PREFIX) :]
        if scope["type"] == "websocket":
            await self._websocket(WebSocket(scope, receive, send), path)
        elif scope["type"] == "http":
            await self._http(scope, receive, send, path)

    async def _http(self, scope: Scope, receive: Receive, send: Send, path: str) -> None:
        from starlette.responses import PlainTextResponse, RedirectResponse, Response

        response: Response
        if scope["method"] not in ("GET", "HEAD"):
            response = PlainTextResponse("Method not allowed.", status_code=405)
        elif not path:
            response = RedirectResponse(f"{VISER_PREFIX}/", status_code=307)
        else:
            headers = {
                key.decode("latin-1"): value.decode("latin-1")
                for key, value in scope["headers"]
                if key.decode("latin-1").lower() in FORWARDED_HEADERS
            }
            try:
                async with httpx.AsyncClient(timeout=UPSTREAM_TIMEOUT_S) as client:
                    answer = await client.request(
                        scope["method"],
                        self.upstream("http", path, scope.get("query_string", b"")),
                        headers=headers,
                    )
            except httpx.HTTPError as exc:
                logger.warning("3D view proxy: viser did not answer: %s", exc)
                response = PlainTextResponse("The 3D view is not available.", status_code=502)
            else:
                response = Response(
                    answer.content,
                    status_code=answer.status_code,
                    media_type=answer.headers.get("content-type"),
                    headers={"Cache-Control": "no-store"},
                )
        await response(scope, receive, send)

    async def _websocket(self, websocket: WebSocket, path: str) -> None:
        offered = [Subprotocol(p) for p in websocket.scope.get("subprotocols", [])]
        try:
            upstream = await connect(
                self.upstream("ws", path),
                subprotocols=offered or None,
                max_size=MAX_MESSAGE_BYTES,
                compression=None,
                open_timeout=UPSTREAM_TIMEOUT_S,
            )
        except (OSError, TimeoutError, ConnectionClosed, ValueError) as exc:
            logger.warning("3D view proxy: no websocket to viser: %s", exc)
            await websocket.close(code=1011)
            return
        async with upstream:
            await websocket.accept(subprotocol=upstream.subprotocol)
            await _pump(websocket, upstream)


async def _pump(websocket: WebSocket, upstream: ClientConnection) -> None:
    """Forward messages both ways until either side closes; then close the other."""

    async def to_upstream() -> None:
        while True:
            message = await websocket.receive()
            if message["type"] == "websocket.disconnect":
                return
            data = message.get("bytes")
            await upstream.send(data if data is not None else message.get("text", ""))

    async def to_client() -> None:
        async for data in upstream:
            if isinstance(data, bytes):
                await websocket.send_bytes(data)
            else:
                await websocket.send_text(data)

    tasks = [asyncio.create_task(to_upstream()), asyncio.create_task(to_client())]
    try:
        await asyncio.wait(tasks, return_when=asyncio.FIRST_COMPLETED)
    finally:
        for task in tasks:
            task.cancel()
        for task in tasks:
            with contextlib.suppress(
                asyncio.CancelledError, ConnectionClosed, WebSocketDisconnect, RuntimeError
            ):
                await task
    code = upstream.close_code
    with contextlib.suppress(RuntimeError, WebSocketDisconnect):
        await websocket.close(code=code if code not in (None, 1005, 1006) else 1000)


def proxy_routes(proxy: ViserProxy) -> list[BaseRoute]:
    """The routes forwarding ``/viser`` (websocket), ``/viser`` (HTTP: a redirect to the slash)
    and everything below ``/viser/`` (HTTP and websocket)."""
    return [
        WebSocketRoute(VISER_PREFIX, proxy),
        Route(VISER_PREFIX, proxy, methods=["GET", "HEAD"], include_in_schema=False),
        Mount(VISER_PREFIX, app=proxy),
    ]
