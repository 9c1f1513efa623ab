"""The live 3D view beside a running web app: the viser view, its route, its trial follower.

Both ``activetouch serve`` and ``activetouch demo`` compose it the same way::

    live = LiveView(host, viz_port)          # the viser server starts here
    app = create_app(settings)
    live.attach(app)                         # GET /api/v1/viz → {"port", "url", "clients"}
    ... start the web app ...
    live.follow(base_url, token)             # trials drawn as they run (REST + events only)
    ...
    live.close()

The dashboard embeds the view at ``GET /api/v1/viz``'s port on the page's own host name, so the
view binds the web app's address (loopback by default, DESIGN.md Security).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from fastapi import FastAPI

from app.main import API_PREFIX
from app.viz.follower import TrialFollower
from app.viz.view import ManifoldView


def add_viz_route(app: FastAPI, view: ManifoldView) -> None:
    """Add ``GET /api/v1/viz`` → ``{"port", "url", "clients"}`` so the dashboard can embed the
    view.

    The route goes first: the dashboard's static mount at ``/`` would otherwise shadow it.
    """

    def viz() -> dict[str, Any]:
        return {"port": view.port, "url": view.url, "clients": view.n_clients}

    app.add_api_route(f"{API_PREFIX}/viz", viz, methods=["GET"], tags=["viz"])
    route = app.router.routes.pop()
    app.router.routes.insert(0, route)


class LiveView:
    """A :class:`~app.viz.ManifoldView` kept in step with a web app's trials.

    Args:
        host: Address the viser server binds (the web app's).
        port: Its port; 0 picks a free one, and viser tries the next ports when it is taken.
    """

    def __init__(self, host: str, port: int) -> None:
        self.view = ManifoldView(host=host, port=port)
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
