"""Joint trajectories for the finger: the limit check every touch passes before anything moves
(:func:`check_trajectory`) and the minimum-jerk moves between poses (:func:`ramp`)."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from hardware.errors import ConfigurationError, UnsafeTrajectoryError
from hardware.finger import JointConfig
from hardware.records import FloatArray


def check_trajectory(
    trajectory: npt.ArrayLike, dt_s: float, joints: Sequence[JointConfig]
) -> FloatArray:
    """Check a joint trajectory against position and velocity limits.

    Args:
        trajectory: Joint positions in degrees, one row per setpoint. Shape (T, J), T >= 2.
        dt_s: Time between setpoints.
        joints: The joints, in column order (their limits are checked).

    Returns:
        The trajectory as a float array of shape (T, J).

    Raises:
        UnsafeTrajectoryError: A position or velocity limit is broken (the message names the
            joint, the limit, the value and the first offending sample), or the shape is wrong.
    """
    names = ",".join(joint.name for joint in joints)
    array = np.array(trajectory, dtype=np.float64)  # a copy: the record freezes it
    if array.ndim != 2 or array.shape[1] != len(joints) or array.shape[0] < 2:
        raise UnsafeTrajectoryError(
            names,
            "shape",
            float("nan"),
            float(len(joints)),
            0,
            f"(expected shape (T >= 2, {len(joints)}), received {array.shape})",
        )
    if not dt_s > 0:
        raise ConfigurationError(f"dt_s: must be positive, received {dt_s}.")
    bad = np.argwhere(~np.isfinite(array))
    if bad.size:
        row, column = (int(i) for i in bad[0])
        raise UnsafeTrajectoryError(
            joints[column].name, "finite value", float("nan"), 0.0, row, "deg"
        )
    velocity = np.diff(array, axis=0) / dt_s
    for column, joint in enumerate(joints):
        values = array[:, column]
        low = np.flatnonzero(values < joint.lower_deg)
        if low.size:
            i = int(low[0])
            raise UnsafeTrajectoryError(
                joint.name, "lower position", float(values[i]), joint.lower_deg, i, "deg"
            )
        high = np.flatnonzero(values > joint.upper_deg)
        if high.size:
            i = int(high[0])
            raise UnsafeTrajectoryError(
                joint.name, "upper position", float(values[i]), joint.upper_deg, i, "deg"
            )
        fast = np.flatnonzero(np.abs(velocity[:, column]) > joint.max_velocity_deg_s)
        if fast.size:
            i = int(fast[0])
            raise UnsafeTrajectoryError(
                joint.name,
                "velocity",
                float(abs(velocity[i, column])),
                joint.max_velocity_deg_s,
                i + 1,
                "deg/s",
            )
    return array


def ramp(
    start_deg: npt.ArrayLike,
    end_deg: npt.ArrayLike,
    max_velocity_deg_s: npt.ArrayLike,
    dt_s: float,
) -> FloatArray:
    """A minimum-jerk move whose peak joint velocity stays below ``max_velocity_deg_s``.

    Returns:
        Setpoints from start to end inclusive. Shape (T, J), T >= 2.
    """
    start = np.asarray(start_deg, dtype=np.float64)
    end = np.asarray(end_deg, dtype=np.float64)
    vmax = np.asarray(max_velocity_deg_s, dtype=np.float64)
    # The minimum-jerk profile peaks at 1.875 times the mean velocity.
    duration = float(np.max(1.875 * np.abs(end - start) / vmax))
    n = max(2, math.ceil(duration / dt_s) + 1)
    s = np.linspace(0.0, 1.0, n)
    blend = s**3 * (10.0 - 15.0 * s + 6.0 * s**2)
    return np.asarray(start[None, :] + (end - start)[None, :] * blend[:, None])
