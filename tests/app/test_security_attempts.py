"""The limit on wrong tokens per client address: the limiter itself (sliding window, keys,
bound) and through the app (429 with Retry-After, reset after the window, one address's
failures never touching another's, successes never limited, refusals in the audit)."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from pydantic import ValidationError

from app.config import Settings
from app.errors import error_response
from app.main import create_app
from app.security.attempts import AttemptLimiter, client_key, retry_after_header
from app.security.errors import TooManyAttemptsError, UnauthorizedError
from app.security.sessions import SessionStore
from app.services import session as sessions_service
from tests.app.conftest import TestClient, make_settings
from tests.app.manual_clock import ManualClock

TOKEN = "attempts-token"
BEARER = {"Authorization": f"Bearer {TOKEN}"}
WRONG = {"Authorization": "Bearer not-the-token"}
SIGN_IN = "/api/v1/session"
MAX_FAILURES = 3
WINDOW_S = 60.0


# --- the limiter -------------------------------------------------------------------------------


def test_limit_is_a_sliding_window_of_failures() -> None:
    clock = ManualClock(5000.0)
    limiter = AttemptLimiter(MAX_FAILURES, WINDOW_S, clock=clock)
    for step in range(MAX_FAILURES):
        assert limiter.retry_after_s("10.0.0.1") is None
        limiter.record_failure("10.0.0.1")
        clock.now_s += 10.0 if step < MAX_FAILURES - 1 else 0.0
    # Failures at t0, t0+10, t0+20; now t0+20: blocked until the first is 60 s old (t0+60).
    assert limiter.failures("10.0.0.1") == MAX_FAILURES
    assert limiter.retry_after_s("10.0.0.1") == pytest.approx(40.0)
    clock.now_s += 39.5
    assert limiter.retry_after_s("10.0.0.1") == pytest.approx(0.5)
    clock.now_s += 0.5  # the first failure leaves the window: one more try
    assert limiter.retry_after_s("10.0.0.1") is None
    assert limiter.failures("10.0.0.1") == MAX_FAILURES - 1
    limiter.record_failure("10.0.0.1")  # at t0+60: blocked until the t0+10 one is 60 s old
    assert limiter.retry_after_s("10.0.0.1") == pytest.approx(10.0)
    clock.now_s += 60.0
    assert limiter.failures("10.0.0.1") == 0
    assert limiter.retry_after_s("10.0.0.1") is None


def test_addresses_count_apart_ipv6_per_64() -> None:
    clock = ManualClock(5000.0)
    limiter = AttemptLimiter(1, WINDOW_S, clock=clock)
    limiter.record_failure("10.0.0.1")
    assert limiter.retry_after_s("10.0.0.1") is not None
    assert limiter.retry_after_s("10.0.0.2") is None
    assert limiter.retry_after_s("::ffff:10.0.0.1") is not None  # the same IPv4 client
    limiter.record_failure("2001:db8:1:2::1")
    assert limiter.retry_after_s("2001:db8:1:2:ffff::9") is not None  # same /64
    assert limiter.retry_after_s("2001:db8:1:3::1") is None
    assert client_key("2001:db8:1:2::1") == "2001:db8:1:2::/64"
    assert client_key("127.0.0.1") == "127.0.0.1"
    assert client_key("testclient") == "testclient"
    assert client_key(None) == client_key("") == "unknown"


def test_limiter_is_bounded_and_checks_its_arguments() -> None:
    clock = ManualClock(5000.0)
    limiter = AttemptLimiter(1, WINDOW_S, clock=clock, max_clients=2)
    for address in ("10.0.0.1", "10.0.0.2", "10.0.0.3"):
        limiter.record_failure(address)
    assert limiter.failures("10.0.0.1") == 0  # failed longest ago: forgotten
    assert limiter.failures("10.0.0.3") == 1
    with pytest.raises(ValueError, match="max_failures"):
        AttemptLimiter(0, WINDOW_S)
    with pytest.raises(ValueError, match="window_s"):
        AttemptLimiter(1, 0.0)
    assert [retry_after_header(s) for s in (0.01, 1.0, 1.2, 59.9)] == ["1", "1", "2", "60"]


def test_settings_defaults_and_bounds(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    defaults = Settings(_env_file=None)  # type: ignore[call-arg]
    assert (defaults.auth_max_failures, defaults.auth_failure_window_s) == (10, 60.0)
    monkeypatch.setenv("ACTIVETOUCH_AUTH_MAX_FAILURES", "5")
    monkeypatch.setenv("ACTIVETOUCH_AUTH_FAILURE_WINDOW_S", "300")
    from_env = Settings(_env_file=None)  # type: ignore[call-arg]
    assert (from_env.auth_max_failures, from_env.auth_failure_window_s) == (5, 300.0)
    with pytest.raises(ValidationError, match="auth_max_failures"):
        make_settings(tmp_path, auth_max_failures=0)
    with pytest.raises(ValidationError, match="auth_failure_window_s"):
        make_settings(tmp_path, auth_failure_window_s=0)


# --- through the app ---------------------------------------------------------------------------


@pytest.fixture
def clock() -> ManualClock:
    return ManualClock(5000.0)


@pytest.fixture
def lab(tmp_path: Path, clock: ManualClock) -> Iterator[Any]:
    """An off-loopback app (limit 3 per 60 s) with the fake clock, and a client per address."""
    settings = make_settings(
        tmp_path,
        host="0.0.0.0",
        api_token=TOKEN,
        hardware="serial",
        auth_max_failures=MAX_FAILURES,
        auth_failure_window_s=WINDOW_S,
    )
    app = create_app(settings, clock=clock)
    with TestClient(app, client=("10.0.0.1", 40000)) as first:

        def client_at(address: str) -> TestClient:
            return TestClient(app, client=(address, 40001))

        yield first, client_at


def sign_in(client: TestClient, token: str) -> int:
    return client.post(SIGN_IN, json={"token": token}).status_code


def assert_too_many(response: Any, wait_s: int) -> None:
    assert response.status_code == 429, response.text
    assert response.headers["retry-after"] == str(wait_s)
    body = response.json()
    assert body["retry_after_s"] == wait_s
    assert f"Try again in {wait_s} s" in body["detail"]
    assert "Too many wrong API tokens" in body["detail"]


def test_wrong_sign_ins_then_429_until_the_window_passes(lab: Any, clock: ManualClock) -> None:
    client, _ = lab
    assert [sign_in(client, "guess") for _ in range(MAX_FAILURES)] == [401] * MAX_FAILURES
    # Over the limit: even the right token is not checked.
    assert_too_many(client.post(SIGN_IN, json={"token": TOKEN}), 60)
    assert_too_many(client.post(SIGN_IN, json={"token": "guess"}), 60)
    clock.now_s += 45.2
    assert_too_many(client.post(SIGN_IN, json={"token": TOKEN}), 15)  # 14.8 s, rounded up
    clock.now_s += 14.8
    response = client.post(SIGN_IN, json={"token": TOKEN})
    assert response.status_code == 200, response.text
    assert client.get("/api/v1/trials").status_code == 200  # the session works


def test_wrong_bearer_tokens_count_and_then_429(lab: Any, clock: ManualClock) -> None:
    client, _ = lab
    assert [client.get("/api/v1/trials", headers=WRONG).status_code for _ in range(2)] == [401] * 2
    assert sign_in(client, "guess") == 401  # sign-ins and bearer tokens count together
    assert_too_many(client.get("/api/v1/trials", headers=BEARER), 60)
    assert_too_many(client.post("/api/v1/rig/estop", headers=BEARER), 60)
    # No token presented is no attempt: still the plain 401; the open health check answers.
    assert client.get("/api/v1/trials").status_code == 401
    assert client.get("/api/v1/health", headers=WRONG).status_code == 200
    clock.now_s += WINDOW_S
    assert client.get("/api/v1/trials", headers=BEARER).status_code == 200


def test_one_address_over_the_limit_leaves_others_alone(lab: Any, clock: ManualClock) -> None:
    blocked, client_at = lab
    other = client_at("10.0.0.2")
    for _ in range(MAX_FAILURES):
        sign_in(blocked, "guess")
    assert blocked.post(SIGN_IN, json={"token": TOKEN}).status_code == 429
    # Another address: its own wrong token is a 401, its right one signs in ...
    assert sign_in(other, "guess") == 401
    assert sign_in(other, TOKEN) == 200
    assert other.get("/api/v1/trials", headers=BEARER).status_code == 200
    # ... and its success resets nothing of the blocked address.
    assert_too_many(blocked.post(SIGN_IN, json={"token": TOKEN}), 60)
    assert blocked.app.state.auth_attempts.failures("10.0.0.1") == MAX_FAILURES  # type: ignore[attr-defined]
    assert blocked.app.state.auth_attempts.failures("10.0.0.2") == 1  # type: ignore[attr-defined]


def test_a_session_keeps_working_while_its_address_is_over_the_limit(
    lab: Any, clock: ManualClock
) -> None:
    client, _ = lab
    assert sign_in(client, TOKEN) == 200
    for _ in range(MAX_FAILURES):
        client.get("/api/v1/trials", headers=WRONG)
    # The cookie is no token guess: it still authenticates, a bearer token on top is ignored.
    assert client.get("/api/v1/trials").status_code == 200
    assert client.get("/api/v1/trials", headers=WRONG).status_code == 200
    assert client.get(SIGN_IN).json()["method"] == "session"


def test_successes_are_never_limited(lab: Any) -> None:
    client, _ = lab
    for _ in range(4 * MAX_FAILURES):
        assert sign_in(client, TOKEN) == 200
        assert client.get("/api/v1/trials", headers=BEARER).status_code == 200
    assert client.app.state.auth_attempts.failures("10.0.0.1") == 0  # type: ignore[attr-defined]


def test_on_loopback_open_reads_stay_open_over_the_limit(
    tmp_path: Path, clock: ManualClock
) -> None:
    settings = make_settings(
        tmp_path, api_token=TOKEN, hardware="serial", auth_max_failures=MAX_FAILURES
    )
    with TestClient(create_app(settings, clock=clock), client=("127.0.0.1", 40000)) as client:
        for _ in range(MAX_FAILURES):
            assert client.post("/api/v1/rig/estop", headers=WRONG).status_code == 401
        # Reads need no token here: they answer as before, the token unchecked ...
        assert client.get("/api/v1/trials", headers=WRONG).status_code == 200
        assert client.get("/api/v1/trials", headers=BEARER).status_code == 200
        assert client.get(SIGN_IN, headers=BEARER).json()["authenticated"] is False
        # ... changes that would need it answer 429; without a token, the plain 401.
        assert_too_many(client.post("/api/v1/rig/estop", headers=BEARER), 60)
        assert client.post("/api/v1/rig/estop").status_code == 401


def test_refused_attempts_are_in_the_audit(lab: Any, clock: ManualClock) -> None:
    client, client_at = lab
    for _ in range(MAX_FAILURES):
        client.post(SIGN_IN, json={"token": "guess"})
    client.post(SIGN_IN, json={"token": TOKEN})  # 429
    client.post("/api/v1/rig/estop", headers=BEARER)  # 429
    auditor = client_at("10.0.0.9")
    assert client.app.state.audit.flush(timeout_s=10)  # type: ignore[attr-defined]
    response = auditor.get("/api/v1/audit", headers=BEARER)
    assert response.status_code == 200, response.text
    rows = [r for r in response.json()["data"] if r["client"] == "10.0.0.1"]
    assert [(r["method"], r["path"], r["status_code"]) for r in rows] == [
        ("POST", "/api/v1/rig/estop", 429),
        ("POST", SIGN_IN, 429),
        ("POST", SIGN_IN, 401),
        ("POST", SIGN_IN, 401),
        ("POST", SIGN_IN, 401),
    ]
    assert all(r["authenticated"] is False and r["auth_method"] is None for r in rows)


def test_the_sign_in_service_limits_without_the_gate_too(
    tmp_path: Path, clock: ManualClock
) -> None:
    settings = make_settings(tmp_path, api_token=TOKEN, auth_max_failures=1)
    limiter = AttemptLimiter(1, WINDOW_S, clock=clock)
    sessions = SessionStore(ttl_s=60.0, clock=clock)
    with pytest.raises(UnauthorizedError):
        sessions_service.sign_in(settings, sessions, "guess", limiter, "10.0.0.1")
    with pytest.raises(TooManyAttemptsError) as raised:
        sessions_service.sign_in(settings, sessions, TOKEN, limiter, "10.0.0.1")
    response = error_response(raised.value)
    assert response.status_code == 429
    assert response.headers["retry-after"] == "60"
    assert len(sessions) == 0
    assert sessions_service.sign_in(settings, sessions, TOKEN, limiter, "10.0.0.2").session_id
