"""Security: loopback by default, a token required elsewhere, bearer auth on changes."""

from __future__ import annotations

from pathlib import Path

import pytest
from typer.testing import CliRunner

from app.config import ConfigurationError, Settings, is_loopback
from app.main import create_app
from tests.app.conftest import TestClient, experiment1_csv, make_settings


def test_default_bind_is_loopback() -> None:
    assert Settings(_env_file=None).host == "127.0.0.1"  # type: ignore[call-arg]
    for host in ("127.0.0.1", "127.0.0.2", "localhost", "::1"):
        assert is_loopback(host)
    for host in ("0.0.0.0", "192.168.1.4", "::", "example.org"):
        assert not is_loopback(host)


def test_refuses_other_hosts_without_token(tmp_path: Path) -> None:
    with pytest.raises(ConfigurationError, match="without an API token"):
        create_app(make_settings(tmp_path, host="0.0.0.0"))
    create_app(make_settings(tmp_path, host="0.0.0.0", api_token="s3cret"))


def test_serve_command_refuses_and_exits_2(tmp_path: Path) -> None:
    import typer

    from app.cli.serve import serve_command

    cli = typer.Typer()
    cli.command()(serve_command)
    result = CliRunner().invoke(
        cli, ["--host", "0.0.0.0", "--database-url", f"sqlite:///{tmp_path / 'x.db'}"], env={}
    )
    assert result.exit_code == 2
    assert "Refusing to bind" in result.output


def test_token_guards_mutations(tmp_path: Path) -> None:
    settings = make_settings(tmp_path, api_token="s3cret")
    csv = experiment1_csv(touches_per_object=3)
    headers = {"content-type": "text/csv"}
    with TestClient(create_app(settings)) as client:
        assert client.get("/api/v1/health").json()["auth_required"] is True
        refused = client.post("/api/v1/datasets", content=csv, headers=headers)
        assert refused.status_code == 401
        wrong = client.post(
            "/api/v1/datasets", content=csv, headers={**headers, "Authorization": "Bearer no"}
        )
        assert wrong.status_code == 401
        accepted = client.post(
            "/api/v1/datasets", content=csv, headers={**headers, "Authorization": "Bearer s3cret"}
        )
        assert accepted.status_code == 201
        assert client.get("/api/v1/datasets/1").status_code == 200


def test_no_client_file_paths(client: TestClient) -> None:
    # Uploads carry content, never a path the server would open.
    response = client.post("/api/v1/datasets", json={"path": "/etc/passwd"})
    assert response.status_code == 422
