"""The gate: who is calling (token, session or nobody) and whether the request may pass.

Policy (docs/security.md):

- With no token configured (loopback only) everything passes.
- Otherwise mutating requests (POST, PUT, PATCH, DELETE) under ``/api/v1`` need the token
  (``Authorization: Bearer``, compared in constant time) or a signed-in session cookie.
- Off loopback (:attr:`~app.config.Settings.reads_need_auth`) every request under ``/api/v1``
  and ``/viser`` (the proxied 3D view, HTTP and websocket) needs them too, except
  ``GET /api/v1/health`` and the sign-in ``POST /api/v1/session``.
- CSRF: a change authenticated by the cookie alone must carry ``X-Requested-With: activetouch``
  (a cross-origin page cannot set a custom header without a CORS preflight, which this server
  never grants) and, when the browser sends ``Origin``, an origin equal to the request's host.
  The cookie is also SameSite=Strict, so other sites' pages do not send it at all; the header
  and origin checks cover pages of the same site on other ports. Websockets to the 3D view
  check ``Origin`` likewise.
- Wrong tokens are limited per client address (:mod:`app.security.attempts`): a wrong bearer
  token counts as a failure (the sign-in counts its own, :mod:`app.services.session`); while an
  address is over the limit its tokens are not checked, and the sign-in or a request that would
  need its token answers 429 with ``Retry-After``. Requests that need no token pass as before.
"""

from __future__ import annotations

import hmac
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Literal
from urllib.parse import urlsplit

from starlette.datastructures import Headers
from starlette.requests import cookie_parser
from starlette.types import ASGIApp, Receive, Scope, Send

from app.config import Settings
from app.errors import AppError, error_response
from app.security.attempts import AttemptLimiter
from app.security.errors import ForbiddenError, TooManyAttemptsError, UnauthorizedError
from app.security.sessions import SESSION_COOKIE, SessionStore
from app.security.watch import watch_session

MUTATING_METHODS = frozenset({"POST", "PUT", "PATCH", "DELETE"})
#: Path prefix of the 3D view proxied through the app.
VISER_PREFIX = "/viser"
#: The header (and its value) a cookie-authenticated change must carry.
CSRF_HEADER = "x-requested-with"
CSRF_VALUE = "activetouch"

AuthMethod = Literal["token", "session"]


@dataclass(frozen=True)
class Identity:
    """How a request authenticated: ``method`` is ``None`` when it did not."""

    method: AuthMethod | None = None

    @property
    def authenticated(self) -> bool:
        """Whether the request carried the token or a live session."""
        return self.method is not None


@dataclass(frozen=True)
class Refusal:
    """Why a request may not pass: HTTP status (401, 403 or 429) and a message; a 429 says
    when to try again."""

    status_code: int
    detail: str
    retry_after_s: float | None = None

    def error(self) -> AppError:
        """The app error that answers it (:func:`app.errors.error_response` writes the body)."""
        if self.status_code == 429:
            assert self.retry_after_s is not None
            return TooManyAttemptsError(self.detail, self.retry_after_s)
        if self.status_code == 401:
            unauthorized = UnauthorizedError(self.detail)
            unauthorized.headers = {"WWW-Authenticate": "Bearer"}
            return unauthorized
        return ForbiddenError(self.detail)


def token_matches(presented: str, token: str) -> bool:
    """Constant-time comparison of a presented token with the configured one."""
    return hmac.compare_digest(
        presented.encode("utf-8", "surrogatepass"), token.encode("utf-8", "surrogatepass")
    )


def bearer_of(headers: Mapping[str, str]) -> str | None:
    """The token of an ``Authorization: Bearer <token>`` header, if there is one."""
    scheme, _, presented = headers.get("authorization", "").partition(" ")
    if scheme.lower() != "bearer" or not presented.strip():
        return None
    return presented.strip()


def session_id_of(headers: Mapping[str, str]) -> str | None:
    """The session id in the request's cookie, if any."""
    return cookie_parser(headers.get("cookie", "")).get(SESSION_COOKIE) or None


def client_address(scope: Scope) -> str | None:
    """The client's address as the server sees it (``None`` when unknown)."""
    client = scope.get("client")
    return str(client[0]) if client else None


def identify(
    headers: Mapping[str, str], token: str | None, sessions: SessionStore, check_bearer: bool = True
) -> Identity:
    """Who is calling: the token (header), a live session (cookie), or nobody.

    With ``check_bearer`` false (the client is over the limit of wrong tokens) a bearer token
    is not looked at.
    """
    if token is None:
        return Identity()
    presented = bearer_of(headers) if check_bearer else None
    if presented is not None and token_matches(presented, token):
        return Identity("token")
    if sessions.is_valid(session_id_of(headers)):
        return Identity("session")
    return Identity()


def is_under(path: str, prefix: str) -> bool:
    """Whether ``path`` is ``prefix`` or below it."""
    return path == prefix or path.startswith(prefix + "/")


def is_sign_in(method: str, path: str, api_prefix: str) -> bool:
    """Whether the request is the sign-in (``POST /session``, the token in its body)."""
    return method == "POST" and path == f"{api_prefix}/session"


def is_exempt(method: str, path: str, api_prefix: str) -> bool:
    """The requests that pass without auth: the health check and the sign-in."""
    if method in ("GET", "HEAD") and path == f"{api_prefix}/health":
        return True
    return is_sign_in(method, path, api_prefix)


def same_origin(headers: Mapping[str, str]) -> bool:
    """Whether the ``Origin`` header (when sent) names the host the request was sent to."""
    origin = headers.get("origin")
    if origin is None:
        return True
    host = headers.get("host", "")
    return bool(host) and urlsplit(origin).netloc.lower() == host.lower()


def refusal(
    settings: Settings,
    method: str,
    path: str,
    identity: Identity,
    headers: Mapping[str, str],
    api_prefix: str,
    websocket: bool = False,
) -> Refusal | None:
    """Why this request may not pass, or ``None`` when it may (the policy in the module doc)."""
    if settings.token is None:
        return None
    in_api = is_under(path, api_prefix)
    if not (in_api or is_under(path, VISER_PREFIX)) or is_exempt(method, path, api_prefix):
        return None
    mutating = method in MUTATING_METHODS and not websocket
    needs_auth = settings.reads_need_auth or (mutating and in_api)
    if needs_auth and not identity.authenticated:
        if settings.reads_need_auth:
            detail = (
                "This server requires authentication: 'Authorization: Bearer <token>', or sign "
                "in to the dashboard."
            )
        else:
            detail = (
                "This server requires the API token for changes: 'Authorization: Bearer "
                "<token>', or sign in to the dashboard."
            )
        return Refusal(401, detail)
    if identity.method == "session" and (mutating or websocket):
        if not same_origin(headers):
            return Refusal(403, "Cross-origin request refused (Origin is not this server).")
        if mutating and headers.get(CSRF_HEADER, "").lower() != CSRF_VALUE:
            return Refusal(
                403,
                f"A change authenticated by the session cookie needs the header "
                f"'X-Requested-With: {CSRF_VALUE}' (CSRF protection).",
            )
    return None


class AuthGate:
    """ASGI middleware applying :func:`refusal` to every HTTP and websocket request.

    It stores the caller's :class:`Identity` in ``scope["state"]["identity"]`` (read by the
    health check, the session routes and the request audit). The event stream and websockets
    opened with a session end when the session does (:mod:`app.security.watch`). Wrong bearer
    tokens are counted per client address, and an address over the limit gets 429
    (:meth:`_identify`).

    Args:
        app: The wrapped application.
        settings: Token and whether reads need auth.
        sessions: The session store.
        attempts: The limit on wrong tokens per client address.
        api_prefix: Prefix of the REST API (``/api/v1``).
    """

    def __init__(
        self,
        app: ASGIApp,
        settings: Settings,
        sessions: SessionStore,
        attempts: AttemptLimiter,
        api_prefix: str,
    ) -> None:
        self.app = app
        self.settings = settings
        self.sessions = sessions
        self.attempts = attempts
        self.api_prefix = api_prefix

    def _identify(
        self, scope: Scope, headers: Headers, method: str, websocket: bool
    ) -> tuple[Identity, float | None]:
        """The caller's identity, and the seconds it must wait when it is over the limit of
        wrong tokens and this request is an attempt (a bearer token, or the sign-in)."""
        token = self.settings.token
        if token is None:
            return Identity(), None
        client = client_address(scope)
        presented = bearer_of(headers)
        signing_in = not websocket and is_sign_in(method, scope["path"], self.api_prefix)
        wait_s = None
        if presented is not None or signing_in:
            wait_s = self.attempts.retry_after_s(client)
        identity = identify(headers, token, self.sessions, check_bearer=wait_s is None)
        if wait_s is None and presented is not None and identity.method != "token":
            self.attempts.record_failure(client)
        return identity, wait_s

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] not in ("http", "websocket"):
            await self.app(scope, receive, send)
            return
        headers = Headers(scope=scope)
        websocket = scope["type"] == "websocket"
        method = "GET" if websocket else scope["method"]
        identity, wait_s = self._identify(scope, headers, method, websocket)
        scope.setdefault("state", {})["identity"] = identity
        refused = refusal(
            self.settings, method, scope["path"], identity, headers, self.api_prefix, websocket
        )
        if wait_s is not None and (
            is_sign_in(method, scope["path"], self.api_prefix)
            or (refused is not None and refused.status_code == 401)
        ):
            # Over the limit: the token was not checked, and this request needs one.
            refused = Refusal(429, self.attempts.detail(wait_s), wait_s)
        if refused is None:
            if identity.method == "session" and (
                websocket or scope["path"] == f"{self.api_prefix}/events"
            ):
                # A long-lived connection: it ends when its session does (sign-out, expiry).
                session_id = session_id_of(headers)
                await watch_session(
                    self.app, scope, receive, send, lambda: self.sessions.is_live(session_id)
                )
            else:
                await self.app(scope, receive, send)
        elif websocket:
            await receive()  # websocket.connect
            # Closing before accepting: the server answers the handshake with HTTP 403.
            await send({"type": "websocket.close", "code": 1008, "reason": refused.detail})
        else:
            await error_response(refused.error())(scope, receive, send)


def identity_of(state: Mapping[str, object]) -> Identity:
    """The identity the gate stored in a request's state (nobody, when the gate did not run)."""
    identity = state.get("identity")
    return identity if isinstance(identity, Identity) else Identity()
