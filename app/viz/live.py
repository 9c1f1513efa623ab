"""The live 3D view beside a running web app: the viser view, its route, its trial follower.

Both ``activetouch serve`` and ``activetouch demo`` compose it the same way::

    live = LiveView(host, viz_port)          # the viser server starts here
    app = create_app(settings)
    live.attach(app)                         # GET /api/v1/viz → {"port", "url", "clients"}
    ... start the web app ...
    live.follow(base_url, token)             # trials drawn as they run (REST + events only)
    ...
    live.close()

The view always binds loopback. On loopback the dashboard embeds it at ``GET /api/v1/viz``'s port
on the page's own host name, as before; off loopback (when reads need auth) ``/api/v1/viz`` gives
``path: "viser/"`` instead and the dashboard embeds the view through the app
(:mod:`app.viz.proxy`), behind the sign-in.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from fastapi import FastAPI

from app.config import is_loopback
from app.main import API_PREFIX
from app.security.gate import VISER_PREFIX
from app.viz.follower import TrialFollower
from app.viz.proxy import ViserProxy, proxy_routes
from app.viz.view import ManifoldView


def add_viz_route(app: FastAPI, view: ManifoldView) -> None:
    """Add ``GET /api/v1/viz`` → ``{"port", "url", "clients", "path"}`` so the dashboard can
    embed the view, and the proxy of the view at ``/viser/``.

    ``path`` is where to embed the view relative to the dashboard (``"viser/"``, the proxy)
    when reads need auth, else ``None`` (embed ``port`` directly, on loopback).
    The routes go first: the dashboard's static mount at ``/`` would otherwise shadow them.
    """
    proxied = bool(app.state.settings.reads_need_auth)

    def viz() -> dict[str, Any]:
        return {
            "port": view.port,
            "url": view.url,
            "clients": view.n_clients,
            "path": f"{VISER_PREFIX.lstrip('/')}/" if proxied else None,
        }

    app.add_api_route(f"{API_PREFIX}/viz", viz, methods=["GET"], tags=["viz"])
    route = app.router.routes.pop()
    app.router.routes.insert(0, route)
    for position, proxy_route in enumerate(proxy_routes(ViserProxy(view.host, lambda: view.port))):
        app.router.routes.insert(1 + position, proxy_route)


class LiveView:
    """A :class:`~app.viz.ManifoldView` kept in step with a web app's trials.

    Args:
        host: The web app's address. The viser server binds it when it is a loopback address,
            else ``127.0.0.1``: off loopback the view is reached only through the app's proxy.
        port: Its port; 0 picks a free one, and viser tries the next ports when it is taken.
    """

    def __init__(self, host: str, port: int) -> None:
        self.view = ManifoldView(host=host if is_loopback(host) else "127.0.0.1", port=port)
        self._follower: TrialFollower | None = None

    def attach(self, app: FastAPI) -> None:
        """Add the view's route to ``app`` (before it starts)."""
        add_viz_route(app, self.view)

    def follow(
        self,
        base_url: str,
        token: str | None = None,
        on_error: Callable[[Exception], None] | None = None,
    ) -> None:
        """Follow the app at ``base_url`` (once it answers): draw each trial as it runs."""
        if self._follower is None:
            self._follower = TrialFollower(
                self.view, base_url, token=token, on_error=on_error
            ).start()

    def show_model(self, model_id: int) -> None:
        """Draw a model now (before any trial of it runs); no-op when not following."""
        if self._follower is not None:
            self._follower.show_model(model_id)

    def stop_following(self) -> None:
        """Stop the follower (idempotent); the view stays up."""
        if self._follower is not None:
            self._follower.stop()
            self._follower = None

    def close(self) -> None:
        """Stop following and close the viser server (idempotent)."""
        self.stop_following()
        self.view.close()
