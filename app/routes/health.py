"""``GET /health``."""

from __future__ import annotations

from fastapi import APIRouter

from app.deps import ContextDep
from app.schemas import Health
from app.services import health

router = APIRouter(tags=["health"])


@router.get("/health")
def get_health(context: ContextDep) -> Health:
    """Liveness and configuration summary."""
    return health.check(context)
