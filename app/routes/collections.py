"""``/collections``: gather a dataset on the rig as a run with progress; control it."""

from __future__ import annotations

from fastapi import APIRouter

from app.deps import ContextDep, IdPath, Limit, Offset, SessionDep
from app.schemas import CollectionCreate, Page, RunPublic
from app.services import collections
from app.states import Action, RunStatus

router = APIRouter(prefix="/collections", tags=["collections"])


@router.post("", status_code=201)
def create_collection(
    body: CollectionCreate, session: SessionDep, context: ContextDep
) -> RunPublic:
    """Touch every object ``samples_per_object`` times; progress comes as events."""
    return context.collections.create(session, body)


@router.get("")
def list_collections(
    session: SessionDep,
    status: RunStatus | None = None,
    limit: Limit = 100,
    offset: Offset = 0,
) -> Page[RunPublic]:
    """Collection runs, newest first."""
    return collections.list_page(session, status, limit, offset)


@router.get("/{collection_id}")
def get_collection(collection_id: IdPath, session: SessionDep) -> RunPublic:
    """A collection run: status, progress, its dataset."""
    return collections.get(session, collection_id)


@router.post("/{collection_id}/{action}")
def control_collection(
    collection_id: IdPath, action: Action, session: SessionDep, context: ContextDep
) -> RunPublic:
    """Pause, resume, stop or abort a collection (409 when its state does not allow it).

    ``pause``, ``stop``: after the touch in progress; ``resume`` a paused collection;
    ``abort``: at once (the rig is emergency-stopped). What was gathered stays.
    """
    return context.collections.control(session, collection_id, action)
