"""The ways to authenticate, declared in the OpenAPI schema (``/api/v1/openapi.json``).

The gate (:mod:`app.security.gate`) authenticates in middleware, so FastAPI cannot see it from
the routes' dependencies. :func:`install_openapi_security` adds what it accepts to the schema,
from the same policy (:func:`app.security.gate.is_exempt`, the settings):

- ``bearerToken``: ``Authorization: Bearer <token>`` (scripts; Swagger's **Authorize**).
- ``sessionCookie``: the dashboard's session cookie, set by ``POST /api/v1/session``; changes
  made with it need ``csrfHeader`` as well (``X-Requested-With: activetouch``).

Every operation but the health check and the sign-in lists them, with a 401 and a 429 (too many
wrong tokens) among its answers. Where reads are open (a loopback bind without
``require_auth_for_reads``) a read lists the empty requirement too: authentication is optional
there, and neither 401 nor 429 can happen. The sign-in lists its 429. A server without a token
accepts no authentication, and its schema declares none.
"""

from __future__ import annotations

from typing import Any

from fastapi import FastAPI

from app.config import Settings
from app.security.gate import CSRF_VALUE, MUTATING_METHODS, is_exempt, is_sign_in
from app.security.sessions import SESSION_COOKIE

BEARER_SCHEME = "bearerToken"
SESSION_SCHEME = "sessionCookie"
CSRF_SCHEME = "csrfHeader"

#: The HTTP methods of OpenAPI path items (the other keys are parameters, summaries...).
OPERATION_METHODS = frozenset({"get", "put", "post", "delete", "options", "head", "patch"})

SECURITY_SCHEMES: dict[str, dict[str, Any]] = {
    BEARER_SCHEME: {
        "type": "http",
        "scheme": "bearer",
        "description": "The server's API token (`ACTIVETOUCH_API_TOKEN`) as "
        "`Authorization: Bearer <token>`: how scripts authenticate.",
    },
    SESSION_SCHEME: {
        "type": "apiKey",
        "in": "cookie",
        "name": SESSION_COOKIE,
        "description": 'A dashboard session: `POST /api/v1/session` with `{"token": ...}` sets '
        "this HttpOnly cookie (a random id, never the token). Sessions live in the server's "
        "memory: a restart signs everyone out.",
    },
    CSRF_SCHEME: {
        "type": "apiKey",
        "in": "header",
        "name": "X-Requested-With",
        "description": f"Changes authenticated by the session cookie must also send "
        f"`X-Requested-With: {CSRF_VALUE}` (CSRF protection); the bearer token needs nothing "
        "more.",
    },
}

UNAUTHORIZED = {"description": "No token or session, or a wrong token (`WWW-Authenticate`)."}
TOO_MANY = {
    "description": "Too many wrong tokens from this client address lately: the token was not "
    "checked. Try again after `Retry-After` seconds.",
    "headers": {
        "Retry-After": {
            "description": "Seconds until this address may try a token again.",
            "schema": {"type": "integer", "minimum": 1},
        }
    },
}


def requirements(method: str, settings: Settings) -> list[dict[str, list[str]]]:
    """The security requirements of a gated operation (any one of them suffices)."""
    mutating = method.upper() in MUTATING_METHODS
    cookie: dict[str, list[str]] = {SESSION_SCHEME: []}
    if mutating:
        cookie[CSRF_SCHEME] = []
    found: list[dict[str, list[str]]] = [{BEARER_SCHEME: []}, cookie]
    if not mutating and not settings.reads_need_auth:
        found.append({})  # open read: authentication optional
    return found


def add_security(schema: dict[str, Any], settings: Settings, api_prefix: str) -> dict[str, Any]:
    """Declare the security schemes in ``schema`` and reference them from gated operations.

    Returns ``schema`` itself (changed in place); unchanged when the server has no token.
    """
    if settings.token is None:
        return schema
    schema.setdefault("components", {}).setdefault("securitySchemes", {}).update(SECURITY_SCHEMES)
    for path, item in schema.get("paths", {}).items():
        for method, operation in item.items():
            if method not in OPERATION_METHODS or not isinstance(operation, dict):
                continue
            responses = operation.setdefault("responses", {})
            if is_exempt(method.upper(), path, api_prefix):
                if is_sign_in(method.upper(), path, api_prefix):
                    responses["429"] = TOO_MANY
                continue
            operation["security"] = requirements(method, settings)
            if {} not in operation["security"]:  # needs authentication: 401, or 429
                responses.setdefault("401", UNAUTHORIZED)
                responses["429"] = TOO_MANY
    return schema


def install_openapi_security(app: FastAPI, settings: Settings, api_prefix: str) -> None:
    """Make ``app.openapi()`` (and so ``/openapi.json`` and ``/docs``) declare the security."""
    build = app.openapi

    def openapi() -> dict[str, Any]:
        if app.openapi_schema is None:
            app.openapi_schema = add_security(build(), settings, api_prefix)
        return app.openapi_schema

    app.openapi = openapi  # type: ignore[method-assign]
