"""A clock the test moves by hand, for the session store and the limit on wrong tokens."""

from __future__ import annotations


class ManualClock:
    """Called like ``time.monotonic``; returns :attr:`now_s`, which the test sets or advances."""

    def __init__(self, now_s: float = 1000.0) -> None:
        self.now_s = now_s

    def __call__(self) -> float:
        return self.now_s
