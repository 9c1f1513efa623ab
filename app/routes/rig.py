"""``/rig``: status, connect, home, turntable slot, emergency stop."""

from __future__ import annotations

from fastapi import APIRouter

from app.deps import ContextDep
from app.schemas import RigPublic, TurntableRequest

router = APIRouter(prefix="/rig", tags=["rig"])


@router.get("")
def rig_status(context: ContextDep) -> RigPublic:
    """Connection, state, slot, faults and which run holds the rig."""
    return context.rig.status()


@router.post("/connect")
def connect_rig(context: ContextDep) -> RigPublic:
    """Connect the devices (or recover after an emergency stop or a fault)."""
    return context.rig.connect()


@router.post("/home")
def home_rig(context: ContextDep) -> RigPublic:
    """Retract the finger and home the turntable."""
    return context.rig.home()


@router.post("/turntable")
def turn_table(body: TurntableRequest, context: ContextDep) -> RigPublic:
    """Put a slot under the finger."""
    return context.rig.turn_to(body.slot)


@router.post("/estop")
async def emergency_stop(context: ContextDep) -> RigPublic:
    """Emergency stop: works in any state, bypasses queues and locks."""
    # Called on the event loop itself, so a busy thread pool cannot delay it.
    return context.rig.estop()
