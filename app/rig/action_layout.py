"""The layout of the rig's actions: the DMP components, and the press depth after them.

Kept apart from :mod:`app.rig.press_depth` (which maps the press depth onto a trajectory) so that a
fit from the command line can ask which action dimensions a placement shifts without loading the
web stack.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from core.errors import InvalidInputError

#: dx of the rig's DMP components alone (2 joints × 3 dominant weights); the press depth adds one.
DMP_ACTION_DIM = 6


def has_press_depth(action_dim: int) -> bool | None:
    """Whether actions of dx = ``action_dim`` carry the press depth: False for the DMP
    components alone, True for those and the press depth, None for a dx the rig cannot make."""
    return {DMP_ACTION_DIM: False, DMP_ACTION_DIM + 1: True}.get(int(action_dim))


#: Which action dimensions a fit lets a placement shift (the input shift, docs/calibration.md):
#: ``"auto"`` the press depth alone when the actions are the rig's with it (dx = 7), every
#: dimension otherwise; ``"all"`` every dimension.
SHIFT_ALONG = ("auto", "all")


def shift_dimensions(action_dim: int, along: str = "auto") -> npt.NDArray[np.int64] | None:
    """The action dimensions the input shift is estimated along (``None``: all of them).

    A placement tilts the object, so its presses land deeper or shallower: on the rig's actions
    with the press depth that is the press-depth component, the last one. The DMP's shape
    components each move the joints around one basis function's time, which no tilt does
    (docs/calibration.md, "The shift along the press depth only").

    Raises:
        InvalidInputError: ``along`` not one of :data:`SHIFT_ALONG`.
    """
    if along not in SHIFT_ALONG:
        raise InvalidInputError(
            f"shift_along: expected one of {list(SHIFT_ALONG)}, received {along!r}."
        )
    if along == "auto" and has_press_depth(action_dim):
        return np.array([int(action_dim) - 1], dtype=np.int64)
    return None
