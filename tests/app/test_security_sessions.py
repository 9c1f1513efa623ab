"""The session store (ids, idle expiry, renewal, bound) and the settings that lock reads."""

from __future__ import annotations

from pathlib import Path

import pytest

from app.config import ConfigurationError
from app.main import create_app
from app.security.gate import Identity, refusal, same_origin, token_matches
from app.security.sessions import SessionStore
from tests.app.conftest import make_settings
from tests.app.manual_clock import ManualClock


def test_sessions_expire_when_idle_and_renew_on_use() -> None:
    clock = ManualClock()
    store = SessionStore(ttl_s=60.0, clock=clock)
    session = store.create()
    assert store.is_valid(session.session_id)
    clock.now_s += 59.0
    assert store.is_valid(session.session_id)  # used: renewed to 60 s from now
    clock.now_s += 59.0
    assert store.is_valid(session.session_id)
    clock.now_s += 60.0
    assert not store.is_valid(session.session_id)  # idle for the whole ttl
    assert len(store) == 0
    assert not store.is_valid(session.session_id)


def test_session_ids_are_random_and_stored_only_as_digests() -> None:
    store = SessionStore(ttl_s=60.0)
    ids = {store.create().session_id for _ in range(50)}
    assert len(ids) == 50
    assert all(len(i) >= 43 for i in ids)  # 32 random bytes, url-safe base64
    held = repr(vars(store))
    assert not any(i in held for i in ids)
    assert not store.is_valid("")
    assert not store.is_valid(None)
    assert not store.is_valid("x" * 43)
    one = ids.pop()
    assert store.delete(one)
    assert not store.delete(one)
    assert not store.is_valid(one)


def test_store_is_bounded_oldest_dropped() -> None:
    store = SessionStore(ttl_s=60.0, max_sessions=3)
    first, *rest = [store.create() for _ in range(4)]
    assert len(store) == 3
    assert not store.is_valid(first.session_id)
    assert all(store.is_valid(s.session_id) for s in rest)
    with pytest.raises(ValueError, match="ttl_s"):
        SessionStore(ttl_s=0.0)


def test_token_comparison_and_origin() -> None:
    assert token_matches("abc", "abc")
    assert not token_matches("abd", "abc")
    assert not token_matches("abc ", "abc")
    assert not token_matches("", "abc")
    assert token_matches("é-ü", "é-ü")
    assert same_origin({"host": "lab:8000"})
    assert same_origin({"host": "lab:8000", "origin": "http://LAB:8000"})
    assert not same_origin({"host": "lab:8000", "origin": "http://lab:9000"})
    assert not same_origin({"origin": "http://lab:8000"})


def test_off_loopback_is_the_bind_address_or_the_switch(tmp_path: Path) -> None:
    for host, locked in (("0.0.0.0", True), ("192.168.1.20", True), ("::", True),
                         ("127.0.0.1", False), ("localhost", False), ("::1", False)):  # fmt: skip
        settings = make_settings(tmp_path, host=host, api_token="t")
        assert settings.reads_need_auth is locked, host
        answer = refusal(settings, "GET", "/api/v1/trials", Identity(), {}, "/api/v1")
        assert (answer is not None) is locked, host
    # Static dashboard files are not data: they stay public (the page then asks to sign in).
    settings = make_settings(tmp_path, host="0.0.0.0", api_token="t")
    assert refusal(settings, "GET", "/js/app.js", Identity(), {}, "/api/v1") is None
    assert refusal(settings, "GET", "/api/v1x", Identity(), {}, "/api/v1") is None
    assert refusal(settings, "GET", "/viserx", Identity(), {}, "/api/v1") is None
    locked = make_settings(tmp_path, require_auth_for_reads=True, api_token="t")
    assert locked.reads_need_auth
    # Off loopback there is no switch to open reads again.
    still = make_settings(tmp_path, host="0.0.0.0", require_auth_for_reads=False, api_token="t")
    assert still.reads_need_auth


def test_locking_reads_needs_a_token(tmp_path: Path) -> None:
    with pytest.raises(ConfigurationError, match="require_auth_for_reads"):
        create_app(make_settings(tmp_path, require_auth_for_reads=True))
