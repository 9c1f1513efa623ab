"""The OpenAPI schema declares how to authenticate, and what it declares is what the gate does.

Off loopback ``/api/v1/openapi.json`` lists the bearer token and the session cookie (with the
CSRF header for changes); every operation but the health check and the sign-in references
them. On loopback with a token, reads list the empty requirement (optional) and changes do not;
the schema's claim is checked against the gate by calling every operation without credentials.
A server without a token declares no security.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

from app.main import create_app
from app.security.openapi import BEARER_SCHEME, CSRF_SCHEME, SESSION_SCHEME
from app.security.sessions import SESSION_COOKIE
from tests.app.conftest import TestClient, make_settings
from tests.app.test_security_gate import call, operations

TOKEN = "openapi-token"
BEARER = {"Authorization": f"Bearer {TOKEN}"}
PUBLIC = {("GET", "/api/v1/health"), ("POST", "/api/v1/session")}


def schema_of(client: TestClient, **kwargs: Any) -> dict[str, Any]:
    response = client.get("/api/v1/openapi.json", **kwargs)
    assert response.status_code == 200, response.text
    schema: dict[str, Any] = response.json()
    return schema


def each_operation(schema: dict[str, Any]) -> list[tuple[str, str, dict[str, Any]]]:
    return [
        (method.upper(), path, operation)
        for path, item in schema["paths"].items()
        for method, operation in item.items()
        if method in ("get", "post", "put", "patch", "delete")
    ]


def test_off_loopback_the_schema_declares_the_token_and_the_session(tmp_path: Path) -> None:
    settings = make_settings(tmp_path, host="0.0.0.0", api_token=TOKEN, hardware="serial")
    with TestClient(create_app(settings)) as client:
        assert client.get("/api/v1/openapi.json").status_code == 401  # the docs are gated too
        schema = schema_of(client, headers=BEARER)
        docs = client.get("/api/v1/docs", headers=BEARER)
    schemes = schema["components"]["securitySchemes"]
    assert schemes[BEARER_SCHEME] == {
        "type": "http",
        "scheme": "bearer",
        "description": schemes[BEARER_SCHEME]["description"],
    }
    assert (schemes[SESSION_SCHEME]["type"], schemes[SESSION_SCHEME]["in"]) == ("apiKey", "cookie")
    assert schemes[SESSION_SCHEME]["name"] == SESSION_COOKIE
    assert "restart signs everyone out" in schemes[SESSION_SCHEME]["description"]
    assert (schemes[CSRF_SCHEME]["in"], schemes[CSRF_SCHEME]["name"]) == (
        "header",
        "X-Requested-With",
    )
    assert "security" not in schema  # no global requirement: the public operations have none
    operations_found = each_operation(schema)
    assert len(operations_found) > 30
    for method, path, operation in operations_found:
        if (method, path) in PUBLIC:
            assert "security" not in operation, (method, path)
            continue
        cookie = [SESSION_SCHEME, CSRF_SCHEME] if method != "GET" else [SESSION_SCHEME]
        assert operation["security"] == [
            {BEARER_SCHEME: []},
            {key: [] for key in cookie},
        ], (method, path)
        assert {"401", "429"} <= set(operation["responses"]), (method, path)
    sign_in = schema["paths"]["/api/v1/session"]["post"]
    assert "Retry-After" in sign_in["responses"]["429"]["headers"]
    trials = schema["paths"]["/api/v1/trials"]
    assert trials["get"]["security"] == [{BEARER_SCHEME: []}, {SESSION_SCHEME: []}]
    assert trials["post"]["security"][1] == {SESSION_SCHEME: [], CSRF_SCHEME: []}
    assert docs.status_code == 200
    assert "swagger" in docs.text.lower()


def test_on_loopback_the_schema_says_what_the_gate_does(tmp_path: Path) -> None:
    settings = make_settings(tmp_path, api_token=TOKEN, hardware="serial")
    with TestClient(create_app(settings)) as client:
        schema = schema_of(client)
        declared = {(m, p): op.get("security") for m, p, op in each_operation(schema)}
        walked = operations(client)
        answers = {(m, p): call(client, m, p) for m, p in walked}
    optional = {(m, p) for (m, p), security in declared.items() if security and {} in security}
    required = {(m, p) for (m, p), security in declared.items() if security and {} not in security}
    assert {m for m, _ in optional} == {"GET"}
    assert {m for m, _ in required} == {"POST", "PUT", "PATCH", "DELETE"} & {m for m, _ in walked}
    assert {(m, p) for (m, p), security in declared.items() if not security} == PUBLIC
    # Walked with dummy ids and no credentials: exactly the required ones are 401.
    templated = {(m, re.sub(r"\{[^}]+\}", "999999", p)): (m, p) for m, p in declared}
    assert sorted(templated) == walked
    refused = {templated[op] for op, status in answers.items() if status == 401}
    assert refused == required | {("POST", "/api/v1/session")}  # the sign-in: no token in it


def test_without_a_token_no_security_is_declared(tmp_path: Path) -> None:
    with TestClient(create_app(make_settings(tmp_path))) as client:
        schema = schema_of(client)
    assert "securitySchemes" not in schema.get("components", {})
    assert all("security" not in op for _, _, op in each_operation(schema))
