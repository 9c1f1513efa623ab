"""Clocks: real time for hardware, scaled or virtual time for simulations.

The rig paces its control loop on a :class:`Clock`; simulated devices read the same clock, so a
simulation can run faster than real time (:class:`ScaledClock`) or, in a single thread, as fast
as the computer allows (:class:`VirtualClock`: time only moves when someone sleeps).
"""

from __future__ import annotations

import threading
import time
from typing import Protocol


class Clock(Protocol):
    """What the rig and the simulators need from a clock."""

    def now(self) -> float:
        """Seconds since an arbitrary origin (monotonic)."""
        ...

    def sleep(self, duration_s: float) -> None:
        """Wait ``duration_s`` seconds of this clock's time (no-op if <= 0)."""
        ...


class SystemClock:
    """Real time (``time.monotonic``)."""

    def now(self) -> float:
        """Monotonic seconds."""
        return time.monotonic()

    def sleep(self, duration_s: float) -> None:
        """``time.sleep``."""
        if duration_s > 0:
            time.sleep(duration_s)


class ScaledClock:
    """Real time multiplied by ``speed``: at speed 20 a 14 s touch takes 0.7 s.

    Args:
        speed: Simulated seconds per real second (> 0).
    """

    def __init__(self, speed: float = 1.0) -> None:
        if not speed > 0:
            raise ValueError(f"speed: must be positive, received {speed}.")
        self.speed = float(speed)
        self._origin = time.monotonic()

    def now(self) -> float:
        """Simulated seconds since the clock was made."""
        return (time.monotonic() - self._origin) * self.speed

    def sleep(self, duration_s: float) -> None:
        """Sleep ``duration_s / speed`` real seconds."""
        if duration_s > 0:
            time.sleep(duration_s / self.speed)


class VirtualClock:
    """Time that advances only when :meth:`sleep` is called (single-threaded simulations).

    Deterministic and as fast as the computation; not for use with devices running in other
    threads (the pseudo-terminal emulators), which need a :class:`ScaledClock`.
    """

    def __init__(self, start_s: float = 0.0) -> None:
        self._now = float(start_s)
        self._lock = threading.Lock()

    def now(self) -> float:
        """The current virtual time."""
        with self._lock:
            return self._now

    def sleep(self, duration_s: float) -> None:
        """Advance the virtual time by ``duration_s``."""
        if duration_s > 0:
            with self._lock:
                self._now += float(duration_s)
