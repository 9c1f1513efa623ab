"""``create_app(settings)``: the FastAPI app with its lifespan (DB, migrations, run manager)."""

from __future__ import annotations

import time
from collections.abc import AsyncIterator, Callable
from contextlib import asynccontextmanager

from fastapi import APIRouter, Depends, FastAPI
from fastapi.staticfiles import StaticFiles
from starlette.datastructures import Headers
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from app.config import Settings
from app.deps import require_token
from app.errors import PayloadTooLargeError, error_response, install_error_handlers
from app.routes import audit as audit_routes
from app.routes import collections, datasets, events, health, models, objects, rig, trials
from app.routes import session as session_routes
from app.routes.evaluations import router as evaluations_router
from app.security.attempts import AttemptLimiter
from app.security.audit import AuditMiddleware, AuditRecorder, database_writer
from app.security.gate import AuthGate
from app.security.openapi import install_openapi_security
from app.security.sessions import SessionStore
from app.services.context import start_context
from app.services.health import version

API_PREFIX = "/api/v1"


@asynccontextmanager
async def lifespan(app: FastAPI) -> AsyncIterator[None]:
    """Build the app context (migrations, recovery of interrupted runs) and the request audit's
    writer; close them at exit."""
    context = start_context(app.state.settings)
    app.state.context = context
    app.state.audit = AuditRecorder(database_writer(context.database)).start()
    try:
        yield
    finally:
        app.state.audit.close()
        context.close()


class BodySizeLimit:
    """Answer a JSON 413 to a request body over the limit.

    A declared Content-Length over the limit is refused before reading; a chunked body is
    counted as it is read and cut with :class:`PayloadTooLargeError` (also when FastAPI reads
    it for a JSON body: :func:`app.errors.error_response` answers the 413 it wraps).
    """

    def __init__(self, app: ASGIApp, max_body_size: int) -> None:
        self.app = app
        self.max_body_size = max_body_size

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] == "http":
            declared = Headers(scope=scope).get("content-length", "")
            if declared.isdigit() and int(declared) > self.max_body_size:
                refusal = PayloadTooLargeError(
                    f"Request body of {declared} bytes is over the limit of "
                    f"{self.max_body_size} bytes.",
                    limit_bytes=self.max_body_size,
                )
                await error_response(refusal)(scope, receive, send)
                return
            received = 0

            async def counting_receive() -> Message:
                nonlocal received
                message = await receive()
                if message["type"] == "http.request":
                    received += len(message.get("body", b""))
                    if received > self.max_body_size:
                        raise PayloadTooLargeError(
                            f"Request body is over the limit of {self.max_body_size} bytes.",
                            limit_bytes=self.max_body_size,
                        )
                return message

            await self.app(scope, counting_receive, send)
            return
        await self.app(scope, receive, send)


def create_app(
    settings: Settings | None = None, clock: Callable[[], float] = time.monotonic
) -> FastAPI:
    """Build the app from ``settings`` (read from the environment when not given).

    ``clock`` (monotonic, seconds) times the sessions and the limit on wrong tokens; tests pass
    their own.

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
    )
    app.state.settings = settings
    app.add_middleware(BodySizeLimit, max_body_size=settings.max_upload_bytes)
    # Security (app.security): the gate inside the audit, so refusals are recorded too.
    app.state.sessions = SessionStore(settings.session_ttl_s, clock=clock)
    app.state.auth_attempts = AttemptLimiter(
        settings.auth_max_failures, settings.auth_failure_window_s, clock=clock
    )
    app.add_middleware(
        AuthGate,
        settings=settings,
        sessions=app.state.sessions,
        attempts=app.state.auth_attempts,
        api_prefix=API_PREFIX,
    )
    app.add_middleware(AuditMiddleware, api_prefix=API_PREFIX)
    install_error_handlers(app)
    api = APIRouter(prefix=API_PREFIX, dependencies=[Depends(require_token)])
    for module in (health, objects, datasets, models, trials, rig, collections, events):
        api.include_router(module.router)
    api.include_router(evaluations_router)
    api.include_router(session_routes.router)
    api.include_router(audit_routes.router)
    app.include_router(api)
    install_openapi_security(app, settings, API_PREFIX)
    if settings.frontend_dir.is_dir():
        app.mount("/", StaticFiles(directory=settings.frontend_dir, html=True), name="frontend")
    return app
