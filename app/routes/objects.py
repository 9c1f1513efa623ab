"""``GET /objects``: the object registry."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Query

from app.deps import SessionDep
from app.schemas import ObjectPublic, Page
from app.services import objects

router = APIRouter(prefix="/objects", tags=["objects"])


@router.get("")
def list_objects(
    session: SessionDep,
    limit: Annotated[int, Query(ge=1, le=1000)] = 100,
    offset: Annotated[int, Query(ge=0)] = 0,
) -> Page[ObjectPublic]:
    """Objects named in datasets and collections, with their turntable slots."""
    return objects.list_page(session, limit, offset)
