"""Waiting for a trial run through the REST API to end (app and browser tests)."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

UNFINISHED = ("queued", "running", "paused")


def wait_finished(
    fetch: Callable[[int], dict[str, Any]], trial_id: int, timeout_s: float = 60
) -> dict[str, Any]:
    """Poll ``fetch(trial_id)`` (the trial's JSON) until its status is final; return it."""
    deadline = time.monotonic() + timeout_s
    while True:
        trial = fetch(trial_id)
        if trial["status"] not in UNFINISHED:
            return trial
        assert time.monotonic() < deadline, f"trial {trial_id} still {trial['status']}"
        time.sleep(0.1)
