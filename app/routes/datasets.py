"""``/datasets``: upload (CSV body, multipart file or JSON), read, list, export."""

from __future__ import annotations

from typing import Any, Literal

from fastapi import APIRouter, Request, Response
from pydantic import ValidationError
from starlette.concurrency import run_in_threadpool

from app.deps import ContextDep, IdPath, Limit, Offset, SessionDep
from app.documents.training_csv import MAX_NAME_CHARACTERS
from app.errors import BadInputError
from app.schemas import DatasetCreate, DatasetPublic, Page
from app.services import datasets
from core.features.pipeline import FEATURE_KINDS

router = APIRouter(prefix="/datasets", tags=["datasets"])

_UPLOAD_BODY: dict[str, Any] = {
    "requestBody": {
        "required": True,
        "content": {
            "application/json": {"schema": {"$ref": "#/components/schemas/DatasetCreate"}},
            "text/csv": {"schema": {"type": "string"}},
            "application/x-ndjson": {
                "schema": {
                    "type": "string",
                    "description": "Raw touches, one JSON object per line (docs/raw-touches.md).",
                }
            },
            "multipart/form-data": {
                "schema": {
                    "type": "object",
                    "properties": {
                        "file": {"type": "string", "format": "binary"},
                        "name": {"type": "string", "maxLength": MAX_NAME_CHARACTERS},
                    },
                    "required": ["file"],
                }
            },
        },
    }
}


@router.post("", status_code=201, openapi_extra=_UPLOAD_BODY)
async def create_dataset(
    request: Request, session: SessionDep, context: ContextDep
) -> DatasetPublic:
    """Upload touches as CSV (``object,x_1..x_dx,y_1..y_dy``), JSON ``{"name", "samples"}`` or
    raw touches (``application/x-ndjson``, docs/raw-touches.md: y is each channel's mean and the
    series are kept, ``GET /datasets/{id}/raw-touches`` gives them back; ``?features=whole``,
    the default, refuses series shorter than the whole-touch pipeline's window, ``means`` only
    empty ones)."""
    content_type = request.headers.get("content-type", "").split(";")[0].strip().lower()
    name = request.query_params.get("name", "")[:MAX_NAME_CHARACTERS]
    if content_type in ("text/csv", "text/plain", "application/csv"):
        text = _decode(await request.body(), "body")
        return await run_in_threadpool(
            datasets.create_from_csv, session, context.events, text, name
        )
    if content_type == "multipart/form-data":
        text, name = await _read_multipart(request, name)
        return await run_in_threadpool(
            datasets.create_from_csv, session, context.events, text, name
        )
    if content_type in ("application/x-ndjson", "application/jsonl"):
        features = request.query_params.get("features", "whole")
        if features not in FEATURE_KINDS:
            raise BadInputError(
                f"features: expected one of {list(FEATURE_KINDS)}, received {features!r}.",
                field="features",
            )
        text = _decode(await request.body(), "body")
        return await run_in_threadpool(
            datasets.create_from_raw,
            session,
            context.events,
            text,
            name,
            "means" if features == "means" else "whole",
        )
    if content_type in ("application/json", ""):
        try:
            body = DatasetCreate.model_validate_json(await request.body())
        except ValidationError as exc:
            raise BadInputError(
                "Invalid dataset JSON.",
                errors=exc.errors(include_url=False, include_input=False, include_context=False),
            ) from exc
        return await run_in_threadpool(datasets.create_from_json, session, context.events, body)
    raise UnsupportedMediaError(content_type)


class UnsupportedMediaError(BadInputError):
    """Upload with a content type that is neither CSV, multipart nor JSON."""

    status_code = 415

    def __init__(self, content_type: str) -> None:
        super().__init__(
            f"Content-Type {content_type!r} is not supported; send text/csv, "
            "multipart/form-data (field 'file'), application/json or application/x-ndjson "
            "(raw touches).",
            field="content-type",
        )


def _decode(raw: bytes, where: str) -> str:
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise BadInputError(f"{where}: not UTF-8 text ({exc}).", field=where) from exc


async def _read_multipart(request: Request, name: str) -> tuple[str, str]:
    try:
        form = await request.form(max_files=1, max_fields=5)
    except Exception as exc:  # malformed multipart bodies raise several starlette errors
        raise BadInputError(f"Malformed multipart body: {exc}", field="body") from exc
    upload = form.get("file")
    if upload is None or isinstance(upload, str):
        raise BadInputError("Multipart upload needs a file in field 'file'.", field="file")
    text = _decode(await upload.read(), "file")
    form_name = form.get("name")
    if isinstance(form_name, str) and form_name:
        name = form_name[:MAX_NAME_CHARACTERS]
    return text, name


@router.get("")
def list_datasets(
    session: SessionDep,
    limit: Limit = 100,
    offset: Offset = 0,
) -> Page[DatasetPublic]:
    """Datasets, newest first."""
    return datasets.list_page(session, limit, offset)


@router.get("/{dataset_id}")
def get_dataset(dataset_id: IdPath, session: SessionDep) -> DatasetPublic:
    """One dataset's summary."""
    return datasets.get(session, dataset_id)


@router.get(
    "/{dataset_id}/export",
    response_model=None,
    responses={
        200: {
            "model": DatasetCreate,
            "content": {"text/csv": {"schema": {"type": "string"}}},
            "description": "CSV (default) or the JSON upload format.",
        }
    },
)
def export_dataset(
    dataset_id: IdPath,
    session: SessionDep,
    format: Literal["csv", "json"] = "csv",
) -> Response:
    """The dataset as CSV or JSON (floats written exactly)."""
    if format == "json":
        body = datasets.export_json(session, dataset_id)
        # A sample without a placement leaves the key out, as an upload without them does.
        return Response(body.model_dump_json(exclude_none=True), media_type="application/json")
    return Response(
        datasets.export_csv(session, dataset_id),
        media_type="text/csv",
        headers={"Content-Disposition": f'attachment; filename="dataset-{dataset_id}.csv"'},
    )


@router.get(
    "/{dataset_id}/raw-touches",
    response_model=None,
    responses={
        200: {
            "content": {"application/x-ndjson": {"schema": {"type": "string"}}},
            "description": "The raw touches, one JSON object per line (docs/raw-touches.md).",
        }
    },
)
def export_raw_touches(dataset_id: IdPath, session: SessionDep) -> Response:
    """The dataset's raw touches, to featurise again (``activetouch fit --features whole``)."""
    return Response(datasets.export_raw(session, dataset_id), media_type="application/x-ndjson")
