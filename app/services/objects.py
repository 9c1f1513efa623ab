"""Objects: the registry of object names, slots and notes (filled by uploads and collections).

A collection on the simulated rig also records what the simulation knows of each object it
touches (material, stiffness, friction, roughness, thermal effusivity, temperature), so the
registry shows the known properties of the demo's objects.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from sqlalchemy.orm import Session

from app import crud
from app.schemas import ObjectPublic, Page, from_row


def list_page(session: Session, limit: int, offset: int) -> Page[ObjectPublic]:
    """Registered objects, by name."""
    rows, count = crud.list_objects(session, limit, offset)
    return Page[ObjectPublic](
        data=[from_row(ObjectPublic, r) for r in rows],
        count=count,
    )


def record_known_properties(
    session: Session, slots: Mapping[str, int], known: Mapping[str, Mapping[str, Any]] | None
) -> list[str]:
    """Store the known properties of objects placed where the rig knows them.

    An object gets the properties of the rig's catalogue entry of the same name only when it
    stands in that entry's slot (otherwise the catalogue describes another object). Keys already
    in the registry that the catalogue does not name (an operator's own) are kept.

    Args:
        session: Database session (the caller commits).
        slots: Object name → turntable slot, as requested.
        known: The rig's catalogue, name → properties including ``slot`` (``None``: a real rig,
            nothing known).

    Returns:
        The names whose properties were recorded.
    """
    if not known:
        return []
    recorded = []
    for name, slot in slots.items():
        entry = known.get(name)
        if entry is None or entry.get("slot") != slot:
            continue
        row = crud.get_or_create_objects(session, [name])[name]
        properties = {key: value for key, value in entry.items() if key != "slot"}
        row.properties = {**(row.properties or {}), **properties}
        recorded.append(name)
    return recorded
