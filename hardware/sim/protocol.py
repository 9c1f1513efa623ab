"""A transport that checks a conversation byte for byte (PyMeasure's ``expected_protocol``).

Give it the exchanges a driver must have with its device — what the driver writes and what the
device answers — and hand it to the driver instead of a port. Any write that differs from the
next expected one fails at once, naming both; :meth:`ExpectedProtocol.assert_done` fails if the
driver stopped early.

>>> link = ExpectedProtocol([(None, b"hello\\r\\n"), (b"?", b"<Idle|MPos:0.000>\\r\\n")])
"""

from __future__ import annotations

import time
from collections.abc import Sequence

from hardware.transport import Transport

Exchange = tuple[bytes | None, bytes | None]
"""``(written, answer)``: ``None`` written means the answer is there before any write (a banner);
``None`` answer means the device stays silent."""


class ProtocolMismatchError(AssertionError):
    """The driver wrote something else than the protocol expects."""


class ExpectedProtocol(Transport):
    """A fake transport replaying a scripted conversation.

    Writes may arrive in pieces; they are matched against the expected bytes as they come.

    Args:
        exchanges: The conversation, in order.
        name: Name used in messages.
    """

    def __init__(self, exchanges: Sequence[Exchange], name: str = "expected protocol") -> None:
        super().__init__(name)
        self._exchanges = list(exchanges)
        self._index = 0
        self._matched = 0  # bytes of the current expected write matched so far
        self._input = bytearray()
        self._open = True  # handed over ready, like an opened port
        self.written = bytearray()
        self.flushes = 0
        self._release_unprompted()

    def _release_unprompted(self) -> None:
        while self._index < len(self._exchanges) and self._exchanges[self._index][0] is None:
            answer = self._exchanges[self._index][1]
            if answer:
                self._input.extend(answer)
            self._index += 1

    @property
    def is_open(self) -> bool:
        """Whether the transport is open."""
        return self._open

    def open(self) -> None:
        """Open (nothing to do)."""
        self._open = True

    def close(self) -> None:
        """Close."""
        self._open = False

    def _write(self, data: bytes) -> None:
        self.written.extend(data)
        for byte in data:
            if self._index >= len(self._exchanges):
                raise ProtocolMismatchError(
                    f"{self.name}: unexpected write {data!r} after the end of the conversation."
                )
            expected = self._exchanges[self._index][0]
            assert expected is not None
            if byte != expected[self._matched]:
                raise ProtocolMismatchError(
                    f"{self.name}: exchange {self._index}: expected {expected!r}, the driver "
                    f"wrote {bytes(expected[: self._matched]) + bytes([byte])!r}..."
                )
            self._matched += 1
            if self._matched == len(expected):
                answer = self._exchanges[self._index][1]
                if answer:
                    self._input.extend(answer)
                self._index += 1
                self._matched = 0
                self._release_unprompted()

    def read(self, max_bytes: int, timeout_s: float) -> bytes:
        """Answers released so far; an empty read after ``timeout_s`` (no real wait beyond a
        token sleep, so timeouts are fast in tests)."""
        if self._input:
            chunk = bytes(self._input[:max_bytes])
            del self._input[:max_bytes]
            return chunk
        if timeout_s > 0:
            time.sleep(min(timeout_s, 0.001))
            self._clock_offset += timeout_s
        return b""

    _clock_offset = 0.0

    def now(self) -> float:
        """A clock that jumps over the timeouts of empty reads."""
        return time.monotonic() + self._clock_offset

    def reset_input_buffer(self) -> None:
        """Drop the answers not yet read."""
        self.flushes += 1
        self._input.clear()

    @property
    def done(self) -> bool:
        """Whether every exchange happened."""
        return self._index >= len(self._exchanges) and self._matched == 0

    def assert_done(self) -> None:
        """Fail unless the whole conversation took place and every answer was read."""
        if not self.done:
            missing = self._exchanges[self._index]
            raise ProtocolMismatchError(
                f"{self.name}: the driver stopped at exchange {self._index} of "
                f"{len(self._exchanges)}; next expected write: {missing[0]!r}."
            )
