"""``/models``: fit in the background, read, list, export and import model documents."""

from __future__ import annotations

from typing import Annotated, Any, Literal

from fastapi import APIRouter, Body
from fastapi.responses import JSONResponse
from starlette.concurrency import run_in_threadpool

from app.deps import ContextDep, IdPath, Limit, Offset, SessionDep
from app.schemas import ModelAccepted, ModelCreate, ModelPublic, Page
from app.services import models

router = APIRouter(prefix="/models", tags=["models"])


@router.post("", status_code=202)
def create_model(body: ModelCreate, session: SessionDep, context: ContextDep) -> ModelAccepted:
    """Start fitting a manifold to a dataset; progress arrives as ``model.progress`` events."""
    return context.models.submit(session, body)


@router.get("")
def list_models(
    session: SessionDep,
    status: Literal["fitting", "ready", "failed"] | None = None,
    limit: Limit = 100,
    offset: Offset = 0,
) -> Page[ModelPublic]:
    """Models, newest first."""
    return models.list_page(session, status, limit, offset)


@router.get("/{model_id}")
def get_model(model_id: IdPath, session: SessionDep) -> ModelPublic:
    """A model: status, object latents, hyperparameters per feature, fit time, progress and
    how its GP is conditioned (``posterior``: structure; for sparse, the inducing points)."""
    return models.get(session, model_id)


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
