"""FastAPI dependencies as ``Annotated`` aliases: the app context, a DB session, the token check."""

from __future__ import annotations

import secrets
from collections.abc import Iterator
from typing import Annotated

from fastapi import Depends, Path, Query, Request
from sqlalchemy.orm import Session

from app.errors import AppError
from app.services.context import AppContext

MUTATING_METHODS = frozenset({"POST", "PUT", "PATCH", "DELETE"})

#: Largest id accepted in a path (SQLite integers are 64-bit signed).
MAX_ID = 2**63 - 1

#: A resource id in a path: a positive 64-bit integer (else 422, not a database error).
IdPath = Annotated[int, Path(ge=1, le=MAX_ID)]

#: Paging of list endpoints.
Limit = Annotated[int, Query(ge=1, le=1000)]
Offset = Annotated[int, Query(ge=0, le=MAX_ID)]


class UnauthorizedError(AppError):
    """A mutating request without the right bearer token."""

    status_code = 401


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


async def require_token(request: Request) -> None:
    """When an API token is configured, mutating requests need ``Authorization: Bearer <token>``."""
    token = request.app.state.settings.token
    if token is None or request.method not in MUTATING_METHODS:
        return
    header = request.headers.get("authorization", "")
    scheme, _, presented = header.partition(" ")
    if scheme.lower() != "bearer" or not secrets.compare_digest(
        presented.strip().encode(), token.encode()
    ):
        raise UnauthorizedError(
            "This server requires 'Authorization: Bearer <token>' for changes.",
        )
