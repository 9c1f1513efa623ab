"""A badly scaled quadratic (condition 1e4) for the optimiser tests.

L-BFGS-B needs many iterations to reach its tolerance on it, which is what the tests of the
memory and of the stall stop want to see.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from core.gp.hyperparameter_fit import minimize_free

SIZE = 30
SCALES = np.logspace(0, 4, SIZE)


class BadlyScaledQuadratic:
    """``0.5 Σ s_i x_i²`` with scales ``s`` from 1 to 1e4; its optimum is 0 at ``x = 0``."""

    def value_and_gradient(self, x: np.ndarray) -> tuple[float, np.ndarray]:
        return float(0.5 * np.sum(SCALES * x**2)), SCALES * x


def minimize_quadratic(**options: Any) -> Any:
    """:func:`~core.gp.hyperparameter_fit.minimize_free` from ``x = 1`` in the box [-10, 10]^30
    (10 000 iterations at most, tolerances 1e-15 and 1e-12), with ``options`` passed on."""
    return minimize_free(
        BadlyScaledQuadratic(),
        np.ones(SIZE),
        np.ones(SIZE, dtype=bool),
        np.full(SIZE, -10.0),
        np.full(SIZE, 10.0),
        10_000,
        1e-15,
        1e-12,
        **options,
    )
