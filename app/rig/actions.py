"""Actions → touches: an action x is a joint trajectory through the DMPs of the teaching trajectory.

``hardware`` knows devices and ``core`` knows DMPs; neither imports the other. Here they meet:
:class:`TouchActions` fits the DMPs of the teaching trajectory (25 basis functions per joint,
3 dominant weights per joint, dx = 6) and maps an action x to a joint trajectory
(action → DMP → trajectory → rig). With the press-depth component (:mod:`app.rig.press_depth`)
an action has one more dimension, a uniform change of the press's flexion; a model's dx says
which of the two it was trained on (:meth:`TouchActions.for_action_dim`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from app.errors import BadInputError
from app.rig.action_layout import DMP_ACTION_DIM, has_press_depth
from app.rig.press_depth import DEFAULT_DEG_PER_UNIT, PressDepth
from core.recognition import BasisResponses, DMPActionSpace, action_space, basis_responses, fit_dmp
from core.recognition import trajectory_for_action as dmp_trajectory
from core.validation import as_float_array
from hardware.records import TouchRecord
from hardware.rig import RigLease, TouchProgress
from hardware.teaching import PAPER_TOUCH_DURATION_S, teaching_trajectory

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class TouchActions:
    """Actions x ∈ R^6 (R^7 with the press depth) as joint trajectories, through the DMPs of
    the teaching trajectory.

    Attributes:
        space: The DMP action space (x = 0 reproduces the teaching trajectory).
        dt_s: Period of the generated trajectories (the rig's control period).
        duration_s: Duration of a touch.
        responses: DMP basis responses on that time grid.
        press: The press-depth component, the action's last one; None without it.
    """

    space: DMPActionSpace
    dt_s: float
    duration_s: float
    responses: BasisResponses = field(repr=False)
    press: PressDepth | None = None

    @classmethod
    def from_teaching(
        cls,
        teaching: npt.ArrayLike | None = None,
        teaching_dt_s: float = 0.02,
        *,
        dt_s: float = 0.02,
        duration_s: float = PAPER_TOUCH_DURATION_S,
        n_basis: int = 25,
        n_dominant: int = 3,
        offset_deg_per_unit: float = 1.0,
        press_depth: bool = False,
        press_deg_per_unit: float = DEFAULT_DEG_PER_UNIT,
    ) -> TouchActions:
        """Fit the DMPs of a teaching trajectory (default: the rig's synthetic demonstration).

        Args:
            teaching: Joint angles in degrees, shape (T, J), sampled every ``teaching_dt_s``.
            teaching_dt_s: Sample period of ``teaching``.
            dt_s: Period of the generated trajectories.
            duration_s: Duration of a generated touch (DMP time scaling).
            n_basis: Basis functions per joint (the paper: 25).
            n_dominant: Dominant weights per joint offset by the action (the paper: 3).
            offset_deg_per_unit: Peak joint change caused by one unit of one action component.
            press_depth: Add the press-depth component as the action's last dimension.
            press_deg_per_unit: Its flexion per unit (degrees).
        """
        demo = (
            teaching_trajectory(dt_s=teaching_dt_s)
            if teaching is None
            else np.asarray(teaching, dtype=np.float64)
        )
        dmp = fit_dmp(demo, teaching_dt_s, n_basis=n_basis)
        space = action_space(dmp, n_dominant=n_dominant, offset_deg_per_unit=offset_deg_per_unit)
        responses = basis_responses(dmp, dt_s=dt_s, duration_s=duration_s)
        press = PressDepth.for_teaching(demo, press_deg_per_unit) if press_depth else None
        return cls(space, float(dt_s), float(duration_s), responses, press)

    @classmethod
    def for_action_dim(
        cls, action_dim: int, *, dt_s: float = 0.02, duration_s: float | None = None
    ) -> TouchActions:
        """The rig's actions for a model of dx = ``action_dim``: the DMP components alone, or
        with the press depth when the model has one more dimension.

        Args:
            action_dim: The model's dx.
            dt_s: Period of the generated trajectories.
            duration_s: Duration of a touch: the one the model's training touches lasted
                (``TrainingData.touch_duration_s``); ``None`` (not recorded): the teaching
                trajectory's, :data:`hardware.teaching.PAPER_TOUCH_DURATION_S`.

        Raises:
            BadInputError: ``action_dim`` is neither.
        """
        press_depth = has_press_depth(action_dim)
        if press_depth is None:
            raise BadInputError(
                f"world: the rig's actions have dx={DMP_ACTION_DIM} (or {DMP_ACTION_DIM + 1} with "
                "the press depth) "
                f"but the model has dx={action_dim}.",
                field="world",
            )
        return cls.from_teaching(
            dt_s=dt_s,
            duration_s=PAPER_TOUCH_DURATION_S if duration_s is None else duration_s,
            press_depth=press_depth,
        )

    @property
    def action_dim(self) -> int:
        """dx: the DMP components, and the press depth's if present."""
        return self.space.action_dim + (self.press is not None)

    def trajectory(self, action: npt.ArrayLike) -> FloatArray:
        """The joint trajectory of action x. Shape (T, J).

        Raises:
            core.errors.InvalidInputError: x is not of shape (dx,).
        """
        x = as_float_array(action, "action", (self.action_dim,))
        if self.press is None:
            return dmp_trajectory(self.space, x, responses=self.responses)
        base = dmp_trajectory(self.space, x[:-1], responses=self.responses)
        return self.press.apply(base, float(x[-1]))

    def touch(
        self,
        lease: RigLease,
        action: npt.ArrayLike,
        slot: int | None = None,
        on_progress: Callable[[TouchProgress], None] | None = None,
    ) -> TouchRecord:
        """Execute action x on the leased rig (after turning ``slot`` under the finger)."""
        trajectory = self.trajectory(action)
        if slot is not None:
            lease.move_to_slot(slot)
        return lease.touch(trajectory, self.dt_s, on_progress)
