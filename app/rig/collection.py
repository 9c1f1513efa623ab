"""The collection loop: every object touched with every action of a design, on a leased rig.

:func:`iter_collect` is a generator (one event per touch), so callers stream progress, persist
as they go and stop; :func:`since_first_touch` dates each touch of a collection from its first.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable, Iterator
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
        time_s: When the touch was made: seconds from the start of the collection's first
            touch to the start of this one, on the rig's clock (``record.started_s``); ``None``
            when the rig did not record it.
    """

    index: int
    total: int
    object_name: str
    slot: int
    action: FloatArray
    record: TouchRecord
    placement: int | None = None
    time_s: float | None = None


def since_first_touch(touches: Iterable[CollectedTouch]) -> Iterator[CollectedTouch]:
    """The touches with ``time_s``: their ``record.started_s`` minus the first touch's.

    The slow drift of the sensor and the room is shared by touches made close together; these
    times let the fit estimate it (:mod:`core.gp.drift_effect`). A touch whose record (or the
    first touch's) has no ``started_s`` gets ``time_s = None``.

    Args:
        touches: A collection's touches, in the order they were made (consumed lazily).

    Yields:
        Each touch, dated.
    """
    origin_s: float | None = None
    first = True
    for touch in touches:
        started_s = touch.record.started_s
        if first:
            origin_s, first = started_s, False
        time_s = None if started_s is None or origin_s is None else started_s - origin_s
        yield dataclasses.replace(touch, time_s=time_s)


def iter_collect(
    lease: RigLease,
    actions: TouchActions,
    slots: dict[str, int],
    action_design: npt.ArrayLike,
    order_seed: int = 0,
) -> Iterator[CollectedTouch]:
    """Touch every object with every action of a design, turning the table between touches.

    It runs in rounds: round t touches every object in turn, object l with action π_l(t) of
    its own random permutation π_l of the design (drawn from ``order_seed``). Every object still
    gets every action once, which is all the shared-design (Kronecker) structure of
    docs/method.md needs (a set of actions per object, not an order). What the permutations
    avoid is touching one action on every object in a row: the slow drift of the sensor and of
    the room over those minutes is then shared by that action's touches, so the fit learns the
    drift as part of the response to the action, with a noise variance too small for what a
    later touch at that action shows, and the recogniser trusts it (docs/calibration.md,
    "Drift and the collection order").

    Args:
        lease: A lease on a connected rig.
        actions: The action → trajectory map.
        slots: Object name → slot.
        action_design: The actions. Shape (M, dx).
        order_seed: Seed of the objects' permutations (the same seed, the same order).

    Yields:
        One :class:`CollectedTouch` per touch, as soon as it is recorded, dated from the first
        (:func:`since_first_touch`).
    """
    design = np.asarray(action_design, dtype=np.float64)
    if design.ndim != 2 or design.shape[1] != actions.action_dim:
        raise ConfigurationError(
            f"action_design: expected shape (M, {actions.action_dim}), received {design.shape}."
        )
    if not slots:
        raise ConfigurationError("slots: at least one object is needed.")
    yield from since_first_touch(_rounds(lease, actions, slots, design, order_seed))


def _rounds(
    lease: RigLease,
    actions: TouchActions,
    slots: dict[str, int],
    design: FloatArray,
    order_seed: int,
) -> Iterator[CollectedTouch]:
    """:func:`iter_collect`'s touches, undated."""
    n_actions = design.shape[0]
    total = n_actions * len(slots)
    rng = np.random.default_rng(order_seed)
    orders = [rng.permutation(n_actions) for _ in slots]
    index = 0
    for turn in range(n_actions):
        for (name, slot), order in zip(slots.items(), orders, strict=True):
            action = design[order[turn]]
            record = actions.touch(lease, action, slot=slot)
            yield CollectedTouch(index, total, name, slot, action.copy(), record)
            index += 1
