"""The 3D view behind the gate: off loopback viser binds loopback only and is reached through
the app at ``/viser/`` (HTTP and websocket), which refuses a client without the session."""

from __future__ import annotations

import threading
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest
import viser
from websockets.exceptions import InvalidStatus
from websockets.sync.client import connect

from app.cli.serve import ServedApp, listening_url
from app.security.sessions import SESSION_COOKIE
from app.viz.live import LiveView
from tests.app.conftest import make_settings
from tests.app.served import start_in_thread

TOKEN = "viser-gate-token"
SUBPROTOCOL = f"viser-v{viser.__version__}"


def serve(settings_dir: Path, **overrides: object) -> tuple[ServedApp, threading.Thread]:
    served = ServedApp(
        make_settings(settings_dir, port=0, viz=True, viz_port=0, **overrides),
        log_level="warning",
    )
    thread = start_in_thread(served.server, served.run)
    return served, thread


@pytest.fixture
def gated(tmp_path: Path) -> Iterator[ServedApp]:
    """Served on 127.0.0.1 with reads locked, as off loopback (no network interface needed)."""
    served, thread = serve(tmp_path, api_token=TOKEN, require_auth_for_reads=True)
    try:
        yield served
    finally:
        served.server.should_exit = True
        thread.join(timeout=30)


def open_ws(url: str, headers: dict[str, str] | None = None) -> None:
    """Open the websocket with viser's subprotocol and close it again."""
    connect(url, subprotocols=[SUBPROTOCOL], additional_headers=headers, open_timeout=10).close()  # type: ignore[list-item]


def sign_in(base: str) -> str:
    response = httpx.post(f"{base}/api/v1/session", json={"token": TOKEN}, timeout=30)
    assert response.status_code == 200, response.text
    return response.cookies[SESSION_COOKIE]


def test_view_binds_loopback_even_when_the_app_does_not() -> None:
    live = LiveView("0.0.0.0", 0)
    try:
        assert live.view.host == "127.0.0.1"
    finally:
        live.close()


def test_the_proxy_refuses_without_the_session_and_serves_with_it(gated: ServedApp) -> None:
    assert gated.live is not None
    view = gated.live.view
    base = listening_url(gated.server, "127.0.0.1")
    ws_url = base.replace("http://", "ws://") + "/viser"
    # Without the session: HTTP 401, and the websocket handshake is refused (403).
    assert httpx.get(f"{base}/viser/", timeout=30).status_code == 401
    assert httpx.get(f"{base}/api/v1/viz", timeout=30).status_code == 401
    with pytest.raises(InvalidStatus) as refused:
        open_ws(ws_url)
    assert refused.value.response.status_code == 403
    assert view.n_clients == 0
    with pytest.raises(InvalidStatus):
        open_ws(ws_url, {"Cookie": f"{SESSION_COOKIE}=forged"})

    cookie = sign_in(base)
    cookies = {SESSION_COOKIE: cookie}
    info = httpx.get(f"{base}/api/v1/viz", cookies=cookies, timeout=30).json()
    assert info["path"] == "viser/"
    page = httpx.get(f"{base}/viser/", cookies=cookies, timeout=30)
    assert page.status_code == 200
    direct = httpx.get(f"http://127.0.0.1:{view.port}/", timeout=30)
    assert page.content == direct.content  # the viser client, as viser serves it
    # The websocket with the session (and the page's own Origin): viser's scene arrives (viser
    # counts a client once its browser sends a camera; the browser test sees that).
    headers = {"Cookie": f"{SESSION_COOKIE}={cookie}", "Origin": base}
    with connect(
        ws_url,
        subprotocols=[SUBPROTOCOL],  # type: ignore[list-item]
        additional_headers=headers,
        open_timeout=10,
        max_size=None,
    ) as websocket:
        assert websocket.subprotocol == SUBPROTOCOL
        first = websocket.recv(timeout=10)
        assert isinstance(first, bytes)
        assert len(first) > 0
    # Another site's page cannot open it with the cookie (cross-site websocket hijacking).
    evil = {"Cookie": f"{SESSION_COOKIE}={cookie}", "Origin": "http://evil.example"}
    with pytest.raises(InvalidStatus):
        open_ws(ws_url, evil)
    # The token works for scripts too.
    bearer = {"Authorization": f"Bearer {TOKEN}"}
    assert httpx.get(f"{base}/viser/", headers=bearer, timeout=30).status_code == 200


def test_on_loopback_the_dashboard_embeds_the_port_and_the_proxy_also_works(
    tmp_path: Path,
) -> None:
    served, thread = serve(tmp_path)
    try:
        base = listening_url(served.server, "127.0.0.1")
        info = httpx.get(f"{base}/api/v1/viz", timeout=30).json()
        assert info["path"] is None
        assert info["port"] > 0
        assert httpx.get(f"{base}/viser/", timeout=30).status_code == 200
        assert httpx.get(f"{base}/viser", timeout=30, follow_redirects=True).status_code == 200
    finally:
        served.server.should_exit = True
        thread.join(timeout=30)
