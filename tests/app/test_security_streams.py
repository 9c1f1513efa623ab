"""Open connections end with their session: after a sign-out the event stream and the 3D view's
websocket, opened while signed in, send nothing more and close (a real uvicorn server)."""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest
import viser
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import ClientConnection, connect

from app.cli.serve import ServedApp, listening_url
from app.security.sessions import SESSION_COOKIE
from tests.app.conftest import make_settings
from tests.app.served import LogRecords, start_in_thread

TOKEN = "stream-gate-token"
BEARER = {"Authorization": f"Bearer {TOKEN}"}
CSRF = {"X-Requested-With": "activetouch"}


@pytest.fixture
def served(tmp_path: Path) -> Iterator[tuple[ServedApp, LogRecords]]:
    settings = make_settings(
        tmp_path, port=0, viz=True, viz_port=0, api_token=TOKEN, require_auth_for_reads=True
    )
    served = ServedApp(settings, log_level="warning")
    errors = LogRecords()
    logging.getLogger("uvicorn.error").addHandler(errors)
    thread = start_in_thread(served.server, served.run)
    try:
        yield served, errors
    finally:
        served.server.should_exit = True
        thread.join(timeout=30)
        logging.getLogger("uvicorn.error").removeHandler(errors)


def sign_in(base: str) -> str:
    response = httpx.post(f"{base}/api/v1/session", json={"token": TOKEN}, timeout=30)
    assert response.status_code == 200
    return response.cookies[SESSION_COOKIE]


def sign_out(base: str, session_id: str) -> None:
    response = httpx.delete(
        f"{base}/api/v1/session", cookies={SESSION_COOKIE: session_id}, headers=CSRF, timeout=30
    )
    assert response.status_code == 204


def drain(websocket: ClientConnection) -> None:
    """Receive until the connection closes (or 10 s pass without a message)."""
    while True:
        websocket.recv(timeout=10)


def test_the_event_stream_ends_at_sign_out(served: tuple[ServedApp, LogRecords]) -> None:
    app, errors = served
    base = listening_url(app.server, "127.0.0.1")
    session_id = sign_in(base)
    received: list[str] = []
    ended = threading.Event()

    def read() -> None:
        with httpx.stream(
            "GET", f"{base}/api/v1/events", cookies={SESSION_COOKIE: session_id},
            timeout=httpx.Timeout(60, read=60),
        ) as response:  # fmt: skip
            assert response.status_code == 200
            for line in response.iter_lines():
                if line.startswith("data:"):
                    received.append(line)
        ended.set()

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    time.sleep(0.5)  # the stream is open (it sends only new events)
    assert httpx.post(f"{base}/api/v1/rig/estop", headers=BEARER, timeout=30).status_code == 200
    deadline = time.monotonic() + 20
    while not received:
        assert time.monotonic() < deadline, "the signed-in stream got no event"
        time.sleep(0.05)
    seen = len(received)
    sign_out(base, session_id)
    assert not ended.is_set()  # still open: nothing was due
    assert httpx.post(f"{base}/api/v1/rig/connect", headers=BEARER, timeout=30).status_code < 500
    assert ended.wait(timeout=20), "the stream stayed open after the sign-out"
    assert len(received) == seen  # the event after the sign-out was not sent
    assert not [line for line in errors.lines if "Exception" in line], errors.lines


def test_the_3d_view_websocket_ends_at_sign_out(served: tuple[ServedApp, LogRecords]) -> None:
    app, errors = served
    assert app.live is not None
    base = listening_url(app.server, "127.0.0.1")
    session_id = sign_in(base)
    headers = {"Cookie": f"{SESSION_COOKIE}={session_id}", "Origin": base}
    with connect(
        base.replace("http://", "ws://") + "/viser",
        subprotocols=[f"viser-v{viser.__version__}"],  # type: ignore[list-item]
        additional_headers=headers,
        open_timeout=10,
        max_size=None,
    ) as websocket:
        assert websocket.recv(timeout=10)
        while True:  # the initial scene, until it goes quiet
            try:
                websocket.recv(timeout=1)
            except TimeoutError:
                break
        sign_out(base, session_id)
        app.live.view.clear_trial()  # the view changes: viser sends, the proxy must not
        with pytest.raises(ConnectionClosed) as closed:
            drain(websocket)
        assert closed.value.rcvd is not None
        assert closed.value.rcvd.code == 1008
    assert not [line for line in errors.lines if "Exception" in line], errors.lines
