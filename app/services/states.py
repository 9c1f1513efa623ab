"""The run state machine shared by trials and collections (DESIGN.md "Run states").

``queued → running ⇄ paused → completed | stopped | aborted | failed``.
"""

from __future__ import annotations

from typing import Literal

from app.errors import ConflictError

Action = Literal["pause", "resume", "stop", "abort"]

ACTIVE = frozenset({"queued", "running", "paused"})
TERMINAL = frozenset({"completed", "stopped", "aborted", "failed"})

TRANSITIONS: dict[str, frozenset[str]] = {
    "queued": frozenset({"running", "stopped", "aborted", "failed"}),
    "running": frozenset({"paused", "completed", "stopped", "aborted", "failed"}),
    "paused": frozenset({"running", "completed", "stopped", "aborted", "failed"}),
}

#: The state each control action leads to.
ACTION_TARGET: dict[Action, str] = {
    "pause": "paused",
    "resume": "running",
    "stop": "stopped",
    "abort": "aborted",
}

#: The states each control action may be taken from.
ACTION_FROM: dict[Action, tuple[str, ...]] = {
    "pause": ("running",),
    "resume": ("paused",),
    "stop": ("queued", "running", "paused"),
    "abort": ("queued", "running", "paused"),
}


def can_transition(current: str, target: str) -> bool:
    """Whether ``current → target`` is allowed."""
    return target in TRANSITIONS.get(current, frozenset())


def check_action(label: str, current: str, action: Action) -> str:
    """The state ``action`` leads to from ``current``.

    Raises:
        ConflictError: (409) the action is not allowed now; the body carries ``current_state``.
    """
    if current not in ACTION_FROM[action]:
        allowed = ", ".join(ACTION_FROM[action])
        raise ConflictError(
            f"Cannot {action} {label}: it is {current} ({action} is allowed from: {allowed}).",
            current_state=current,
        )
    return ACTION_TARGET[action]
