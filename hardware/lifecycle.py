"""One context-manager protocol for the objects that hold a device, a port or a lease.

A transport closes its port, an emulator stops serving, a lease is given back, a simulated rig
closes everything at the end of a ``with`` block: each says only *what* ending (and, where
needed, beginning) means; the protocol itself is written once, here.
"""

from __future__ import annotations

from types import TracebackType
from typing import Self


class WithBlock:
    """A context manager: ``with x:`` calls :meth:`_begin`, yields ``x``, then :meth:`_end`.

    :meth:`_end` runs whether or not the block raised, and the exception (if any) propagates.
    """

    def _begin(self) -> None:
        """What entering a ``with`` block does first (by default nothing)."""

    def _end(self) -> None:
        """What leaving a ``with`` block does (close, stop, release)."""
        raise NotImplementedError(f"{type(self).__name__} does not say how a with-block ends")

    def __enter__(self) -> Self:
        self._begin()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        self._end()
