"""Off loopback nothing answers without the token or a session: the whole OpenAPI schema walked.

Each operation of ``app.openapi()`` is called with dummy path parameters and no body on three
apps: loopback without a token (the baseline), off loopback (``host=0.0.0.0``) without
credentials, and off loopback with the token (header) or a signed-in session (cookie). Without
credentials everything is 401 but ``GET /health``; with them every answer equals the
baseline's. The hardware is "serial" without ports, so rig calls answer 503 at once on both.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from app.main import create_app
from app.security.sessions import SESSION_COOKIE
from tests.app.conftest import TestClient, make_settings

TOKEN = "s3cret-token-for-tests"
BEARER = {"Authorization": f"Bearer {TOKEN}"}
CSRF = {"X-Requested-With": "activetouch"}
SIGN_IN = "/api/v1/session"


def operations(client: TestClient) -> list[tuple[str, str]]:
    """Every (method, path) of the app's OpenAPI schema, path parameters filled with 999999."""
    schema: dict[str, Any] = client.app.openapi()  # type: ignore[attr-defined]
    found = []
    for path, item in schema["paths"].items():
        for method in item:
            if method in ("get", "post", "put", "patch", "delete"):
                found.append((method.upper(), re.sub(r"\{[^}]+\}", "999999", path)))
    return sorted(found)


def call(client: TestClient, method: str, path: str, **kwargs: Any) -> int:
    # The event stream ends after its backlog with follow=false.
    params = {"follow": "false"} if path.endswith("/events") else None
    return client.request(method, path, params=params, **kwargs).status_code


def app_client(tmp_path: Path, name: str, **overrides: Any) -> TestClient:
    settings = make_settings(tmp_path / name, hardware="serial", **overrides)
    return TestClient(create_app(settings))


@pytest.fixture
def baseline(tmp_path: Path) -> Iterator[TestClient]:
    with app_client(tmp_path, "loopback") as client:
        yield client


@pytest.fixture
def gated(tmp_path: Path) -> Iterator[TestClient]:
    with app_client(tmp_path, "lab", host="0.0.0.0", api_token=TOKEN) as client:
        yield client


def test_the_schema_has_the_operations_walked(gated: TestClient) -> None:
    ops = operations(gated)
    assert len(ops) > 30
    for expected in [("GET", "/api/v1/trials"), ("GET", "/api/v1/events"), ("GET", SIGN_IN),
                     ("POST", "/api/v1/rig/estop"), ("GET", "/api/v1/audit")]:  # fmt: skip
        assert expected in ops


def test_off_loopback_everything_but_health_is_401_without_credentials(
    gated: TestClient,
) -> None:
    answers = {(m, p): call(gated, m, p) for m, p in operations(gated)}
    refused = {op for op, status in answers.items() if status == 401}
    assert set(answers) - refused == {("GET", "/api/v1/health")}, answers
    health = gated.get("/api/v1/health")
    assert health.status_code == 200
    assert health.json() == {"auth_required": True}
    # Outside the schema: the docs, unknown API paths and the proxied 3D view are gated too.
    for path in ("/api/v1/openapi.json", "/api/v1/docs", "/api/v1/nothing-here", "/viser/"):
        assert gated.get(path).status_code == 401, path
    # A wrong token or an unknown session cookie is no better.
    assert gated.get("/api/v1/trials", headers={"Authorization": "Bearer no"}).status_code == 401
    gated.cookies.set(SESSION_COOKIE, "made-up")
    assert gated.get("/api/v1/trials").status_code == 401
    refusal = gated.get("/api/v1/trials")
    assert refusal.headers["www-authenticate"] == "Bearer"
    assert TOKEN not in refusal.text


def test_off_loopback_with_the_token_answers_as_on_loopback(
    baseline: TestClient, gated: TestClient
) -> None:
    ops = [op for op in operations(gated) if op[1] != SIGN_IN]
    assert ops == [op for op in operations(baseline) if op[1] != SIGN_IN]
    expected = {op: call(baseline, *op) for op in ops}
    assert 401 not in expected.values()
    with_header = {op: call(gated, *op, headers=BEARER) for op in ops}
    assert with_header == expected
    # GET /health with the token: the full summary.
    assert gated.get("/api/v1/health", headers=BEARER).json()["status"] == "ok"


def test_off_loopback_with_a_session_answers_as_on_loopback(
    baseline: TestClient, gated: TestClient
) -> None:
    ops = [op for op in operations(gated) if op[1] != SIGN_IN]
    expected = {op: call(baseline, *op) for op in ops}
    signed_in = gated.post(SIGN_IN, json={"token": TOKEN})
    assert signed_in.status_code == 200, signed_in.text
    assert signed_in.json()["method"] == "session"
    with_cookie = {op: call(gated, *op, headers=CSRF) for op in ops}
    assert with_cookie == expected
    assert gated.get(SIGN_IN).json()["authenticated"] is True


def test_sign_in_cookie_is_a_server_session_not_the_token(gated: TestClient) -> None:
    assert gated.post(SIGN_IN).status_code == 401
    assert gated.post(SIGN_IN, json={"token": "wrong"}).status_code == 401
    assert SESSION_COOKIE not in gated.cookies
    response = gated.post(SIGN_IN, json={"token": TOKEN})
    header = response.headers["set-cookie"]
    attributes = {part.strip().split("=")[0].lower() for part in header.split(";")}
    assert {"httponly", "samesite", "path"} <= attributes
    assert "max-age" not in attributes  # a browser-session cookie; the server ends idle sessions
    assert "samesite=strict" in header.lower()
    value = gated.cookies[SESSION_COOKIE]
    assert len(value) >= 40
    assert TOKEN not in header
    # A second sign-in is another session; each stands on its own.
    other = TestClient(gated.app)
    other.post(SIGN_IN, json={"token": TOKEN})
    assert other.cookies[SESSION_COOKIE] != value


def test_sign_out_ends_the_session(gated: TestClient) -> None:
    gated.post(SIGN_IN, json={"token": TOKEN})
    session_id = gated.cookies[SESSION_COOKIE]
    assert gated.get("/api/v1/trials").status_code == 200
    # Sign-out is a change: without the CSRF header it is refused and the session lives on.
    assert gated.delete(SIGN_IN).status_code == 403
    assert gated.get("/api/v1/trials").status_code == 200
    out = gated.delete(SIGN_IN, headers=CSRF)
    assert out.status_code == 204
    assert SESSION_COOKIE not in gated.cookies
    assert gated.get("/api/v1/trials").status_code == 401
    # The old id, replayed, is dead on the server too.
    gated.cookies.set(SESSION_COOKIE, session_id)
    assert gated.get("/api/v1/trials").status_code == 401


def test_cookie_changes_need_the_csrf_header_and_same_origin(gated: TestClient) -> None:
    gated.post(SIGN_IN, json={"token": TOKEN})
    estop = "/api/v1/rig/estop"
    assert gated.post(estop).status_code == 403
    assert gated.post(estop, headers={"X-Requested-With": "XMLHttpRequest"}).status_code == 403
    evil = {**CSRF, "Origin": "http://evil.example"}
    assert gated.post(estop, headers=evil).status_code == 403
    same = {**CSRF, "Origin": "http://testserver"}
    assert gated.post(estop, headers=same).status_code != 403
    assert gated.post(estop, headers=CSRF).status_code != 403
    # Reads need no CSRF header; the bearer token needs none either (not a browser credential).
    assert gated.get("/api/v1/trials").status_code == 200
    gated.cookies.clear()
    assert gated.post(estop, headers=BEARER).status_code not in (401, 403)


def test_on_loopback_reads_stay_open_and_changes_need_the_token(tmp_path: Path) -> None:
    with app_client(tmp_path, "local-token", api_token=TOKEN) as client:
        assert client.get("/api/v1/trials").status_code == 200
        assert client.get("/api/v1/events", params={"follow": "false"}).status_code == 200
        assert client.get("/api/v1/health").json()["auth_required"] is True
        assert client.get(SIGN_IN).json() == {
            "authenticated": False,
            "method": None,
            "auth_required": True,
            "reads_need_auth": False,
            "expires_at": None,
        }
        assert client.post("/api/v1/rig/estop").status_code == 401
        assert client.post("/api/v1/rig/estop", headers=BEARER).status_code not in (401, 403)
        client.post(SIGN_IN, json={"token": TOKEN})
        assert client.post("/api/v1/rig/estop", headers=CSRF).status_code not in (401, 403)
    with app_client(tmp_path, "local-open") as client:
        assert client.post("/api/v1/rig/estop").status_code not in (401, 403)
        assert client.post(SIGN_IN, json={"token": "x"}).status_code == 409


def test_reads_can_be_locked_on_loopback_too(tmp_path: Path) -> None:
    """Behind a reverse proxy on the same machine every client is loopback: the switch."""
    with app_client(tmp_path, "proxied", api_token=TOKEN, require_auth_for_reads=True) as client:
        assert client.get("/api/v1/trials").status_code == 401
        assert client.get("/api/v1/health").json() == {"auth_required": True}
