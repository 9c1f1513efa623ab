"""Failed token attempts, limited per client address.

A wrong token — in a sign-in's body or in an ``Authorization: Bearer`` header — is a guess. An
:class:`AttemptLimiter` remembers when each client address last failed (a sliding window): once
an address has ``max_failures`` failures within ``window_s`` seconds, its tokens are no longer
checked until the oldest of them is ``window_s`` old. Meanwhile the sign-in, and any request that
would need the token it carries, answers 429 with ``Retry-After`` (:mod:`app.security.gate`).

- Only failures count. A success neither counts nor resets anything: behind a proxy that does
  not forward the client's address, several people share one address, and one person's sign-in
  must not wipe another's failures.
- Attempts refused with 429 are not checked, so they are not failures either: waiting out the
  window always lets an address try again.
- IPv6 addresses count per /64 network (one host is usually given a whole /64 and could
  otherwise step through it); IPv4 addresses count one by one.
- Every address counts, loopback included: "off loopback" is decided by the bind address, and
  behind a proxy or tunnel on the same machine every client would look like loopback.
- At most :data:`MAX_CLIENTS` addresses are remembered; the one that failed longest ago is
  forgotten first.
"""

from __future__ import annotations

import ipaddress
import math
import threading
import time
from collections import OrderedDict, deque
from collections.abc import Callable

#: Client addresses remembered at most (the least recently failing one is dropped beyond it).
MAX_CLIENTS = 10_000
#: Prefix length of the IPv6 networks counted as one client.
IPV6_PREFIX = 64


def client_key(address: str | None) -> str:
    """The key an address's failures count under: the address, or its /64 for IPv6.

    Args:
        address: The client's address as the server sees it (``scope["client"][0]``), ``None``
            when unknown. Anything that is not an IP address counts under its own text.
    """
    if not address:
        return "unknown"
    try:
        ip = ipaddress.ip_address(address.strip("[]"))
    except ValueError:
        return address
    if isinstance(ip, ipaddress.IPv6Address):
        if ip.ipv4_mapped is not None:  # ::ffff:a.b.c.d is the IPv4 client a.b.c.d
            return str(ip.ipv4_mapped)
        return str(ipaddress.IPv6Network((ip, IPV6_PREFIX), strict=False))
    return str(ip)


def retry_after_header(retry_after_s: float) -> str:
    """``Retry-After`` in whole seconds, rounded up (at least 1)."""
    return str(max(1, math.ceil(retry_after_s)))


def too_many_detail(retry_after_s: float, max_failures: int, window_s: float) -> str:
    """The message of a 429: what happened and when to try again."""
    return (
        f"Too many wrong API tokens from this address ({max_failures:d} within {window_s:g} s): "
        f"tokens from it are not checked for now. Try again in {retry_after_header(retry_after_s)} "
        "s (Retry-After)."
    )


class AttemptLimiter:
    """At most ``max_failures`` failed token attempts per client address within ``window_s``.

    Thread-safe (the gate runs on the event loop, the sign-in in the thread pool).

    Args:
        max_failures: Failures an address may have within the window (>= 1).
        window_s: Length of the sliding window, in seconds (> 0).
        clock: Monotonic clock in seconds (tests pass their own).
        max_clients: Addresses remembered at most.
    """

    def __init__(
        self,
        max_failures: int,
        window_s: float,
        clock: Callable[[], float] = time.monotonic,
        max_clients: int = MAX_CLIENTS,
    ) -> None:
        if max_failures < 1:
            raise ValueError(f"max_failures: expected at least 1, received {max_failures!r}.")
        if not window_s > 0:
            raise ValueError(
                f"window_s: expected a positive number of seconds, received {window_s!r}."
            )
        self._max_failures = max_failures
        self._window_s = window_s
        self._clock = clock
        self._max_clients = max_clients
        self._failures: OrderedDict[str, deque[float]] = OrderedDict()  # oldest failing first
        self._lock = threading.Lock()

    @property
    def max_failures(self) -> int:
        """Failures an address may have within the window."""
        return self._max_failures

    @property
    def window_s(self) -> float:
        """Length of the window, in seconds."""
        return self._window_s

    def retry_after_s(self, address: str | None) -> float | None:
        """Seconds until ``address`` may try a token again; ``None`` when it may now."""
        with self._lock:
            now = self._clock()
            times = self._recent(client_key(address), now)
            if times is None or len(times) < self._max_failures:
                return None
            return times[0] + self._window_s - now

    def detail(self, retry_after_s: float) -> str:
        """The message of a 429 that asks to wait ``retry_after_s`` seconds."""
        return too_many_detail(retry_after_s, self._max_failures, self._window_s)

    def record_failure(self, address: str | None) -> None:
        """Note one failed attempt of ``address`` (now)."""
        key = client_key(address)
        with self._lock:
            now = self._clock()
            times = self._recent(key, now)
            if times is None:
                times = self._failures[key] = deque(maxlen=self._max_failures)
            times.append(now)
            self._failures.move_to_end(key)
            while len(self._failures) > self._max_clients:
                self._failures.popitem(last=False)

    def failures(self, address: str | None) -> int:
        """How many failures of ``address`` are within the window now."""
        with self._lock:
            times = self._recent(client_key(address), self._clock())
            return 0 if times is None else len(times)

    def _recent(self, key: str, now: float) -> deque[float] | None:
        """The failure times of ``key`` still within the window (older ones dropped)."""
        times = self._failures.get(key)
        if times is None:
            return None
        while times and times[0] + self._window_s <= now:
            times.popleft()
        if not times:
            del self._failures[key]
            return None
        return times
