"""The error of every document: a malformed training CSV, model document or recorded field."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from core.errors import InvalidInputError


class DocumentError(InvalidInputError):
    """A CSV or model document is malformed; says where (row, column, field) and why.

    Attributes:
        row: 1-based line number in the file (the header is line 1), if the problem is in a row.
        column: Column or field name, if known.
    """

    def __init__(self, message: str, row: int | None = None, column: str | None = None) -> None:
        super().__init__(message)
        self.row = row
        self.column = column


def read_kind(
    field: Any, name: str, key: str, kinds: Sequence[str], where: str
) -> tuple[Mapping[str, Any], Any]:
    """Check a recorded field that is an object whose ``key`` names its kind, one of ``kinds``.

    Args:
        field: The field's JSON value (not ``None``: an absent field is the caller's case).
        name: The field's name in the document (``noise_model``, ``posterior``).
        key: The member that names the kind (``kind``, ``structure``).
        kinds: The kinds allowed.
        where: What holds the field, to start error messages (``"model document"``).

    Returns:
        The field as a mapping, and its kind (an element of ``kinds``, typed as the caller's).

    Raises:
        DocumentError: ``field`` is not an object (``column`` ``name``) or its kind is not one of
            ``kinds`` (``column`` ``name.key``).
    """
    if not isinstance(field, Mapping):
        raise DocumentError(
            f"{where}: '{name}' must be an object, found {type(field).__name__}.", column=name
        )
    kind = field.get(key)
    if kind not in kinds:
        raise DocumentError(
            f"{where}: {name}.{key} must be one of {', '.join(kinds)}, found {kind!r}.",
            column=f"{name}.{key}",
        )
    return field, kind
