"""Objects: the registry of object names, slots and notes (filled by uploads and collections)."""

from __future__ import annotations

from sqlalchemy.orm import Session

from app import crud
from app.schemas import ObjectPublic, Page


def list_page(session: Session, limit: int, offset: int) -> Page[ObjectPublic]:
    """Registered objects, by name."""
    rows, count = crud.list_objects(session, limit, offset)
    return Page[ObjectPublic](
        data=[
            ObjectPublic(
                id=r.id,
                name=r.name,
                slot=r.slot,
                notes=r.notes,
                properties=r.properties,
                created_at=r.created_at,
            )
            for r in rows
        ],
        count=count,
    )
