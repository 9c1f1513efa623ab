"""``GET /health``."""

from __future__ import annotations

from fastapi import APIRouter

from app.deps import ContextDep, IdentityDep
from app.schemas import Health, HealthLocked
from app.services import health

router = APIRouter(tags=["health"])


@router.get("/health")
def get_health(context: ContextDep, identity: IdentityDep) -> Health | HealthLocked:
    """Liveness and configuration summary; off loopback without the token or a session, only
    ``{"auth_required": true}``."""
    if health.locked(context.settings, identity):
        return HealthLocked()
    return health.check(context)
