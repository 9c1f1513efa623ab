"""The request audit, read back: mutating requests newest first (recorded by
:mod:`app.security.audit`)."""

from __future__ import annotations

from sqlalchemy.orm import Session

from app import crud
from app.schemas import Page, RequestAuditPublic


def list_page(
    session: Session,
    limit: int,
    offset: int,
    method: str | None = None,
    path_prefix: str | None = None,
) -> Page[RequestAuditPublic]:
    """A page of recorded requests, newest first, filtered by method and path prefix."""
    rows, count = crud.list_request_audits(session, limit, offset, method, path_prefix)
    return Page[RequestAuditPublic](
        data=[RequestAuditPublic.model_validate(row, from_attributes=True) for row in rows],
        count=count,
    )
