"""Dashboard sessions: random ids issued by the server, kept in memory with an expiry.

The cookie holds the session id, never the token. The store keeps only a SHA-256 digest of each
id, so a memory dump of the store is no sign-in. A session ends after ``ttl_s`` without use (each
authenticated request renews it: an open dashboard polls, so it stays signed in while it is
open), at sign-out, and when the server restarts (the dashboard then asks for the token again).
The cookie itself has no ``Max-Age``: it goes when the browser closes.
"""

from __future__ import annotations

import hashlib
import secrets
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta

#: Name of the session cookie.
SESSION_COOKIE = "activetouch_session"
#: Most sessions kept at once; the oldest is dropped beyond it (a sign-in loop cannot grow it).
MAX_SESSIONS = 1000


@dataclass(frozen=True)
class Session:
    """A signed-in session: its id (for the cookie, shown once) and when it expires unless used."""

    session_id: str
    expires_at: datetime


def _digest(session_id: str) -> str:
    return hashlib.sha256(session_id.encode("utf-8", "surrogatepass")).hexdigest()


class SessionStore:
    """Sessions in memory; thread-safe.

    Args:
        ttl_s: How long a session lives without use, in seconds (> 0).
        clock: Monotonic clock in seconds (tests pass their own).
        max_sessions: Most sessions kept at once.
    """

    def __init__(
        self,
        ttl_s: float,
        clock: Callable[[], float] = time.monotonic,
        max_sessions: int = MAX_SESSIONS,
    ) -> None:
        if not ttl_s > 0:
            raise ValueError(f"ttl_s: expected a positive number of seconds, received {ttl_s!r}.")
        self._ttl_s = ttl_s
        self._clock = clock
        self._max = max_sessions
        self._expiry: dict[str, float] = {}  # digest → monotonic expiry (insertion ordered)
        self._lock = threading.Lock()

    @property
    def ttl_s(self) -> float:
        """How long a session lives without use, in seconds."""
        return self._ttl_s

    def create(self) -> Session:
        """Issue a new session (256 random bits)."""
        session_id = secrets.token_urlsafe(32)
        with self._lock:
            self._prune()
            while len(self._expiry) >= self._max:
                self._expiry.pop(next(iter(self._expiry)))
            self._expiry[_digest(session_id)] = self._clock() + self._ttl_s
        return Session(session_id, datetime.now(UTC) + timedelta(seconds=self._ttl_s))

    def is_valid(self, session_id: str | None) -> bool:
        """Whether ``session_id`` is a live session; a live one is renewed (``ttl_s`` from now),
        an expired one forgotten."""
        if not session_id:
            return False
        key = _digest(session_id)
        with self._lock:
            expiry = self._expiry.get(key)
            if expiry is None:
                return False
            now = self._clock()
            if now >= expiry:
                del self._expiry[key]
                return False
            self._expiry[key] = now + self._ttl_s
            return True

    def is_live(self, session_id: str | None) -> bool:
        """Whether ``session_id`` is a live session, without renewing it (open streams ask
        this before each chunk; only requests renew a session)."""
        if not session_id:
            return False
        with self._lock:
            expiry = self._expiry.get(_digest(session_id))
            return expiry is not None and self._clock() < expiry

    def delete(self, session_id: str | None) -> bool:
        """End a session; returns whether it existed."""
        if not session_id:
            return False
        with self._lock:
            return self._expiry.pop(_digest(session_id), None) is not None

    def __len__(self) -> int:
        with self._lock:
            self._prune()
            return len(self._expiry)

    def _prune(self) -> None:
        now = self._clock()
        for key in [k for k, expiry in self._expiry.items() if now >= expiry]:
            del self._expiry[key]
