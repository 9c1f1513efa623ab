"""``activetouch serve``: run the web app with uvicorn.

:func:`serve` is the function; :func:`serve_command` is the typer command the CLI registers
(``app.command("serve")(serve_command)``). ``python -m app.server_cli`` runs it on its own.
:class:`GracefulServer` is the uvicorn server both ``serve`` and the demo run: its shutdown ends
the open event streams first, so it neither hangs on them nor cancels them with tracebacks.
"""

from __future__ import annotations

import socket
import sys
from typing import Annotated, Any, Literal

import typer
import uvicorn
from starlette.applications import Starlette

from app.config import ConfigurationError, Settings
from app.main import create_app

#: Seconds uvicorn waits for open responses at shutdown before cancelling them.
GRACEFUL_SHUTDOWN_S = 5


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
) -> None:
    """Serve the API (and the dashboard) until interrupted.

    Arguments left ``None`` come from the environment (``ACTIVETOUCH_*``), ``.env`` or the
    defaults (127.0.0.1:8000, ``sqlite:///activetouch.db``, mock hardware).

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
        }.items()
        if value is not None
    }
    settings = Settings(**overrides)
    app = create_app(settings)  # refuses unsafe settings before anything binds
    config = uvicorn.Config(
        app,
        host=settings.host,
        port=settings.port,
        log_level=log_level,
        timeout_graceful_shutdown=GRACEFUL_SHUTDOWN_S,
    )
    server = GracefulServer(config)
    server.run()
    if not server.started:  # as uvicorn.run: the port was taken, or the app failed to start
        sys.exit(3)


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
) -> None:
    """Run the REST API, the live event stream and the dashboard."""
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
        )
    except ConfigurationError as exc:
        typer.echo(f"activetouch serve: {exc}", err=True)
        raise typer.Exit(code=2) from exc


if __name__ == "__main__":
    typer.run(serve_command)
