"""Central finite differences, for the gradient checks of the core tests."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np


def central_differences(
    function: Callable[[np.ndarray], float], point: np.ndarray, step: float = 1e-6
) -> np.ndarray:
    """(f(x + h e_i) - f(x - h e_i)) / 2h for every coordinate i of a 1-D ``point``."""
    numeric = np.empty(point.shape, dtype=np.float64)
    for i in range(point.size):
        up, down = point.copy(), point.copy()
        up[i] += step
        down[i] -= step
        numeric[i] = (function(up) - function(down)) / (2 * step)
    return numeric
