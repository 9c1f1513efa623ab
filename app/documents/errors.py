"""The error of every document: a malformed training CSV, model document or recorded field."""

from __future__ import annotations

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
