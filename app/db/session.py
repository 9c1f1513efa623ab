"""The database of one app: engine (SQLite, WAL, foreign keys), sessions and migrations (the
tables are in :mod:`app.db.tables`)."""

from __future__ import annotations

import sqlite3
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from alembic import command
from alembic.config import Config
from sqlalchemy import Engine, create_engine, event
from sqlalchemy.engine import make_url
from sqlalchemy.orm import Session, sessionmaker

#: How long a writer waits for SQLite's write lock before failing (milliseconds).
BUSY_TIMEOUT_MS = 30_000


def _on_connect(dbapi_connection: Any, _record: Any) -> None:
    """Per-connection pragmas: WAL journal, foreign keys, busy timeout."""
    if not isinstance(dbapi_connection, sqlite3.Connection):
        return
    cursor = dbapi_connection.cursor()
    cursor.execute("PRAGMA journal_mode=WAL")
    # NORMAL is durable across a process crash (SIGKILL) in WAL mode; only power loss can
    # lose the last transactions.
    cursor.execute("PRAGMA synchronous=NORMAL")
    cursor.execute("PRAGMA foreign_keys=ON")
    cursor.execute(f"PRAGMA busy_timeout={BUSY_TIMEOUT_MS}")
    cursor.close()


def make_engine(database_url: str) -> Engine:
    """A SQLAlchemy engine for ``database_url`` (SQLite), safe to share between threads."""
    url = make_url(database_url)
    if url.get_backend_name() != "sqlite":
        raise ValueError(f"database_url: only SQLite is supported, received {database_url!r}.")
    if url.database and url.database != ":memory:":
        Path(url.database).expanduser().parent.mkdir(parents=True, exist_ok=True)
    engine = create_engine(
        url,
        connect_args={"check_same_thread": False, "timeout": BUSY_TIMEOUT_MS / 1000},
        pool_size=10,
        max_overflow=30,
        pool_timeout=60,
    )
    event.listen(engine, "connect", _on_connect)
    return engine


def upgrade_to_head(engine: Engine, migrations_dir: Path) -> None:
    """Apply every Alembic migration in ``migrations_dir`` to the database of ``engine``."""
    config = Config()
    config.set_main_option("script_location", str(migrations_dir))
    config.set_main_option("sqlalchemy.url", engine.url.render_as_string(hide_password=False))
    with engine.begin() as connection:
        config.attributes["connection"] = connection
        command.upgrade(config, "head")


class Database:
    """Engine and session factory of one app instance.

    Args:
        database_url: SQLAlchemy URL (SQLite).
    """

    def __init__(self, database_url: str) -> None:
        self.engine = make_engine(database_url)
        self._sessions = sessionmaker(self.engine, expire_on_commit=False)

    @contextmanager
    def session(self) -> Iterator[Session]:
        """A session that rolls back on error and is always closed."""
        session = self._sessions()
        try:
            yield session
        except BaseException:
            session.rollback()
            raise
        finally:
            session.close()

    def dispose(self) -> None:
        """Close every pooled connection."""
        self.engine.dispose()
