"""The web app on a real socket in tests: uvicorn in a thread, and its log lines caught."""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable

import uvicorn


def start_in_thread(
    server: uvicorn.Server, run: Callable[[], object] | None = None, timeout_s: float = 60
) -> threading.Thread:
    """Run ``run`` (default: ``server.run``) in a daemon thread; return once ``server`` listens.

    Raises:
        AssertionError: The server stopped, or did not listen within ``timeout_s`` (it is then
            told to exit).
    """
    thread = threading.Thread(target=run or server.run, daemon=True)
    thread.start()
    deadline = time.monotonic() + timeout_s
    try:
        while not server.started:
            assert thread.is_alive(), "the server stopped while starting"
            assert time.monotonic() < deadline, f"the server did not start within {timeout_s:g} s"
            time.sleep(0.02)
    except AssertionError:
        server.should_exit = True
        thread.join(timeout=30)
        raise
    return thread


class LogRecords(logging.Handler):
    """Keeps every log record it is handed (all levels)."""

    def __init__(self) -> None:
        super().__init__(level=logging.DEBUG)
        self.records: list[logging.LogRecord] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.records.append(record)

    @property
    def lines(self) -> list[str]:
        """The records' messages, in order."""
        return [record.getMessage() for record in self.records]
