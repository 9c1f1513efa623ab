"""What a server-driven trial touches with: a touch source and the touch it returns."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from core.validation import FloatArray


@dataclass(frozen=True)
class Touch:
    """One touch: the action performed (dx,), the observation (dy,), optional trajectory."""

    action: FloatArray
    observation: FloatArray
    trajectory: dict[str, Any] | None = None


class TouchSource(Protocol):
    """Something that touches the target object."""

    def touch(self, action: FloatArray, rng: np.random.Generator) -> Touch:
        """Perform ``action`` (dx,) and return the touch."""
        ...

    def close(self) -> None:
        """Release what the source holds."""
        ...
