"""``GET /audit``: the mutating requests the server recorded (who started, stopped, e-stopped)."""

from __future__ import annotations

from typing import Annotated, Literal

from fastapi import APIRouter, Query

from app.deps import Limit, Offset, SessionDep
from app.schemas import Page, RequestAuditPublic
from app.services import audit

router = APIRouter(prefix="/audit", tags=["audit"])


@router.get("")
def list_audit(
    session: SessionDep,
    method: Literal["POST", "PUT", "PATCH", "DELETE"] | None = None,
    path_prefix: Annotated[str | None, Query(max_length=500)] = None,
    limit: Limit = 100,
    offset: Offset = 0,
) -> Page[RequestAuditPublic]:
    """Recorded changes, newest first: time, client address, method, path and route, status,
    and whether (and how) the request authenticated. Refused requests are listed too."""
    return audit.list_page(session, limit, offset, method, path_prefix)
