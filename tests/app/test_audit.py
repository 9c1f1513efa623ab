"""The request audit: every change recorded (client, route, outcome, authentication), listed at
``GET /api/v1/audit``, written off the request path so it never delays or breaks a request."""

from __future__ import annotations

import threading
from dataclasses import asdict
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from alembic.runtime.migration import MigrationContext
from sqlalchemy import inspect

from app import crud
from app.db import Database, upgrade_to_head
from app.main import create_app
from app.security.audit import PRUNE_EVERY, AuditEntry, AuditRecorder, database_writer
from tests.app.conftest import TestClient, import_model, make_settings
from tests.app.test_migrations import migrate

TOKEN = "audit-token"
BEARER = {"Authorization": f"Bearer {TOKEN}"}


def audit_rows(client: TestClient, **params: Any) -> list[dict[str, Any]]:
    assert client.app.state.audit.flush(timeout_s=10)  # type: ignore[attr-defined]
    response = client.get("/api/v1/audit", params=params, headers=BEARER)
    assert response.status_code == 200, response.text
    rows: list[dict[str, Any]] = response.json()["data"]
    return rows


def test_start_stop_and_estop_are_recorded_with_client_and_outcome(tmp_path: Path) -> None:
    settings = make_settings(tmp_path, host="0.0.0.0", api_token=TOKEN)
    with TestClient(create_app(settings)) as client:
        model_id = import_model_with_token(client)
        created = client.post(
            "/api/v1/trials",
            json={"model_id": model_id, "mode": "scripted", "target": "O1", "seed": 1},
            headers=BEARER,
        )
        assert created.status_code == 201
        trial_id = created.json()["id"]
        assert client.post(f"/api/v1/trials/{trial_id}/stop", headers=BEARER).status_code == 200
        estop = client.post("/api/v1/rig/estop", headers=BEARER)
        refused = client.post(f"/api/v1/trials/{trial_id}/stop")  # no token
        assert refused.status_code == 401
        # Reads are not recorded.
        client.get("/api/v1/trials", headers=BEARER)
        rows = audit_rows(client)
    # Newest first: the refused stop, the e-stop, the stop, the start, the model import.
    assert [(r["method"], r["path"]) for r in rows] == [
        ("POST", f"/api/v1/trials/{trial_id}/stop"),
        ("POST", "/api/v1/rig/estop"),
        ("POST", f"/api/v1/trials/{trial_id}/stop"),
        ("POST", "/api/v1/trials"),
        ("POST", "/api/v1/models/import"),
    ]
    refused_row, estop_row, stop_row, start_row, _ = rows
    assert refused_row["status_code"] == 401
    assert refused_row["authenticated"] is False
    assert refused_row["auth_method"] is None
    assert estop_row["status_code"] == estop.status_code
    assert stop_row["status_code"] == 200
    assert start_row["status_code"] == 201
    for row in (estop_row, stop_row, start_row):
        assert row["authenticated"] is True
        assert row["auth_method"] == "token"
    assert {r["client"] for r in rows} == {"testclient"}
    # The route is the template (one control route for every action); the path names the action.
    assert stop_row["route"] == "/api/v1/trials/{trial_id}/{action}"
    assert [r["id"] for r in rows] == sorted((r["id"] for r in rows), reverse=True)
    assert all(r["duration_ms"] >= 0 for r in rows)
    times = [r["time"] for r in rows]
    assert times == sorted(times, reverse=True)


def import_model_with_token(client: TestClient) -> int:
    client.headers.update(BEARER)
    try:
        return import_model(client)
    finally:
        del client.headers["Authorization"]


def test_audit_filters_and_session_sign_ins(tmp_path: Path) -> None:
    with TestClient(create_app(make_settings(tmp_path, api_token=TOKEN))) as client:
        assert client.post("/api/v1/session", json={"token": "wrong"}).status_code == 401
        assert client.post("/api/v1/session", json={"token": TOKEN}).status_code == 200
        client.post("/api/v1/rig/estop", headers={"X-Requested-With": "activetouch"})
        sign_ins = audit_rows(client, path_prefix="/api/v1/session")
        assert [(r["status_code"], r["auth_method"]) for r in sign_ins] == [
            (200, "token"),  # the token, presented in the body
            (401, None),
        ]
        estops = audit_rows(client, path_prefix="/api/v1/rig/")
        assert len(estops) == 1
        assert estops[0]["auth_method"] == "session"
        assert audit_rows(client, method="DELETE") == []
        assert client.get("/api/v1/audit", params={"method": "GET"}).status_code == 422


def test_a_failing_audit_never_breaks_the_request(tmp_path: Path) -> None:
    def broken(rows: list[dict[str, Any]]) -> None:
        raise RuntimeError("disk full")

    with TestClient(create_app(make_settings(tmp_path))) as client:
        client.app.state.audit.close()  # type: ignore[attr-defined]
        recorder = AuditRecorder(broken).start()
        client.app.state.audit = recorder  # type: ignore[attr-defined]
        response = client.post("/api/v1/rig/estop")
        assert response.status_code == 200, response.text
        assert recorder.flush(timeout_s=10)
        assert recorder.failed == 1
        recorder.close()


def test_estop_answers_while_the_audit_writer_is_stuck(tmp_path: Path) -> None:
    """The writer blocked (a locked database, say): the e-stop answers anyway, and the entry is
    written once the writer moves on; a full queue drops entries, not requests."""
    release = threading.Event()
    written: list[dict[str, Any]] = []

    def stuck(rows: list[dict[str, Any]]) -> None:
        release.wait(timeout=30)
        written.extend(rows)

    with TestClient(create_app(make_settings(tmp_path))) as client:
        client.app.state.audit.close()  # type: ignore[attr-defined]
        recorder = AuditRecorder(stuck, max_pending=2, gather_s=0.0).start()
        client.app.state.audit = recorder  # type: ignore[attr-defined]
        statuses = [client.post("/api/v1/rig/estop").status_code for _ in range(5)]
        assert statuses == [200] * 5
        assert not release.is_set()
        assert written == []
        assert recorder.dropped >= 1
        release.set()
        assert recorder.flush(timeout_s=10)
        recorder.close()
    assert 1 <= len(written) == 5 - recorder.dropped
    assert all(row["path"] == "/api/v1/rig/estop" for row in written)


def test_recorder_close_writes_what_is_queued() -> None:
    written: list[dict[str, Any]] = []
    recorder = AuditRecorder(written.extend)
    entry = AuditEntry(datetime.now(UTC), "10.0.0.7", "POST", "/api/v1/x", None, 200, True,
                       "token", 1.5)  # fmt: skip
    for _ in range(3):
        assert recorder.submit(entry)
    recorder.start().close()
    assert len(written) == 3
    assert written[0]["client"] == "10.0.0.7"
    assert not recorder.submit(entry)  # closed


def test_the_table_keeps_the_newest_rows(tmp_path: Path) -> None:
    settings = make_settings(tmp_path)
    database = Database(settings.database_url)
    try:
        upgrade_to_head(database.engine, settings.migrations_dir)
        write = database_writer(database, keep=250)
        entry = AuditEntry(datetime.now(UTC), "10.0.0.9", "POST", "/api/v1/session", None, 401,
                           False, None, 0.2)  # fmt: skip
        for _ in range(PRUNE_EVERY // 100):
            write([asdict(entry)] * 100)  # the last batch reaches PRUNE_EVERY: pruned
        with database.session() as session:
            rows, count = crud.list_request_audits(session, limit=1000, offset=0)
        assert count == 250
        assert rows[0].id == PRUNE_EVERY
        assert rows[-1].id == PRUNE_EVERY - 249
    finally:
        database.dispose()


def test_migration_0004_up_and_down(tmp_path: Path) -> None:
    settings = make_settings(tmp_path)
    database = Database(settings.database_url)
    try:
        upgrade_to_head(database.engine, settings.migrations_dir)
        assert "request_audit" in inspect(database.engine).get_table_names()
        migrate(database, settings.migrations_dir, "0002", down=True)
        with database.engine.connect() as connection:
            assert MigrationContext.configure(connection).get_current_revision() == "0002"
        assert "request_audit" not in inspect(database.engine).get_table_names()
        migrate(database, settings.migrations_dir, "0004_request_audit")
        names = inspect(database.engine).get_table_names()
        assert "request_audit" in names
        indexes = {i["name"] for i in inspect(database.engine).get_indexes("request_audit")}
        assert indexes == {"ix_request_audit_time"}
    finally:
        database.dispose()
