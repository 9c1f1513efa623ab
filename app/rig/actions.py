"""Actions → touches: an action x is a joint trajectory through the DMPs of the teaching trajectory.

``hardware`` knows devices and ``core`` knows DMPs; neither imports the other. Here they meet:
:class:`TouchActions` fits the DMPs of the teaching trajectory (25 basis functions per joint,
3 dominant weights per joint, dx = 6) and maps an action x to a joint trajectory
(action → DMP → trajectory → rig).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from core.recognition import BasisResponses, DMPActionSpace, action_space, basis_responses, fit_dmp
from core.recognition import trajectory_for_action as dmp_trajectory
from hardware.records import TouchRecord
from hardware.rig import RigLease, TouchProgress
from hardware.teaching import PAPER_TOUCH_DURATION_S, teaching_trajectory

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class TouchActions:
    """Actions x ∈ R^6 as joint trajectories, through the DMPs of the teaching trajectory.

    Attributes:
        space: The DMP action space (x = 0 reproduces the teaching trajectory).
        dt_s: Period of the generated trajectories (the rig's control period).
        duration_s: Duration of a touch.
        responses: DMP basis responses on that time grid.
    """

    space: DMPActionSpace
    dt_s: float
    duration_s: float
    responses: BasisResponses = field(repr=False)

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
        """
        demo = (
            teaching_trajectory(dt_s=teaching_dt_s)
            if teaching is None
            else np.asarray(teaching, dtype=np.float64)
        )
        dmp = fit_dmp(demo, teaching_dt_s, n_basis=n_basis)
        space = action_space(dmp, n_dominant=n_dominant, offset_deg_per_unit=offset_deg_per_unit)
        responses = basis_responses(dmp, dt_s=dt_s, duration_s=duration_s)
        return cls(space, float(dt_s), float(duration_s), responses)

    @property
    def action_dim(self) -> int:
        """dx."""
        return self.space.action_dim

    def trajectory(self, action: npt.ArrayLike) -> FloatArray:
        """The joint trajectory of action x. Shape (T, J)."""
        return dmp_trajectory(self.space, action, responses=self.responses)

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
