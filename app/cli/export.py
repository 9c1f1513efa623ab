"""``activetouch export``: read what the server stored (datasets, models, trials) into files.

::

    activetouch export list                              # what the database holds
    activetouch export dataset 3 --out data.csv          # the training CSV
    activetouch export dataset 3 --raw --out raw.jsonl   # its raw touches (to featurise again)
    activetouch export model 2 --out model.json          # the model document
    activetouch export trial 7 --out steps.csv           # one row per step
    activetouch export trial 7 --json > trial.json       # the trial as GET /trials/7 returns it

The database is the one ``activetouch serve`` uses: ``--db`` (a file or a ``sqlite:///`` URL),
else ``ACTIVETOUCH_DATABASE_URL`` or ``.env``, else ``sqlite:///activetouch.db``. It is read
through the server's own services (a running server may keep writing to it), never created or
migrated here. Without ``--out`` the document goes to stdout.

Exit codes: 0 exported; 1 the item exists but cannot be exported yet (a model still fitting or
failed); 2 bad input (no database there, an older or newer database schema, an unknown id).
"""

from __future__ import annotations

import csv
import io
import json
import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer
from rich.markup import escape

from app.cli.output import messages as console
from app.cli.output import results

if TYPE_CHECKING:
    from sqlalchemy.orm import Session

    from app.config import Settings
    from app.db import Database
    from app.schemas import Page, TrialPublic

export_app = typer.Typer(
    help="Export datasets, models and trials from the server's database (read-only).",
    no_args_is_help=True,
)

Db = Annotated[
    str | None,
    typer.Option(
        "--db",
        help="SQLite file or sqlite:/// URL (default: as serve: ACTIVETOUCH_DATABASE_URL, "
        ".env, sqlite:///activetouch.db).",
    ),
]
Out = Annotated[Path | None, typer.Option("--out", help="File to write (default: stdout).")]
AsJson = Annotated[bool, typer.Option("--json", help="Print JSON on stdout.")]

#: Rows per page when listing everything.
_PAGE = 500


def fail(message: str, code: int = 2) -> typer.Exit:
    """Print a one-line error to stderr and return the exit to raise."""
    console.print(f"[red]error:[/red] {escape(message)}")
    return typer.Exit(code=code)


def database_url(db: str | None, settings: Settings) -> str:
    """The SQLite URL of ``--db`` (a path or a URL), or the one ``serve`` would use."""
    if db is None:
        return settings.database_url
    if "://" in db:
        return db
    return f"sqlite:///{Path(db).expanduser().absolute()}"


def _database_file(url: str, must_exist: bool = True) -> Path:
    """The file behind a SQLite URL; exit 2 when it is not a SQLite file (that exists, unless
    ``must_exist`` is false)."""
    from sqlalchemy.engine import make_url
    from sqlalchemy.exc import ArgumentError

    try:
        parsed = make_url(url)
    except ArgumentError:
        raise fail(f"--db: {url!r} is neither a file nor a database URL.") from None
    if parsed.get_backend_name() != "sqlite":
        raise fail(f"--db: only SQLite databases are supported, received {url!r}.")
    if not parsed.database or parsed.database == ":memory:":
        raise fail(f"--db: {url!r} is an in-memory database; there is nothing to export.")
    path = Path(parsed.database).expanduser()
    if must_exist and not path.is_file():
        raise fail(
            f"no database at {path} (give --db FILE, or set ACTIVETOUCH_DATABASE_URL as for "
            "activetouch serve)."
        )
    return path


def _check_schema(database: Database, path: Path, migrations_dir: Path) -> None:
    """Exit 2 unless the database is an ActiveTouch database at this version's schema."""
    from alembic.config import Config
    from alembic.runtime.migration import MigrationContext
    from alembic.script import ScriptDirectory

    with database.engine.connect() as connection:
        current = MigrationContext.configure(connection).get_current_revision()
    config = Config()
    config.set_main_option("script_location", str(migrations_dir))
    head = ScriptDirectory.from_config(config).get_current_head()
    if current is None:
        raise fail(f"{path} is not an ActiveTouch database (no schema revision).")
    if current != head:
        raise fail(
            f"{path} has schema revision {current}, this version reads {head}: start "
            "`activetouch serve` on it once to upgrade it (or use the matching version)."
        )


@contextmanager
def open_session(db: str | None, create: bool = False) -> Iterator[tuple[Database, Session]]:
    """The database ``serve`` would use (or ``--db``), checked, and a session on it.

    Args:
        db: ``--db``.
        create: Create the database (at this version's schema, as ``serve`` does) when no
            file is there.

    Raises:
        typer.Exit: (code 2) no such file (unless ``create``), not SQLite, not an ActiveTouch
            database, or a schema of another version.
    """
    from sqlalchemy.exc import DatabaseError

    from app.config import Settings
    from app.db import Database, upgrade_to_head

    settings = Settings()
    url = database_url(db, settings)
    path = _database_file(url, must_exist=not create)
    if create and not path.parent.is_dir():
        raise fail(f"--db: no directory {path.parent} to create the database in.")
    new = not path.exists()
    database = Database(url)
    try:
        if new:
            upgrade_to_head(database.engine, settings.migrations_dir)
        _check_schema(database, path, settings.migrations_dir)
        with database.session() as session:
            yield database, session
    except DatabaseError as exc:
        raise fail(f"cannot read {path}: {exc.orig}") from None
    finally:
        database.dispose()


def _write(text: str, out: Path | None, what: str) -> None:
    """Write ``text`` to ``out`` (saying so on stderr) or to stdout."""
    if out is None:
        sys.stdout.write(text if text.endswith("\n") else text + "\n")
        return
    try:
        out.write_text(text, encoding="utf-8")
    except OSError as exc:
        raise fail(f"--out: cannot write {out}: {exc.strerror}") from None
    console.print(f"wrote {escape(what)} to {escape(str(out))}")


@contextmanager
def _app_errors() -> Iterator[None]:
    """A service's not-found (exit 2) or conflict (exit 1) as a one-line error."""
    from app.errors import AppError, ConflictError

    try:
        yield
    except ConflictError as exc:
        raise fail(exc.message, 1) from None
    except AppError as exc:
        raise fail(exc.message) from None


@export_app.command("list")
def list_command(db: Db = None, as_json: AsJson = False) -> None:
    """List the datasets, models and trials in the database."""
    from app.services import datasets, models, trial_views

    with open_session(db) as (_, session):
        listing = {
            "datasets": _all(lambda limit, offset: datasets.list_page(session, limit, offset)),
            "models": _all(lambda limit, offset: models.list_page(session, None, limit, offset)),
            "trials": _all(
                lambda limit, offset: trial_views.list_page(session, None, None, limit, offset)
            ),
        }
    if as_json:
        sys.stdout.write(json.dumps(listing) + "\n")
        return
    _print_listing(listing)


def _all(page: Callable[[int, int], Page[Any]]) -> list[dict[str, Any]]:
    """Every row of a paged service list, as JSON-ready dicts (newest first)."""
    rows: list[dict[str, Any]] = []
    while True:
        result = page(_PAGE, len(rows))
        rows += [item.model_dump(mode="json") for item in result.data]
        if not result.data or len(rows) >= result.count:
            return rows


def _created(row: dict[str, Any]) -> str:
    """A row's creation time to the second (``YYYY-MM-DDTHH:MM:SS``)."""
    return str(row["created_at"][:19])


def _print_listing(listing: dict[str, list[dict[str, Any]]]) -> None:
    from rich.table import Table

    out = results
    # A column: its header and the row's field shown, or a function of the row.
    columns: dict[str, list[tuple[str, str | Callable[[dict[str, Any]], Any]]]] = {
        "datasets": [
            ("id", "id"),
            ("name", "name"),
            ("source", "source"),
            ("status", "status"),
            ("samples", "n_samples"),
            ("objects", lambda r: len(r["objects"])),
            ("dx", "action_dim"),
            ("dy", "observation_dim"),
            ("created", _created),
        ],
        "models": [
            ("id", "id"),
            ("status", "status"),
            ("dataset", "dataset_id"),
            ("ds", "latent_dim"),
            ("optimizer", "optimizer"),
            (
                "log-likelihood",
                lambda r: "" if r["log_likelihood"] is None else f"{r['log_likelihood']:.3f}",
            ),
            ("created", _created),
        ],
        "trials": [
            ("id", "id"),
            ("model", "model_id"),
            ("mode", "mode"),
            ("policy", "policy"),
            ("status", "status"),
            ("steps", "n_steps"),
            ("target", lambda r: r["target"] or ""),
            ("answer", lambda r: (r["result"] or {}).get("object") or ""),
            ("created", _created),
        ],
    }
    for kind, spec in columns.items():
        rows = listing[kind]
        if not rows:
            out.print(f"[bold]{escape(kind)}[/bold]: none")
            continue
        table = Table(title=f"{escape(kind)} ({len(rows):d})", title_justify="left")
        for header, _ in spec:
            table.add_column(header)
        for row in rows:
            cells = (row[cell] if isinstance(cell, str) else cell(row) for _, cell in spec)
            table.add_row(*(escape(str(value)) for value in cells))
        out.print(table)


@export_app.command("dataset")
def dataset_command(
    dataset_id: Annotated[int, typer.Argument(help="Dataset id (see export list).")],
    out: Out = None,
    raw: Annotated[
        bool,
        typer.Option(
            "--raw",
            help="The raw touches (JSON lines, docs/raw-touches.md) instead of the CSV, to "
            "featurise again with fit --features whole.",
        ),
    ] = False,
    db: Db = None,
) -> None:
    """A dataset as a training CSV (object,x_1..x_dx,y_1..y_dy) or its raw touches."""
    from app.services import datasets

    with open_session(db) as (_, session), _app_errors():
        summary = datasets.get(session, dataset_id)
        export = datasets.export_raw if raw else datasets.export_csv
        text = export(session, dataset_id)
    if summary.status != "ready":
        console.print(
            f"[yellow]note:[/yellow] dataset {dataset_id:d} is {escape(summary.status)}: "
            f"exporting the {summary.n_samples:d} samples recorded."
        )
    _write(text, out, f"dataset {dataset_id} ({summary.n_samples} samples)")


@export_app.command("model")
def model_command(
    model_id: Annotated[int, typer.Argument(help="Model id (see export list).")],
    out: Out = None,
    db: Db = None,
) -> None:
    """A fitted model as its self-contained model document (JSON)."""
    from app.services.events import EventBus
    from app.services.models import ReadyModels

    with open_session(db) as (database, session), _app_errors():
        document = ReadyModels(database, EventBus(database)).export_document(session, model_id)
    _write(json.dumps(document, indent=1), out, f"model {model_id}")


@export_app.command("trial")
def trial_command(
    trial_id: Annotated[int, typer.Argument(help="Trial id (see export list).")],
    out: Out = None,
    as_json: Annotated[
        bool, typer.Option("--json", help="The whole trial as JSON (as GET /trials/{id}).")
    ] = False,
    db: Db = None,
) -> None:
    """A trial's steps as CSV (one row per touch), or the whole trial as JSON."""
    from app.services import datasets, models, trial_views

    with open_session(db) as (_, session), _app_errors():
        trial = trial_views.get(session, trial_id)
        model = models.get(session, trial.model_id)
        names = datasets.get(session, model.dataset_id).objects
    if as_json:
        text = trial.model_dump_json()
    else:
        text = trial_steps_csv(trial, model.action_dim, model.observation_dim, names)
    _write(text, out, f"trial {trial_id} ({len(trial.steps)} steps)")


def trial_steps_csv(
    trial: TrialPublic, action_dim: int, observation_dim: int, object_names: list[str]
) -> str:
    """One row per step: ``step, x_1..x_dx, y_1..y_dy, mutual_information, mean_1..mean_ds,
    cov_i_j (i ≤ j), nearest_object, answer, p_<object>..., stop_reason, duration_s,
    created_at`` (floats written with ``repr``)."""
    latent_dim = len(trial.prior_mean)
    pairs = [(i, j) for i in range(latent_dim) for j in range(i, latent_dim)]
    header = (
        ["step"]
        + [f"x_{i + 1}" for i in range(action_dim)]
        + [f"y_{i + 1}" for i in range(observation_dim)]
        + ["mutual_information"]
        + [f"mean_{i + 1}" for i in range(latent_dim)]
        + [f"cov_{i + 1}_{j + 1}" for i, j in pairs]
        + ["nearest_object", "answer"]
        + [f"p_{name}" for name in object_names]
        + ["stop_reason", "duration_s", "created_at"]
    )
    text = io.StringIO()
    writer = csv.writer(text, lineterminator="\n")
    writer.writerow(header)
    for step in trial.steps:
        mi = step.mutual_information
        writer.writerow(
            [step.step]
            + [repr(v) for v in step.action]
            + [repr(v) for v in step.observation]
            + ["" if mi is None else repr(mi)]
            + [repr(v) for v in step.belief.mean]
            + [repr(step.belief.cov[i][j]) for i, j in pairs]
            + [step.nearest_object, step.answer]
            + [repr(step.probabilities.get(name, 0.0)) for name in object_names]
            + [step.stop_reason or "", repr(step.duration_s), step.created_at.isoformat()]
        )
    return text.getvalue()
