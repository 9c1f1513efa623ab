"""The press-depth action component: one more action dimension that presses deeper or shallower.

A placement tilts the object a little, so every press of that placement reaches a different
depth than commanded (docs/calibration.md, "The input shift"). The model can only describe that
as a shift of the *action* if some direction of the action space moves the press the way a
tilt does: a uniform change of the flexion angle over the whole press. None of the DMP
components does that (each moves the joints around one basis function's time), so the
placement's effect, which depends strongly on the action, ends up as unexplained noise shared by
a trial's touches. The press-depth component x_p adds ``deg_per_unit · x_p · e(q)`` to the
pressing joint, where the envelope e rises from 0 to 1 as the joint flexes from ``start_deg`` to
``full_deg``: zero while the finger approaches, constant while it presses, so it changes where
the press lands and nothing else. A collection draws x_p like every other component, and the
input shift estimated from its placement pairs then learns the placement's tilt along x_p
(docs/calibration.md, "What a placement covariance could achieve, and a press-depth input").
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from app.errors import BadInputError
from app.rig.action_layout import DMP_ACTION_DIM, has_press_depth

FloatArray = npt.NDArray[np.float64]

#: Envelope start and full, as fractions of the teaching trajectory's peak flexion: the offset
#: is off during the approach and complete before the finger meets the object.
ENVELOPE_FRACTIONS = (0.47, 0.70)

#: Degrees of flexion per unit of x_p: the size of a placement's tilt on the simulated rig, so a
#: design's spread of x_p reaches a few tilts either side.
DEFAULT_DEG_PER_UNIT = 0.25


def rig_action_dim(action_dim: int) -> int:
    """dx of the rig's actions for a model of dx = ``action_dim``: that dx if the rig makes it,
    else the DMP components' (the dx an error message names)."""
    return DMP_ACTION_DIM if has_press_depth(action_dim) is None else int(action_dim)


@dataclass(frozen=True)
class PressDepth:
    """The press-depth component of an action.

    Attributes:
        deg_per_unit: Flexion added per unit of x_p while pressing (degrees).
        start_deg: Joint angle where the envelope starts to rise (degrees).
        full_deg: Joint angle from which the whole offset applies (degrees, > ``start_deg``).
        joint: Column of the pressing joint in a trajectory.
    """

    deg_per_unit: float
    start_deg: float
    full_deg: float
    joint: int = 0

    def __post_init__(self) -> None:
        if not np.isfinite(self.deg_per_unit) or self.deg_per_unit <= 0.0:
            raise BadInputError(
                f"press_depth: deg_per_unit must be > 0, received {self.deg_per_unit}.",
                field="press_depth",
            )
        if not (np.isfinite(self.start_deg) and self.full_deg > self.start_deg):
            raise BadInputError(
                f"press_depth: the envelope needs start_deg < full_deg, received "
                f"{self.start_deg} and {self.full_deg}.",
                field="press_depth",
            )

    @classmethod
    def for_teaching(
        cls, teaching: FloatArray, deg_per_unit: float = DEFAULT_DEG_PER_UNIT, joint: int = 0
    ) -> PressDepth:
        """The component for a teaching trajectory: its envelope from the joint's peak flexion.

        Args:
            teaching: Joint angles in degrees. Shape (T, J).
            deg_per_unit: Flexion per unit of x_p.
            joint: The pressing joint's column.
        """
        peak = float(np.max(teaching[:, joint]))
        low, high = ENVELOPE_FRACTIONS
        return cls(float(deg_per_unit), low * peak, high * peak, joint)

    def envelope(self, angle_deg: FloatArray) -> FloatArray:
        """e(q): 0 below ``start_deg``, 1 from ``full_deg``, linear between. Shape of the input."""
        ramp = (angle_deg - self.start_deg) / (self.full_deg - self.start_deg)
        return np.asarray(np.clip(ramp, 0.0, 1.0), dtype=np.float64)

    def apply(self, trajectory: FloatArray, value: float) -> FloatArray:
        """The trajectory with x_p = ``value`` applied (a new array). Shape (T, J)."""
        out = np.array(trajectory, dtype=np.float64)
        joint = out[:, self.joint]
        out[:, self.joint] = joint + self.deg_per_unit * value * self.envelope(joint)
        return out
