"""``GET /objects``: the object registry."""

from __future__ import annotations

from fastapi import APIRouter

from app.deps import Limit, Offset, SessionDep
from app.schemas import ObjectPublic, Page
from app.services import objects

router = APIRouter(prefix="/objects", tags=["objects"])


@router.get("")
def list_objects(
    session: SessionDep,
    limit: Limit = 100,
    offset: Offset = 0,
) -> Page[ObjectPublic]:
    """Objects named in datasets and collections, with their turntable slots."""
    return objects.list_page(session, limit, offset)
