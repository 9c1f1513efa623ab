"""``/collections``: gather a dataset on the rig as a run with progress; control it."""

from __future__ import annotations

from fastapi import APIRouter

from app.deps import ContextDep, IdPath, Limit, Offset, SessionDep
from app.schemas import CollectionCreate, Page, RunPublic
from app.services import collections
from app.states import RunStatus

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


@router.post("/{collection_id}/pause")
def pause_collection(collection_id: IdPath, session: SessionDep, context: ContextDep) -> RunPublic:
    """Pause after the touch in progress."""
    return context.collections.control(session, collection_id, "pause")


@router.post("/{collection_id}/resume")
def resume_collection(collection_id: IdPath, session: SessionDep, context: ContextDep) -> RunPublic:
    """Resume a paused collection."""
    return context.collections.control(session, collection_id, "resume")


@router.post("/{collection_id}/stop")
def stop_collection(collection_id: IdPath, session: SessionDep, context: ContextDep) -> RunPublic:
    """Stop after the touch in progress; what was gathered stays."""
    return context.collections.control(session, collection_id, "stop")


@router.post("/{collection_id}/abort")
def abort_collection(collection_id: IdPath, session: SessionDep, context: ContextDep) -> RunPublic:
    """Abort at once (the rig is emergency-stopped); what was gathered stays."""
    return context.collections.control(session, collection_id, "abort")
