"""Free-form JSON a client sends (a model document, a touch's trajectory record), checked
before it is used or stored: finite numbers, valid text of bounded length, bounded nesting.

Python's ``json`` reads the non-standard ``NaN``, ``Infinity`` and ``1e400`` (→ inf) and turns
a ``\\ud800`` escape into a lone surrogate; none of them can be written back as strict JSON or
UTF-8, so a value that holds one would be stored and then fail every read.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from app.documents.errors import DocumentError

Path = tuple[str | int, ...]


def check_json_values(value: Any, where: str, *, max_depth: int, max_text: int) -> None:
    """Check every value of a parsed JSON value, without recursion (a value nested deeper
    than any Python stack is refused like one nested a level too deep).

    Args:
        value: The parsed JSON (``dict``, ``list``, ``str``, numbers, ``bool``, ``None``).
        where: What it is, to start the messages (``"model document"``).
        max_depth: Deepest list or object allowed (``value`` itself is level 0).
        max_text: Longest string (value or field name), in characters.

    Raises:
        DocumentError: A number that is not finite, text over ``max_text`` characters or not
            valid Unicode, or nesting deeper than ``max_depth``; ``column`` is the field's
            path (``training_data.actions[3][0]``).
    """
    if not isinstance(value, Mapping | list):
        _check_scalar(value, (), where, max_text)
        return
    pending: list[tuple[Path, Mapping[str, Any] | list[Any]]] = [((), value)]
    while pending:
        path, container = pending.pop()
        if len(path) > max_depth:
            raise DocumentError(
                f"{where}: {dotted(path)} is nested deeper than {max_depth} levels.",
                column=dotted(path),
            )
        items = container.items() if isinstance(container, Mapping) else enumerate(container)
        for key, item in items:
            if isinstance(key, str):
                _check_scalar(key, (*path, key), where, max_text)
            if isinstance(item, Mapping | list):
                pending.append(((*path, key), item))
            else:
                _check_scalar(item, (*path, key), where, max_text)


def _check_scalar(value: Any, path: Path, where: str, max_text: int) -> None:
    if isinstance(value, float) and not math.isfinite(value):
        raise DocumentError(
            f"{where}: {dotted(path) or 'the value'} is a non-finite number ({value}).",
            column=dotted(path),
        )
    if isinstance(value, str):
        if len(value) > max_text:
            raise DocumentError(
                f"{where}: {dotted(path) or 'the value'} has {len(value)} characters; at most "
                f"{max_text} are allowed.",
                column=dotted(path),
            )
        if not value.isascii():
            try:
                value.encode("utf-8")
            except UnicodeEncodeError:
                raise DocumentError(
                    f"{where}: {dotted(path) or 'the value'} is not valid Unicode (a lone "
                    "surrogate escape).",
                    column=dotted(path),
                ) from None


def dotted(path: Path) -> str:
    """A field's path as ``training_data.actions[3][0]`` (empty for the value itself)."""
    text = "".join(f"[{key}]" if isinstance(key, int) else f".{key}" for key in path)
    return text.removeprefix(".")
