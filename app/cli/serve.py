"""``activetouch serve``: run the web app with uvicorn, and the live 3D view beside it.

:func:`serve` is the function; :func:`serve_command` is the typer command the CLI registers
(``app.command("serve")(serve_command)``). ``python -m app.cli.serve`` runs it on its own.
:class:`GracefulServer` is the uvicorn server both ``serve`` and the demo run: its shutdown ends
the open event streams first, so it neither hangs on them nor cancels them with tracebacks.
"""

from __future__ import annotations

import os
import socket
import sys
import threading
import time
from typing import Annotated, Any, Literal

import typer
import uvicorn
from starlette.applications import Starlette

from app.config import ConfigurationError, Settings
from app.main import create_app
from app.viz.live import LiveView

#: Seconds uvicorn waits for open responses at shutdown before cancelling them.
GRACEFUL_SHUTDOWN_S = 5
#: Seconds the 3D view's follower waits for the web app to start listening.
FOLLOW_START_TIMEOUT_S = 120.0


def end_event_streams(app: object) -> None:
    """Close the event bus of an app built by :func:`~app.main.create_app` (if it has started).

    Its SSE streams then return after what they have sent, and their responses complete.
    """
    state = app.state if isinstance(app, Starlette) else None
    context = getattr(state, "context", None)
    if context is not None:
        context.events.close()


class GracefulServer(uvicorn.Server):
    """A uvicorn server that ends the app's event streams as soon as its shutdown begins.

    uvicorn waits for open responses before the app's lifespan shutdown; an event stream never
    ends by itself, so a plain server waits for ever (or ``timeout_graceful_shutdown``) and then
    cancels each stream, logging "Exception in ASGI application" with a traceback per stream.
    Closing the event bus first lets every stream finish its response cleanly.
    """

    async def shutdown(self, sockets: list[socket.socket] | None = None) -> None:
        """End the event streams, then shut down as uvicorn does."""
        end_event_streams(self.config.app)
        await super().shutdown(sockets)


def serve(
    host: str | None = None,
    port: int | None = None,
    database_url: str | None = None,
    hardware: Literal["mock", "serial"] | None = None,
    turntable_port: str | None = None,
    finger_port: str | None = None,
    tactile_port: str | None = None,
    api_token: str | None = None,
    log_level: str = "info",
    viz: bool | None = None,
    viz_port: int | None = None,
) -> None:
    """Serve the API (and the dashboard), and the live 3D view beside them, until interrupted.

    Arguments left ``None`` come from the environment (``ACTIVETOUCH_*``), ``.env`` or the
    defaults (127.0.0.1:8000, ``sqlite:///activetouch.db``, mock hardware, the 3D view on port
    8081 of loopback). The view draws every trial as it runs; the dashboard embeds it (off
    loopback through the app at ``/viser/``, behind the sign-in: :mod:`app.viz.proxy`).

    Raises:
        ConfigurationError: A non-loopback host without an API token, or other unsafe settings.
    """
    overrides: dict[str, Any] = {
        key: value
        for key, value in {
            "host": host,
            "port": port,
            "database_url": database_url,
            "hardware": hardware,
            "turntable_port": turntable_port,
            "finger_port": finger_port,
            "tactile_port": tactile_port,
            "api_token": api_token,
            "viz": viz,
            "viz_port": viz_port,
        }.items()
        if value is not None
    }
    if not ServedApp(Settings(**overrides), log_level).run():
        sys.exit(3)  # as uvicorn.run: the port was taken, or the app failed to start


class ServedApp:
    """The web app under uvicorn and, unless ``settings.viz`` is off, the live 3D view.

    Args:
        settings: What to serve; unsafe settings are refused here, before anything binds.
        log_level: uvicorn's log level.

    Raises:
        ConfigurationError: A non-loopback host without an API token, or other unsafe settings.
    """

    def __init__(self, settings: Settings, log_level: str = "info") -> None:
        self.settings = settings
        self.app = create_app(settings)
        self.live = LiveView(settings.host, settings.viz_port) if settings.viz else None
        if self.live is not None:
            self.live.attach(self.app)
        self.server = GracefulServer(
            uvicorn.Config(
                self.app,
                host=settings.host,
                port=settings.port,
                log_level=log_level,
                timeout_graceful_shutdown=GRACEFUL_SHUTDOWN_S,
            )
        )

    def run(self) -> bool:
        """Serve until the server is told to exit (Ctrl-C, SIGTERM, ``server.should_exit``);
        the view follows the app's trials once it listens, and is closed at the end.

        Returns:
            Whether the server started.
        """
        if self.live is not None:
            threading.Thread(
                target=follow_when_listening,
                args=(self.server, self.live, self.settings),
                name="viz-follower-start",
                daemon=True,
            ).start()
        try:
            self.server.run()
        finally:
            if self.live is not None:
                self.live.close()
        return bool(self.server.started)


def listening_url(server: uvicorn.Server, host: str) -> str:
    """``http://host:port`` of a started server, as seen from this machine (the port it bound,
    which differs from the configured one when that was 0)."""
    listeners = getattr(server, "servers", [])  # set by uvicorn once it listens
    sockets = [s for listener in listeners for s in (listener.sockets or [])]
    port = int(sockets[0].getsockname()[1]) if sockets else int(server.config.port)
    if host in ("0.0.0.0", "::", ""):
        host = "127.0.0.1"
    elif ":" in host:
        host = f"[{host}]"
    return f"http://{host}:{port}"


def follow_when_listening(server: uvicorn.Server, live: LiveView, settings: Settings) -> None:
    """Once ``server`` listens, let ``live`` follow its trials (gives up if it never starts)."""
    deadline = time.monotonic() + FOLLOW_START_TIMEOUT_S
    while not server.started:
        if server.should_exit or time.monotonic() > deadline:
            return
        time.sleep(0.05)
    live.follow(listening_url(server, settings.host), token=settings.token)


def serve_command(
    host: Annotated[
        str | None, typer.Option(help="Address to bind (default 127.0.0.1; others need a token).")
    ] = None,
    port: Annotated[int | None, typer.Option(help="TCP port (default 8000).")] = None,
    database_url: Annotated[
        str | None, typer.Option(help="SQLite URL (default sqlite:///activetouch.db).")
    ] = None,
    hardware: Annotated[
        str | None, typer.Option(help="mock (simulated rig, default) or serial.")
    ] = None,
    turntable_port: Annotated[
        str | None, typer.Option(help="Serial port of the GRBL turntable.")
    ] = None,
    finger_port: Annotated[
        str | None, typer.Option(help="Serial port of the Dynamixel bus.")
    ] = None,
    tactile_port: Annotated[
        str | None, typer.Option(help="Serial port of the tactile sensor.")
    ] = None,
    api_token: Annotated[
        str | None,
        typer.Option(
            envvar="ACTIVETOUCH_API_TOKEN",
            help="Bearer token required for changes (required off loopback).",
        ),
    ] = None,
    log_level: Annotated[str, typer.Option(help="uvicorn log level.")] = "info",
    viz: Annotated[
        bool | None,
        typer.Option("--viz/--no-viz", help="Run the live 3D view (viser) beside the app."),
    ] = None,
    viz_port: Annotated[
        int | None,
        typer.Option(
            min=0, max=65535, help="3D view port on loopback (default 8081; 0: a free one)."
        ),
    ] = None,
) -> None:
    """Run the REST API, the live event stream, the dashboard and the live 3D view."""
    if hardware is not None and hardware not in ("mock", "serial"):
        raise typer.BadParameter("expected 'mock' or 'serial'.", param_hint="--hardware")
    try:
        serve(
            host=host,
            port=port,
            database_url=database_url,
            hardware=hardware,  # type: ignore[arg-type]
            turntable_port=turntable_port,
            finger_port=finger_port,
            tactile_port=tactile_port,
            api_token=api_token,
            log_level=log_level,
            viz=viz,
            viz_port=viz_port,
        )
    except ConfigurationError as exc:
        typer.echo(f"activetouch serve: {exc}", err=True)
        raise typer.Exit(code=2) from exc


if __name__ == "__main__":
    from threadpoolctl import threadpool_limits

    # As the activetouch command (app.cli.main), but numpy is loaded by now: limit it live.
    with threadpool_limits(limits=int(os.environ.get("ACTIVETOUCH_BLAS_THREADS", "1"))):
        typer.run(serve_command)
