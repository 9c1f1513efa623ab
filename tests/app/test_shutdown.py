"""Shutdown with open event streams: they end cleanly, nothing cancelled, no error logged."""

from __future__ import annotations

import logging
import threading
import time
from pathlib import Path

import httpx
import uvicorn

from app.cli.serve import GracefulServer, listening_url
from app.main import create_app
from tests.app.conftest import TestClient, make_settings
from tests.app.served import LogRecords, start_in_thread

API = "/api/v1"


def test_a_closed_bus_ends_a_following_stream_after_its_backlog(tmp_path: Path) -> None:
    with TestClient(create_app(make_settings(tmp_path))) as client:
        events = client.app.state.context.events  # type: ignore[attr-defined]
        events.publish("test.ping", {"n": 1})
        events.close()
        assert events.closed
        events.publish("test.ping", {"n": 2})  # still recorded after close
        body = client.get(f"{API}/events?after=0").text  # follow=true by default
    assert body.count('"type": "test.ping"') == 2


def test_shutdown_with_open_streams_logs_no_traceback(tmp_path: Path) -> None:
    app = create_app(make_settings(tmp_path))
    # No log_config: uvicorn's loggers keep propagating, and our handler sees every record.
    config = uvicorn.Config(
        app, host="127.0.0.1", port=0, log_config=None, timeout_graceful_shutdown=30
    )
    server = GracefulServer(config)
    handler = LogRecords()
    loggers = [logging.getLogger(name) for name in ("uvicorn", "uvicorn.error", "app")]
    levels = [logger.level for logger in loggers]
    for logger in loggers:
        logger.addHandler(handler)
        logger.setLevel(logging.INFO)
    thread: threading.Thread | None = None
    try:
        thread = start_in_thread(server, timeout_s=30)
        base = listening_url(server, "127.0.0.1")
        received: list[list[str]] = [[], []]
        errors: list[BaseException] = []
        opened = threading.Barrier(3, timeout=20)

        def follow(lines: list[str]) -> None:
            try:
                url = f"{base}{API}/events?after=0"
                with httpx.stream("GET", url, timeout=60) as response:
                    opened.wait()
                    for line in response.iter_lines():
                        lines.append(line)
            except BaseException as exc:  # reported by the assertion below
                errors.append(exc)

        readers = [threading.Thread(target=follow, args=(lines,)) for lines in received]
        for reader in readers:
            reader.start()
        opened.wait()  # both streams are open (status and headers received)
        app.state.context.events.publish("test.ping", {"n": 1})
        deadline = time.monotonic() + 10
        while not all(any("test.ping" in line for line in lines) for lines in received):
            assert time.monotonic() < deadline, f"no event on the streams: {received}"
            time.sleep(0.02)

        stopping = time.monotonic()
        server.should_exit = True
        thread.join(timeout=20)
        for reader in readers:
            reader.join(timeout=10)
        stopped_in_s = time.monotonic() - stopping
    finally:
        server.should_exit = True
        if thread is not None:
            thread.join(timeout=20)
        for logger, level in zip(loggers, levels, strict=True):
            logger.removeHandler(handler)
            logger.setLevel(level)

    assert thread is not None
    assert not thread.is_alive()
    assert stopped_in_s < 5.0  # not the 30 s grace period: the streams ended by themselves
    assert errors == []  # each response was complete (no "incomplete chunked read")
    problems = [
        f"{r.name} {r.levelname}: {r.getMessage()}"
        for r in handler.records
        if r.levelno >= logging.WARNING or r.exc_info is not None
    ]
    assert problems == []
    messages = [r.getMessage() for r in handler.records]
    assert "Application shutdown complete." in messages  # the lifespan ran: context closed
