"""What a server-driven trial touches with: a touch source and the touch it returns."""

from __future__ import annotations

from typing import Protocol

import numpy as np

from core.evaluation import Touch
from core.validation import FloatArray

__all__ = ["Touch", "TouchSource"]


class TouchSource(Protocol):
    """Something that touches the target object (a :class:`core.evaluation.trial_engine.TouchSource`
    that holds something to release)."""

    def touch(self, action: FloatArray, rng: np.random.Generator) -> Touch:
        """Perform ``action`` (dx,) and return the touch."""
        ...

    def close(self) -> None:
        """Release what the source holds."""
        ...
