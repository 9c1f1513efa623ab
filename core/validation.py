"""Shape and finiteness checks used at the public entry points of :mod:`core`."""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

from core.errors import InvalidInputError

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]


def as_float_array(
    value: Any,
    name: str,
    shape: tuple[int | None, ...],
) -> FloatArray:
    """Convert ``value`` to a finite float64 array of the given shape.

    Args:
        value: Anything :func:`numpy.asarray` accepts.
        name: Name of the argument, used in the error message.
        shape: Expected shape; ``None`` entries match any length.

    Raises:
        InvalidInputError: Wrong number of dimensions, wrong length, or NaN/inf entries.
    """
    try:
        array = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InvalidInputError(f"{name}: could not be read as numbers ({exc}).") from exc
    expected = "(" + ", ".join("any" if s is None else str(s) for s in shape) + ")"
    if array.ndim != len(shape) or any(
        want is not None and got != want for got, want in zip(array.shape, shape, strict=True)
    ):
        raise InvalidInputError(f"{name}: expected shape {expected}, received {array.shape}.")
    if not np.all(np.isfinite(array)):
        bad = np.argwhere(~np.isfinite(array))[0]
        where = ", ".join(str(int(i)) for i in bad)
        raise InvalidInputError(
            f"{name}: contains a non-finite value (NaN or inf) at index [{where}]."
        )
    return array


def require_positive(value: FloatArray, name: str) -> None:
    """Raise :class:`InvalidInputError` unless every entry of ``value`` is > 0."""
    if np.any(value <= 0):
        raise InvalidInputError(f"{name}: every entry must be positive, received {value}.")


def store_read_only(instance: object, **arrays: npt.NDArray[Any]) -> None:
    """Set fields of a frozen dataclass (from its ``__post_init__``) to read-only arrays.

    The checked arrays replace what the caller passed and cannot be written through afterwards,
    so a frozen record stays what it was checked to be (its caller's array is not locked when
    the check copied it).

    Args:
        instance: The frozen dataclass being initialised.
        **arrays: Field name → its checked array.
    """
    for name, array in arrays.items():
        array.flags.writeable = False
        object.__setattr__(instance, name, array)
