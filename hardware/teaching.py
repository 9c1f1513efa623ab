"""The teaching trajectory of a touch: press into the object, slide across it, lift off.

In the paper a human demonstrated the touch through a data glove (14.4 s). This is a synthetic
stand-in with the same structure, for the simulated rig and as a starting point on a real one:
FFJ3 (flexion) presses the fingertip in, FFJ4 (abduction) sweeps it sideways while pressed,
then both return to the start. Every phase is a minimum-jerk blend, so velocities are smooth and
small (peak ~20 °/s with the defaults).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from hardware.errors import ConfigurationError

FloatArray = npt.NDArray[np.float64]

PAPER_TOUCH_DURATION_S = 14.4


def _blend(u: FloatArray, start: float, end: float) -> FloatArray:
    """0 before ``start``, 1 after ``end``, minimum-jerk in between (u is normalised time)."""
    z = np.clip((u - start) / (end - start), 0.0, 1.0)
    return np.asarray(z**3 * (10.0 - 15.0 * z + 6.0 * z**2))


def teaching_trajectory(
    dt_s: float = 0.02,
    duration_s: float = PAPER_TOUCH_DURATION_S,
    press_deg: float = 24.0,
    sweep_deg: float = 8.0,
) -> FloatArray:
    """The demonstration, sampled every ``dt_s``.

    Args:
        dt_s: Sample period.
        duration_s: Length of the touch.
        press_deg: FFJ3 flexion while pressing (objects are met at ~18-21°).
        sweep_deg: FFJ4 sweeps from -sweep to +sweep while pressing.

    Returns:
        Joint angles in degrees, columns (FFJ3, FFJ4). Shape (T, 2), T = duration / dt + 1.
    """
    if not dt_s > 0 or not duration_s > 0:
        raise ConfigurationError(
            f"dt_s and duration_s must be positive, received {dt_s} and {duration_s}."
        )
    n = round(duration_s / dt_s) + 1
    if n < 10:
        raise ConfigurationError(
            f"a teaching trajectory needs at least 10 samples, received {n} "
            f"(duration {duration_s} s at {dt_s} s)."
        )
    u = np.linspace(0.0, 1.0, n)
    flexion = press_deg * (_blend(u, 0.02, 0.20) - _blend(u, 0.82, 0.97))
    flexion = flexion + 1.5 * (_blend(u, 0.30, 0.50) - _blend(u, 0.55, 0.75))
    abduction = sweep_deg * (
        -_blend(u, 0.05, 0.20) + 2.0 * _blend(u, 0.25, 0.80) - _blend(u, 0.85, 0.98)
    )
    return np.stack([flexion, abduction], axis=1)
