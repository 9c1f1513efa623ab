"""``activetouch demo``: the whole product on a simulated rig, ready for a first trial.

:func:`run_demo` starts the web app (dashboard + REST API) in-process on the mock hardware, the
viser 3D view beside it, and then prepares, through the REST API alone (the same calls a lab
script would make):

1. the rig connected and homed;
2. a training set: if the database holds no demo dataset yet, a collection run touches the demo
   objects on the simulated rig (progress in the terminal and live in the dashboard);
3. a model: if no ready model of that dataset exists, a manifold is fitted (progress likewise).

A second start reuses the dataset and the model in the database, so it is ready in seconds.
The newcomer then opens the dashboard and clicks **Start trial**. With ``world="exp1"``
the rig is left out: the paper's Experiment 1 training set is uploaded instead and trials run
against that synthetic world.

Use :class:`DemoServer` to embed the same composition (the browser tests do).
"""

from __future__ import annotations

import secrets
import signal
import threading
import time
import webbrowser
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any, Literal

import httpx
import numpy as np
import typer
import uvicorn
from rich.console import Console
from rich.markup import escape
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

from app import states
from app.cli.options import TableFile, TableName, table_choice
from app.cli.output import messages
from app.cli.serve import GracefulServer
from app.config import Settings, is_loopback
from app.documents.training_csv import write_training_csv
from app.main import API_PREFIX, create_app
from app.viz.live import LiveView
from core.evaluation import sample_experiment1

#: Name of the dataset the demo collects (and finds again on the next start).
DEMO_DATASET_NAME = "demo: simulated rig"

#: The simulated table of the demo: four cushions alike to any ordinary touch, told apart by a
#: deep press (docs/results.md, "What choosing the touch buys"). ``--table`` picks another.
DEMO_TABLE = "cushions"

#: Touches per object of the demo's training set: enough that some of each object's random
#: touches press deep (at the design's spread, about one in ten).
DEMO_TOUCHES_PER_OBJECT = 100


EXPERIMENT1_DATASET_NAME = "demo: paper Experiment 1"


@dataclass(frozen=True)
class DemoObject:
    """An object of the demo: name and turntable slot of the simulated rig."""

    name: str
    slot: int


@dataclass(frozen=True)
class DemoOptions:
    """How the demo starts.

    Attributes:
        host: Address of the web app; loopback by default. Any other address needs a token: if
            none is given, a random one is made and printed in the login URL.
        port: Port of the web app (0: a free one).
        viz_port: Port of the viser view (0: a free one).
        database_url: SQLite database (created and migrated if missing).
        world: ``rig``: the simulated rig (collection + trials on mock hardware);
            ``exp1``: the paper's Experiment 1 synthetic world, no rig (``experiment1``, its
            older name, is accepted too).
        objects: Objects to collect on the simulated rig; ``None``: the rig's own catalogue.
        table: The simulated rig's table (:data:`DEMO_TABLE` by default).
        table_file: A table file of your own objects, used instead of ``table``.
        touches_per_object: Touches per object of the training set.
        action_scale: Standard deviation of each component of the collection's random actions
            (``None``: the table's :attr:`~hardware.sim.materials.Table.action_std`; the
            cushions' 1.5 lets about one random touch in ten press down to the inserts).
        latent_dim: ds of the fitted manifold.
        restarts: Random restarts of the fit.
        max_iterations: L-BFGS iteration limit of each start of the fit (``None``: the fit's
            default; the 400 touches of the cushions fit in seconds).
        seed: Seed of the collection and of the fit.
        api_token: API token (required off loopback, made up when missing).
        open_browser: Open the dashboard in the default browser once it is up.
    """

    host: str = "127.0.0.1"
    port: int = 8000
    viz_port: int = 8081
    database_url: str = "sqlite:///data/demo.db"
    world: Literal["rig", "exp1", "experiment1"] = "rig"
    objects: tuple[DemoObject, ...] | None = None
    table: str = DEMO_TABLE
    table_file: Path | None = None
    touches_per_object: int = DEMO_TOUCHES_PER_OBJECT
    action_scale: float | None = None
    latent_dim: int = 2
    restarts: int = 2
    max_iterations: int | None = None
    seed: int = 0
    api_token: str | None = None
    open_browser: bool = True


@dataclass
class DemoTimings:
    """Seconds from :meth:`DemoServer.start` to each milestone (``None``: not reached/skipped)."""

    server_ready_s: float | None = None
    dataset_ready_s: float | None = None
    model_ready_s: float | None = None
    collected: bool = False
    fitted: bool = False


@dataclass
class DemoState:
    """What the demo prepared: ids, the trial settings to use, the URLs."""

    dataset_id: int
    model_id: int
    mode: str
    world: str
    dashboard_url: str
    viz_url: str
    timings: DemoTimings = field(default_factory=DemoTimings)


class DemoError(RuntimeError):
    """The demo could not be prepared; the message says which step failed and why."""


class DemoServer:
    """The web app in a uvicorn thread, the viser view, and the follower that links them.

    Use as a context manager, or call :meth:`start` then :meth:`stop`::

        with DemoServer(DemoOptions(port=0, viz_port=0, open_browser=False)) as demo:
            state = demo.prepare()
            ...

    Args:
        options: What to start.
        console: Where progress goes (stderr by default).
        settings_overrides: Extra :class:`~app.config.Settings` fields (tests).
    """

    def __init__(
        self,
        options: DemoOptions,
        console: Console | None = None,
        settings_overrides: dict[str, Any] | None = None,
    ) -> None:
        self.options = options
        self.console = console if console is not None else Console(stderr=True)
        token = options.api_token
        if token is None and not is_loopback(options.host):
            token = secrets.token_urlsafe(24)
        self.token = token
        self.settings = Settings(
            host=options.host,
            port=options.port,
            database_url=options.database_url,
            hardware="mock",
            sim_table=options.table,
            sim_table_file=options.table_file,
            api_token=token,
            **(settings_overrides or {}),
        )
        self.table = self.settings.simulated_table()
        self.timings = DemoTimings()
        self._started_at = 0.0
        self._server: uvicorn.Server | None = None
        self._thread: threading.Thread | None = None
        self._served = threading.Event()  # set when the server thread's run() has returned
        self.live: LiveView | None = None
        self._client: httpx.Client | None = None
        self.port = options.port

    # -- lifecycle ------------------------------------------------------------------------------

    def __enter__(self) -> DemoServer:
        self.start()
        return self

    def __exit__(self, *_: object) -> None:
        self.stop()

    @property
    def base_url(self) -> str:
        """The web app, as seen from this machine."""
        host = "127.0.0.1" if self.options.host in ("0.0.0.0", "::", "") else self.options.host
        return f"http://{host}:{self.port}"

    @property
    def dashboard_url(self) -> str:
        """The dashboard; with ``#token=`` when the server wants a token (a login link)."""
        fragment = f"#token={self.token}" if self.token else "#trials"
        return f"{self.base_url}/{fragment}"

    def start(self) -> None:
        """Start the viser view and the web app; return once the app answers."""
        self._started_at = time.perf_counter()
        self.live = LiveView(self.options.host, self.options.viz_port)
        app = create_app(self.settings)
        self.live.attach(app)
        config = uvicorn.Config(
            app,
            host=self.options.host,
            port=self.options.port,
            log_level="warning",
            timeout_graceful_shutdown=2,
        )
        self._server = GracefulServer(config)
        self._served.clear()
        self._thread = threading.Thread(target=self._serve, name="demo-uvicorn", daemon=True)
        self._thread.start()
        deadline = time.monotonic() + 120.0
        while not self._server.started:
            if not self._thread.is_alive():
                raise DemoError(
                    f"the web app did not start on {self.options.host}:{self.options.port} "
                    "(is the port taken? try --port)."
                )
            if time.monotonic() > deadline:
                raise DemoError("the web app did not start within 120 s.")
            time.sleep(0.05)
        sockets = [s for server in self._server.servers for s in (server.sockets or [])]
        if sockets:
            self.port = int(sockets[0].getsockname()[1])
        headers = {"Authorization": f"Bearer {self.token}"} if self.token else {}
        self._client = httpx.Client(
            base_url=self.base_url + API_PREFIX, headers=headers, timeout=30
        )
        self.timings.server_ready_s = self._elapsed()
        self.live.follow(self.base_url, token=self.token, on_error=self._follower_error)

    def stop(self) -> None:
        """Stop the follower, the web app and the view."""
        if self.live is not None:
            self.live.stop_following()
        if self._server is not None:
            # GracefulServer ends the open event streams (browser tabs) before it waits for
            # connections, so they close cleanly (no cancelled responses, no tracebacks).
            self._server.should_exit = True
        if self._thread is not None:
            # Waits on an Event, not Thread.join: see wait().
            if self._served.wait(timeout=10.0):
                self._thread.join(timeout=1.0)
            self._thread = None
        if self._client is not None:
            self._client.close()
            self._client = None
        if self.live is not None:
            self.live.close()
            self.live = None

    def wait(self) -> None:
        """Block until Ctrl-C (or until the web app stops)."""
        try:
            # Not Thread.join: a KeyboardInterrupt (Ctrl-C, or SIGTERM made one) that lands inside
            # join() can leave a running thread marked as stopped (CPython 3.11), and stop()
            # would then return at once and let the process exit mid-shutdown, cutting open
            # responses and skipping the app's lifespan shutdown. An Event wait is safe.
            while self._thread is not None and not self._served.wait(timeout=0.5):
                pass
        except KeyboardInterrupt:
            self.console.print("\nStopping…")

    def _serve(self) -> None:
        assert self._server is not None
        try:
            self._server.run()
        finally:
            self._served.set()

    def _elapsed(self) -> float:
        return time.perf_counter() - self._started_at

    def _follower_error(self, exc: Exception) -> None:
        if self._server is not None and not self._server.should_exit:
            self.console.log(
                f"[dim]3D view: event stream interrupted ({escape(str(exc))}); reconnecting[/dim]"
            )

    # -- REST helpers -------------------------------------------------------------------------

    @property
    def client(self) -> httpx.Client:
        """An HTTP client on ``/api/v1`` of the running app."""
        if self._client is None:
            raise DemoError("the demo server is not started.")
        return self._client

    def _call(self, method: str, path: str, what: str, **kwargs: Any) -> Any:
        response = self.client.request(method, path, **kwargs)
        if response.status_code >= 400:
            try:
                detail = response.json().get("detail", response.text)
            except ValueError:
                detail = response.text
            raise DemoError(f"{what}: {method} {path} answered {response.status_code}: {detail}")
        return response.json() if response.content else None

    def _list(self, path: str, what: str) -> list[dict[str, Any]]:
        page = self._call("GET", path, what, params={"limit": 1000})
        return list(page["data"])

    # -- preparation --------------------------------------------------------------------------

    def prepare(self) -> DemoState:
        """Make sure a dataset and a ready model exist (collect and fit if needed)."""
        if self.options.world in ("exp1", "experiment1"):
            dataset = self._experiment1_dataset()
            mode, world = "simulated", "exp1"
        else:
            dataset = self._rig_dataset()
            mode, world = "rig", "rig"
        self.timings.dataset_ready_s = self._elapsed()
        model = self._ready_model(dataset)
        self.timings.model_ready_s = self._elapsed()
        if self.live is not None:
            self.live.show_model(model["id"])
        return DemoState(
            dataset_id=int(dataset["id"]),
            model_id=int(model["id"]),
            mode=mode,
            world=world,
            dashboard_url=self.dashboard_url,
            viz_url=self.viz_url,
            timings=self.timings,
        )

    @property
    def action_scale(self) -> float:
        """The collection design's spread: the options', or the table's own."""
        from hardware.sim.materials import design_std

        return design_std(self.table, self.options.action_scale)

    @property
    def dataset_name(self) -> str:
        """The demo dataset's name: the default table's keeps the old name, others name theirs."""
        if self.table.name == "default" and self.options.table_file is None:
            return DEMO_DATASET_NAME
        return f"{DEMO_DATASET_NAME} ({self.table.name})"

    @property
    def viz_url(self) -> str:
        """The viser view as seen from this machine."""
        if self.live is None:
            raise DemoError("the demo server is not started.")
        return self.live.view.url

    def _experiment1_dataset(self) -> dict[str, Any]:
        for dataset in self._list("/datasets", "list datasets"):
            if dataset["name"] == EXPERIMENT1_DATASET_NAME and dataset["status"] == "ready":
                return dataset
        rng = np.random.default_rng(self.options.seed)
        data = sample_experiment1(rng, touches_per_object=self.options.touches_per_object)
        self.timings.collected = True
        created: dict[str, Any] = self._call(
            "POST",
            "/datasets",
            "upload the Experiment 1 training set",
            params={"name": EXPERIMENT1_DATASET_NAME},
            content=write_training_csv(data),
            headers={"Content-Type": "text/csv"},
        )
        return created

    def rig_objects(self) -> tuple[DemoObject, ...]:
        """The objects to collect: the options' list, else the simulated rig's catalogue."""
        if self.options.objects is not None:
            return self.options.objects
        rig = self._call("GET", "/rig", "read the rig")
        by_slot = (rig.get("detail") or {}).get("objects_by_slot") or []
        objects = tuple(
            DemoObject(name=str(name), slot=slot) for slot, name in enumerate(by_slot) if name
        )
        if len(objects) < 2:
            raise DemoError(
                "the simulated rig lists fewer than 2 objects in GET /rig "
                f"detail.objects_by_slot; received {by_slot!r}."
            )
        return objects

    def _rig_dataset(self) -> dict[str, Any]:
        for dataset in self._list("/datasets", "list datasets"):
            if dataset["name"] == self.dataset_name and dataset["status"] == "ready":
                return dataset
        rig = self._call("GET", "/rig", "read the rig")
        if not rig.get("connected"):
            self._call("POST", "/rig/connect", "connect the simulated rig")
        self._call("POST", "/rig/home", "home the simulated rig")
        objects = self.rig_objects()
        self.console.print(
            f"Collecting the training set on the simulated rig: {len(objects):d} objects × "
            f"{self.options.touches_per_object:d} touches "
            f"({escape(', '.join(o.name for o in objects))})."
        )
        run = self._call(
            "POST",
            "/collections",
            "start the collection",
            json={
                "name": self.dataset_name,
                "objects": [{"name": o.name, "slot": o.slot} for o in objects],
                "samples_per_object": self.options.touches_per_object,
                # Rounds at the actions the planners choose (docs/calibration.md, "Adaptive
                # training design"): the model is then right where the trials touch.
                "action_design": "adaptive",
                "action_scale": self.action_scale,
                "seed": self.options.seed,
            },
        )
        run = self._follow(
            f"/collections/{run['id']}",
            "collect",
            lambda r: (int(r.get("done") or 0), int(r.get("total") or 0), ""),
            done=lambda r: r["status"] in states.FINISHED,
        )
        if run["status"] != "completed" or run.get("dataset_id") is None:
            raise DemoError(
                f"the collection ended {run['status']}: {run.get('reason') or 'no reason given'}."
            )
        self.timings.collected = True
        collected: dict[str, Any] = self._call(
            "GET", f"/datasets/{run['dataset_id']}", "read the dataset"
        )
        return collected

    def _ready_model(self, dataset: dict[str, Any]) -> dict[str, Any]:
        for model in self._list("/models", "list models"):
            if model["dataset_id"] == dataset["id"] and model["status"] == "ready":
                return model
        self.console.print(
            f"Fitting the object manifold (ds = {self.options.latent_dim:d}, "
            f"{self.options.restarts:d} restarts) to {dataset['n_samples']:d} touches."
        )
        accepted = self._call(
            "POST",
            "/models",
            "start the fit",
            json={
                "dataset_id": dataset["id"],
                "latent_dim": self.options.latent_dim,
                "optimizer": "lbfgs",
                "restarts": self.options.restarts,
                "max_iterations": self.options.max_iterations,
                "seed": self.options.seed,
            },
        )

        def progress(model: dict[str, Any]) -> tuple[int, int, str]:
            p = model.get("progress") or {}
            best = p.get("best_log_likelihood")
            status = "" if best is None else f"log-lik {best:.1f}"
            return int(p.get("start") or 0), int(p.get("n_starts") or 0), status

        model = self._follow(
            f"/models/{accepted['id']}",
            "fit",
            progress,
            done=lambda m: m["status"] in states.MODEL_FINISHED,
        )
        if model["status"] != "ready":
            raise DemoError(f"the fit failed: {model.get('reason') or 'no reason given'}.")
        self.timings.fitted = True
        return model

    def _follow(
        self,
        path: str,
        label: str,
        progress: Callable[[dict[str, Any]], tuple[int, int, str]],
        done: Callable[[dict[str, Any]], bool],
        poll_s: float = 0.3,
    ) -> dict[str, Any]:
        """Poll ``path`` with a progress bar until ``done``; return the last record."""
        with Progress(
            TextColumn(f"[bold]{label:<8}"),
            BarColumn(),
            TextColumn("{task.completed}/{task.total}"),
            TextColumn("{task.fields[status]}"),
            TimeElapsedColumn(),
            TimeRemainingColumn(),
            console=self.console,
            transient=False,
        ) as bar:
            task = bar.add_task(label, total=None, status="")
            while True:
                record: dict[str, Any] = self._call("GET", path, label)
                completed, total, status = progress(record)
                bar.update(task, completed=completed, total=total or None, status=status)
                if done(record):
                    if total:
                        bar.update(task, completed=total)
                    return record
                time.sleep(poll_s)


def _interrupt(signum: int, frame: object) -> None:
    raise KeyboardInterrupt


def run_demo(options: DemoOptions, console: Console | None = None) -> DemoState:
    """Start the demo, prepare it, print where to go, and serve until Ctrl-C.

    Returns:
        What was prepared (after the server has stopped).
    """
    out = console if console is not None else Console(stderr=True)
    if options.database_url.startswith("sqlite:///") and not options.database_url.startswith(
        "sqlite:////"
    ):
        Path(options.database_url.removeprefix("sqlite:///")).parent.mkdir(
            parents=True, exist_ok=True
        )
    demo = DemoServer(options, console=out)
    if threading.current_thread() is threading.main_thread():
        # `docker stop` sends SIGTERM: stop as on Ctrl-C (runs end cleanly, the DB is closed).
        signal.signal(signal.SIGTERM, _interrupt)
    demo.start()
    try:
        out.print(
            f"[bold]ActiveTouch demo[/bold] — dashboard [link]{escape(demo.dashboard_url)}[/link] "
            f"(up after {demo.timings.server_ready_s:.1f} s), 3D view {escape(demo.viz_url)}"
        )
        if options.open_browser:
            webbrowser.open(demo.dashboard_url)
        state = demo.prepare()
        t = state.timings
        out.print(
            f"[green]Ready[/green] after {t.model_ready_s:.1f} s "
            f"({'collected' if t.collected else 'reused'} dataset #{state.dataset_id:d}, "
            f"{'fitted' if t.fitted else 'reused'} model #{state.model_id:d}).\n"
            f"Open [link]{escape(state.dashboard_url)}[/link] → Trials → [bold]Start trial[/bold]. "
            "Ctrl-C stops."
        )
        demo.wait()
        return state
    finally:
        demo.stop()


demo_app = typer.Typer(help="Run the demo on the simulated rig.")


@demo_app.command("demo")
def demo_command(
    host: Annotated[str, typer.Option(help="Address of the dashboard (loopback default).")] = (
        "127.0.0.1"
    ),
    port: Annotated[int, typer.Option(min=0, max=65535, help="Dashboard port.")] = 8000,
    viz_port: Annotated[int, typer.Option(min=0, max=65535, help="3D view port.")] = 8081,
    database_url: Annotated[str, typer.Option(help="SQLite URL.")] = "sqlite:///data/demo.db",
    world: Annotated[
        str,
        typer.Option(help="rig (simulated rig) or exp1 (the paper's world; alias experiment1)."),
    ] = "rig",
    table: TableName = None,
    table_file: TableFile = None,
    touches_per_object: Annotated[
        int, typer.Option(min=2, help="Training touches per object.")
    ] = DEMO_TOUCHES_PER_OBJECT,
    action_scale: Annotated[
        float | None,
        typer.Option(min=0.01, help="Std of each random action component (default: the table's)."),
    ] = None,
    latent_dim: Annotated[int, typer.Option(min=1, max=8, help="ds of the model.")] = 2,
    restarts: Annotated[int, typer.Option(min=0, help="Random restarts of the fit.")] = 2,
    seed: Annotated[int, typer.Option(min=0, help="Seed of collection and fit.")] = 0,
    api_token: Annotated[
        str | None, typer.Option(envvar="ACTIVETOUCH_API_TOKEN", help="Token (off loopback).")
    ] = None,
    browser: Annotated[bool, typer.Option(help="Open the dashboard in a browser.")] = True,
) -> None:
    """Start everything on the simulated rig: dashboard, 3D view, a trained model."""
    if world not in ("rig", "exp1", "experiment1"):
        raise typer.BadParameter(f"expected rig or exp1, received {world!r}", param_hint="--world")
    from hardware.sim.materials import TABLES

    table_choice(table, table_file)  # exit 2 naming what is wrong with a table file
    table = table or DEMO_TABLE
    if table not in TABLES:
        raise typer.BadParameter(
            f"{table!r} is not a simulated table; choose from {sorted(TABLES)}",
            param_hint="--table",
        )
    options = DemoOptions(
        host=host,
        port=port,
        viz_port=viz_port,
        database_url=database_url,
        world="rig" if world == "rig" else "exp1",
        table=table,
        table_file=table_file,
        touches_per_object=touches_per_object,
        action_scale=action_scale,
        latent_dim=latent_dim,
        restarts=restarts,
        seed=seed,
        api_token=api_token or None,
        open_browser=browser,
    )
    try:
        run_demo(options)
    except DemoError as exc:
        messages.print(f"[red]demo failed:[/red] {escape(str(exc))}")
        raise typer.Exit(code=1) from exc
