"""No token in logs: the server's access log (uvicorn, level info) over a sign-in, reads, the
event stream, a change and a sign-out shows the paths, never the token or the session id."""

from __future__ import annotations

import logging
from pathlib import Path

import httpx

from app.cli.serve import ServedApp, listening_url
from app.security.sessions import SESSION_COOKIE
from tests.app.conftest import make_settings
from tests.app.served import LogRecords, start_in_thread

TOKEN = "log-probe-token-5d1e9a"


def test_access_log_never_shows_the_token_or_the_session(tmp_path: Path) -> None:
    settings = make_settings(
        tmp_path, port=0, viz=False, api_token=TOKEN, require_auth_for_reads=True
    )
    served = ServedApp(settings, log_level="info")
    collect = LogRecords()
    loggers = [logging.getLogger(name) for name in ("uvicorn.access", "uvicorn.error", "app")]
    for logger in loggers:
        logger.addHandler(collect)
    thread = start_in_thread(served.server, served.run)
    try:
        base = listening_url(served.server, "127.0.0.1")
        with httpx.Client(base_url=base, timeout=30) as client:
            assert client.post("/api/v1/session", json={"token": "wrong"}).status_code == 401
            assert client.post("/api/v1/session", json={"token": TOKEN}).status_code == 200
            session_id = client.cookies[SESSION_COOKIE]
            assert client.get("/api/v1/trials").status_code == 200
            assert client.get("/api/v1/events", params={"follow": "false"}).status_code == 200
            csrf = {"X-Requested-With": "activetouch"}
            assert client.post("/api/v1/rig/estop", headers=csrf).status_code == 200
            bearer = {"Authorization": f"Bearer {TOKEN}"}
            assert client.get("/api/v1/models", headers=bearer).status_code == 200
            assert client.delete("/api/v1/session", headers=csrf).status_code == 204
    finally:
        served.server.should_exit = True
        thread.join(timeout=30)
        for logger in loggers:
            logger.removeHandler(collect)
    access = [line for line in collect.lines if "HTTP/1.1" in line]
    assert any("/api/v1/session" in line for line in access), collect.lines
    assert any("/api/v1/rig/estop" in line for line in access)
    for line in collect.lines:
        assert TOKEN not in line
        assert session_id not in line
