"""Health check."""

from __future__ import annotations

from importlib import metadata

from app import crud
from app.config import Settings
from app.schemas import Health
from app.security.gate import Identity
from app.services.context import AppContext


def version() -> str:
    """The installed package version."""
    try:
        return metadata.version("activetouch")
    except metadata.PackageNotFoundError:  # pragma: no cover - running from a bare checkout
        return "0+unknown"


def locked(settings: Settings, identity: Identity) -> bool:
    """Whether the caller may see only that auth is required (off loopback, unauthenticated)."""
    return settings.reads_need_auth and settings.token is not None and not identity.authenticated


def check(context: AppContext) -> Health:
    """Ping the database and report the configuration."""
    with context.database.session() as session:
        crud.ping(session)
    return Health(
        status="ok",
        version=version(),
        database="ok",
        hardware=context.settings.hardware,
        auth_required=context.settings.token is not None,
    )
