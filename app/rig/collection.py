"""The collection loop: every object touched with every action of a design, on a leased rig.

:func:`iter_collect` is a generator (one event per touch), so callers stream progress, persist
as they go and stop.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from app.rig.actions import TouchActions
from hardware.errors import ConfigurationError
from hardware.records import TouchRecord
from hardware.rig import RigLease

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class CollectedTouch:
    """One touch of a collection.

    Attributes:
        index: Position in the collection (0-based).
        total: Number of touches planned.
        object_name: The object touched.
        slot: Its slot.
        action: x. Shape (dx,).
        record: What the rig recorded; ``record.observation`` is y.
        placement: Which placement of its object the touch met (0, 1, …), when the collection
            recorded placements; ``None`` when every touch met its own.
    """

    index: int
    total: int
    object_name: str
    slot: int
    action: FloatArray
    record: TouchRecord
    placement: int | None = None


def iter_collect(
    lease: RigLease,
    actions: TouchActions,
    slots: dict[str, int],
    action_design: npt.ArrayLike,
) -> Iterator[CollectedTouch]:
    """Touch every object with every action of a design, turning the table between touches.

    The order is action-major (each action on every object, as the turntable makes natural),
    which also gives the shared-action-design (Kronecker) structure of docs/method.md.

    Args:
        lease: A lease on a connected rig.
        actions: The action → trajectory map.
        slots: Object name → slot.
        action_design: The actions. Shape (M, dx).

    Yields:
        One :class:`CollectedTouch` per touch, as soon as it is recorded.
    """
    design = np.asarray(action_design, dtype=np.float64)
    if design.ndim != 2 or design.shape[1] != actions.action_dim:
        raise ConfigurationError(
            f"action_design: expected shape (M, {actions.action_dim}), received {design.shape}."
        )
    if not slots:
        raise ConfigurationError("slots: at least one object is needed.")
    total = design.shape[0] * len(slots)
    index = 0
    for action in design:
        for name, slot in slots.items():
            record = actions.touch(lease, action, slot=slot)
            yield CollectedTouch(index, total, name, slot, action.copy(), record)
            index += 1
