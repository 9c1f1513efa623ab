"""Crash test: SIGKILL the server mid-trial, restart it, the trial is failed("interrupted")
with every step recorded before the kill."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import httpx
import pytest

from app.main import create_app
from tests.app.conftest import TestClient, import_model, make_settings

ROOT = Path(__file__).resolve().parents[2]


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port: int = sock.getsockname()[1]
        return port


@contextmanager
def server(database_url: str, port: int, log: Path) -> Iterator[subprocess.Popen[bytes]]:
    """``python -m app.cli.serve`` on 127.0.0.1:port, ready when /health answers."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("ACTIVETOUCH_")}
    with log.open("ab") as out:
        process = subprocess.Popen(
            [sys.executable, "-m", "app.cli.serve", "--port", str(port),
             "--database-url", database_url, "--log-level", "warning"],
            cwd=ROOT, env=env, stdout=out, stderr=subprocess.STDOUT,
        )  # fmt: skip
    try:
        deadline = time.monotonic() + 60
        while True:
            try:
                if httpx.get(f"http://127.0.0.1:{port}/api/v1/health", timeout=1).is_success:
                    break
            except httpx.TransportError:
                pass
            if process.poll() is not None or time.monotonic() > deadline:
                raise RuntimeError(f"server did not start: {log.read_text()[-2000:]}")
            time.sleep(0.1)
        yield process
    finally:
        if process.poll() is None:
            process.terminate()
            try:
                process.wait(timeout=15)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()


def read_live_events(base: str, after: int, count: int) -> list[dict[str, str]]:
    """The first ``count`` events of a following SSE stream started after ``after``."""
    events: list[dict[str, str]] = []
    with httpx.stream(
        "GET", f"{base}/events", headers={"Last-Event-ID": str(after)}, timeout=10
    ) as response:
        assert response.headers["content-type"].startswith("text/event-stream")
        fields: dict[str, str] = {}
        for line in response.iter_lines():
            if not line:
                if "data" in fields:
                    events.append(fields)
                    if len(events) == count:
                        break
                fields = {}
                continue
            key, _, value = line.partition(": ")
            fields[key] = value
    return events


@pytest.mark.slow
def test_sigkill_mid_trial_leaves_failed_interrupted_with_steps(tmp_path: Path) -> None:
    settings = make_settings(tmp_path)
    with TestClient(create_app(settings)) as client:
        model_id = import_model(client)
    port = _free_port()
    base = f"http://127.0.0.1:{port}/api/v1"
    log = tmp_path / "server.log"

    with server(settings.database_url, port, log) as process:
        created = httpx.post(
            f"{base}/trials",
            json={
                "model_id": model_id, "mode": "simulated", "policy": "active",
                "max_steps": 500, "tolerance": 0.0, "target": "O2", "seed": 7,
                "simulation": {"world": "experiment1", "step_interval_s": 0.02},
            },
            timeout=10,
        )  # fmt: skip
        assert created.status_code == 201, created.text
        trial_id = created.json()["id"]
        deadline = time.monotonic() + 30
        seen: dict = {}
        while time.monotonic() < deadline:
            seen = httpx.get(f"{base}/trials/{trial_id}", timeout=10).json()
            if seen["n_steps"] >= 5:
                break
            time.sleep(0.02)
        assert seen["status"] == "running", seen
        assert seen["n_steps"] >= 5
        # Live events over SSE, resumed from a sequence id: new steps arrive in order.
        live = read_live_events(base, after=0, count=3)
        assert [int(e["id"]) for e in live] == sorted(int(e["id"]) for e in live)
        os.kill(process.pid, signal.SIGKILL)
        process.wait(timeout=10)

    # Restart on the same database file (in this process, to keep the test fast: the app's
    # start-up, where recovery happens, is the same as the server's).
    with TestClient(create_app(settings)) as restarted:
        after = restarted.get(f"/api/v1/trials/{trial_id}").json()
        events = restarted.get("/api/v1/events?after=0&follow=false").text

    assert after["status"] == "failed"
    assert after["reason"] == "interrupted"
    # Every step seen before the kill is there, unchanged; the record is contiguous.
    assert after["n_steps"] >= seen["n_steps"]
    assert len(after["steps"]) == after["n_steps"] < 500
    assert [s["step"] for s in after["steps"]] == list(range(1, after["n_steps"] + 1))
    for before, now in zip(seen["steps"], after["steps"], strict=False):
        assert now == before
    assert '"status": "failed"' in events
    assert '"reason": "interrupted"' in events
