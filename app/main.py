"""``create_app(settings)``: the FastAPI app with its lifespan (DB, migrations, run manager)."""

from __future__ import annotations

from collections.abc import AsyncIterator
from contextlib import asynccontextmanager

from fastapi import APIRouter, Depends, FastAPI
from fastapi.staticfiles import StaticFiles

from app.config import Settings
from app.deps import require_token
from app.errors import install_error_handlers
from app.routes import datasets, events, health
from app.services.context import start_context
from app.services.health import version

API_PREFIX = "/api/v1"


@asynccontextmanager
async def lifespan(app: FastAPI) -> AsyncIterator[None]:
    """Build the app context (migrations, recovery of interrupted runs); close it at exit."""
    context = start_context(app.state.settings)
    app.state.context = context
    try:
        yield
    finally:
        context.close()


def create_app(settings: Settings | None = None) -> FastAPI:
    """Build the app from ``settings`` (read from the environment when not given).

    Raises:
        app.config.ConfigurationError: Unsafe settings (a non-loopback host without a token).
    """
    settings = settings if settings is not None else Settings()
    settings.check_safe_to_serve()
    app = FastAPI(
        title="ActiveTouch",
        version=version(),
        summary="Active tactile object recognition: datasets, manifold models, trials, rig.",
        lifespan=lifespan,
        openapi_url=f"{API_PREFIX}/openapi.json",
        docs_url=f"{API_PREFIX}/docs",
        redoc_url=None,
        max_body_size=settings.max_upload_bytes,
    )
    app.state.settings = settings
    install_error_handlers(app)
    api = APIRouter(prefix=API_PREFIX, dependencies=[Depends(require_token)])
    for module in (health, datasets, events):
        api.include_router(module.router)
    app.include_router(api)
    if settings.frontend_dir.is_dir():
        app.mount("/", StaticFiles(directory=settings.frontend_dir, html=True), name="frontend")
    return app
