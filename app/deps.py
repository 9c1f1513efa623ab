"""FastAPI dependencies as ``Annotated`` aliases: the app context, a DB session, the caller's
identity, the session store, the limit on wrong tokens, and the auth check (a backstop of the
gate's middleware)."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Annotated

from fastapi import Depends, Path, Query, Request
from sqlalchemy.orm import Session

from app.security.attempts import AttemptLimiter
from app.security.gate import Identity, identify, refusal
from app.security.sessions import SessionStore
from app.services.context import AppContext

#: Largest id accepted in a path (SQLite integers are 64-bit signed).
MAX_ID = 2**63 - 1

#: A resource id in a path: a positive 64-bit integer (else 422, not a database error).
IdPath = Annotated[int, Path(ge=1, le=MAX_ID)]

#: Paging of list endpoints.
Limit = Annotated[int, Query(ge=1, le=1000)]
Offset = Annotated[int, Query(ge=0, le=MAX_ID)]


async def get_context(request: Request) -> AppContext:
    """The context built by the app's lifespan (async: no thread-pool hop for a lookup)."""
    context: AppContext = request.app.state.context
    return context


ContextDep = Annotated[AppContext, Depends(get_context)]


def get_session(context: ContextDep) -> Iterator[Session]:
    """A database session for one request."""
    with context.database.session() as session:
        yield session


SessionDep = Annotated[Session, Depends(get_session)]


async def get_identity(request: Request) -> Identity:
    """How the request authenticated (found by the gate; worked out here if it did not run)."""
    identity = request.scope.get("state", {}).get("identity")
    if isinstance(identity, Identity):
        return identity
    return identify(request.headers, request.app.state.settings.token, request.app.state.sessions)


IdentityDep = Annotated[Identity, Depends(get_identity)]


async def get_sessions(request: Request) -> SessionStore:
    """The app's dashboard sessions."""
    sessions: SessionStore = request.app.state.sessions
    return sessions


SessionsDep = Annotated[SessionStore, Depends(get_sessions)]


async def get_attempts(request: Request) -> AttemptLimiter:
    """The app's limit on wrong tokens per client address."""
    attempts: AttemptLimiter = request.app.state.auth_attempts
    return attempts


AttemptsDep = Annotated[AttemptLimiter, Depends(get_attempts)]


async def require_token(request: Request, identity: IdentityDep) -> None:
    """The gate's policy again, per API route (defence in depth if the middleware were missing).

    Off loopback every request needs the token or a session; on loopback only changes do (when
    a token is configured). See :func:`app.security.gate.refusal`.
    """
    from app.main import API_PREFIX  # here: app.main imports this module

    refused = refusal(
        request.app.state.settings,
        request.method,
        request.scope["path"],
        identity,
        request.headers,
        API_PREFIX,
    )
    if refused is not None:
        raise refused.error()
