"""``/session``: the dashboard's sign-in (token → HttpOnly session cookie), status, sign-out."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Body, Request, Response

from app.deps import AttemptsDep, ContextDep, IdentityDep, SessionsDep
from app.schemas import SessionStatus, SignIn
from app.security.gate import Identity, session_id_of
from app.security.sessions import SESSION_COOKIE
from app.services import session as sessions_service

router = APIRouter(prefix="/session", tags=["session"])


@router.post(
    "",
    responses={
        401: {"description": "Not this server's token."},
        429: {"description": "Too many wrong tokens from this address: wait `Retry-After` s."},
    },
)
def sign_in(
    request: Request,
    response: Response,
    context: ContextDep,
    sessions: SessionsDep,
    attempts: AttemptsDep,
    body: Annotated[SignIn | None, Body()] = None,
) -> SessionStatus:
    """Check the API token once and set an HttpOnly, SameSite=Strict session cookie.

    The cookie holds a random session id issued by the server (never the token). The session
    ends after ``session_ttl_s`` without use, at sign-out or at a server restart; the cookie when
    the browser closes. The token goes in the body, never in the URL. After
    ``auth_max_failures`` wrong tokens from one address within ``auth_failure_window_s``, its
    sign-ins answer 429 with ``Retry-After`` until the window has passed.
    """
    session = sessions_service.sign_in(
        context.settings,
        sessions,
        body.token if body is not None else None,
        attempts,
        request.client.host if request.client else None,
    )
    # The request presented the token (in its body): the audit records it as authenticated.
    request.scope.setdefault("state", {})["identity"] = Identity("token")
    response.set_cookie(
        SESSION_COOKIE,
        session.session_id,
        path="/",
        httponly=True,
        samesite="strict",
        secure=request.url.scheme == "https",
    )
    return sessions_service.status(context.settings, Identity("session"), session)


@router.get("")
def session_status(context: ContextDep, identity: IdentityDep) -> SessionStatus:
    """How this request is authenticated (off loopback: 401 unless it is)."""
    return sessions_service.status(context.settings, identity)


@router.delete("", status_code=204)
def sign_out(request: Request, response: Response, sessions: SessionsDep) -> None:
    """End the session and delete its cookie."""
    sessions_service.sign_out(sessions, session_id_of(request.headers))
    response.delete_cookie(
        SESSION_COOKIE,
        path="/",
        httponly=True,
        samesite="strict",
        secure=request.url.scheme == "https",
    )
