"""``/models``: fit as a background job (queued, fitting, stop), read, list, export and import
model documents."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Body
from fastapi.responses import JSONResponse
from starlette.concurrency import run_in_threadpool

from app.deps import ContextDep, IdPath, Limit, Offset, SessionDep
from app.schemas import ModelAccepted, ModelCreate, ModelPublic, Page
from app.services import models
from app.states import ModelStatus

router = APIRouter(prefix="/models", tags=["models"])


@router.post("", status_code=202)
def create_model(body: ModelCreate, session: SessionDep, context: ContextDep) -> ModelAccepted:
    """Fit a manifold to a dataset as a background job: ``fitting`` at once, or ``queued`` (with
    its ``queue_position``) while the server runs its most fits at once; progress arrives as
    ``model.progress`` events."""
    return context.fits.submit(session, body)


@router.get("")
def list_models(
    session: SessionDep,
    context: ContextDep,
    status: ModelStatus | None = None,
    limit: Limit = 100,
    offset: Offset = 0,
) -> Page[ModelPublic]:
    """Models, newest first."""
    return models.list_page(session, status, limit, offset, context.fits.queue_position)


@router.get("/{model_id}")
def get_model(model_id: IdPath, session: SessionDep, context: ContextDep) -> ModelPublic:
    """A model: status (with its place in the queue while queued), object latents,
    hyperparameters per feature, fit time, progress and how its GP is conditioned
    (``posterior``: structure; for sparse, the inducing points)."""
    return context.fits.get(session, model_id)


@router.post("/{model_id}/stop")
def stop_fit(model_id: IdPath, session: SessionDep, context: ContextDep) -> ModelPublic:
    """Stop a queued or running fit: the model ends ``stopped`` (a running fit at its next
    progress checkpoint); 409 once the fit has ended."""
    return context.fits.stop(session, model_id)


@router.get("/{model_id}/export")
def export_model(model_id: IdPath, session: SessionDep, context: ContextDep) -> JSONResponse:
    """The model as a self-contained JSON document (format ``activetouch-model/1``)."""
    document = context.models.export_document(session, model_id)
    return JSONResponse(
        document,
        headers={"Content-Disposition": f'attachment; filename="model-{model_id}.json"'},
    )


@router.post("/import", status_code=201)
async def import_model(
    document: Annotated[dict[str, Any], Body()], session: SessionDep, context: ContextDep
) -> ModelPublic:
    """Store a model document (as exported) as a new ready model."""
    return await run_in_threadpool(context.models.import_document, session, document)
