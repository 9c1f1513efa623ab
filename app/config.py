"""Settings of the web app, read from the environment (prefix ``ACTIVETOUCH_``) and ``.env``.

Nothing here is a module-level instance: :func:`app.main.create_app` is handed a
:class:`Settings`, so tests build their own without patching.
"""

from __future__ import annotations

import ipaddress
import os
from pathlib import Path
from typing import TYPE_CHECKING, Literal

from pydantic import Field, SecretStr
from pydantic_settings import BaseSettings, SettingsConfigDict

if TYPE_CHECKING:
    from hardware.sim.materials import Table

#: Repository root (``app/..``): where ``migrations/`` and ``frontend/`` live.
PROJECT_ROOT = Path(__file__).resolve().parent.parent


class ConfigurationError(RuntimeError):
    """The settings are unsafe or inconsistent; the server refuses to start."""


class Settings(BaseSettings):
    """Everything the server needs to start.

    Attributes:
        host: Address to bind. Anything but a loopback address requires ``api_token``.
        port: TCP port.
        database_url: SQLAlchemy URL of the SQLite database.
        api_token: Bearer token for mutating endpoints; required off loopback.
        hardware: ``mock`` (simulated rig) or ``serial`` (real devices on the ports below).
        sim_table: The simulated rig's table of objects by name (``mock`` hardware, and rig
            evaluations; :data:`hardware.sim.materials.TABLES`).
        sim_table_file: A table file of your own objects (JSON or TOML,
            :mod:`hardware.sim.table_file`) used instead of ``sim_table``.
        turntable_port: Serial port of the GRBL turntable controller (serial hardware).
        finger_port: Serial port of the Dynamixel bus (serial hardware).
        tactile_port: Serial port of the tactile sensor stream (serial hardware).
        settle_s: Rest before each touch, so that a heated sensor's skin recovers its
            temperature (:attr:`hardware.rig.RigConfig.settle_s`; 0: no rest).
        max_upload_bytes: Largest request body accepted (uploads included).
        event_log_size: How many events are kept for ``Last-Event-ID`` resume.
        max_training_touches: Largest number of touches a fit or imported model may have (the
            GP costs O(N³) time and O(N²) memory per feature).
        max_simulated_step_interval_s: Upper bound of the pause a client may ask between the
            steps of a simulated trial.
        frontend_dir: Folder of the static dashboard served at ``/`` (if it exists).
        migrations_dir: Folder of the Alembic environment.
        viz: Whether ``activetouch serve`` runs the live 3D view (viser) beside the app.
        viz_port: Its port (0: a free one). It binds loopback; off loopback the app proxies it
            at ``/viser/`` behind the sign-in (see :mod:`app.security`).
        require_auth_for_reads: Lock reads on loopback too: every ``/api/v1`` request (reads
            and the event stream too) and the 3D view then need the token or a signed-in
            session, as they always do off loopback. Set it behind a reverse proxy on the same
            machine, where every client appears as loopback.
        session_ttl_s: How long a dashboard sign-in lasts without use (each request renews it).
            Sessions live in memory: a restart signs everyone out.
        auth_max_failures: Wrong tokens (sign-in or bearer header) one client address may send
            within ``auth_failure_window_s``; beyond, its attempts answer 429 with
            ``Retry-After`` until the oldest failure is that old (:mod:`app.security.attempts`).
        auth_failure_window_s: The window of ``auth_max_failures``, in seconds.
        max_concurrent_fits: Most model fits the server runs at once; more wait ``queued`` in
            the order they came (default: the cores this process may use).
        dask_scheduler: Address of a Dask scheduler (``tcp://host:8786``) that evaluations
            run their trials on; none: in-process, or a local cluster of the request's workers.
    """

    model_config = SettingsConfigDict(
        env_prefix="ACTIVETOUCH_", env_file=".env", env_file_encoding="utf-8", extra="ignore"
    )

    host: str = "127.0.0.1"
    port: int = Field(default=8000, ge=0, le=65535)
    database_url: str = "sqlite:///activetouch.db"
    api_token: SecretStr | None = None
    hardware: Literal["mock", "serial"] = "mock"
    sim_table: str = "default"
    sim_table_file: Path | None = None
    turntable_port: str | None = None
    finger_port: str | None = None
    tactile_port: str | None = None
    settle_s: float = Field(default=20.0, ge=0.0)
    max_upload_bytes: int = Field(default=10 * 1024 * 1024, ge=1024)
    event_log_size: int = Field(default=10_000, ge=100)
    max_training_touches: int = Field(default=5000, ge=4)
    max_simulated_step_interval_s: float = Field(default=10.0, ge=0.0)
    frontend_dir: Path = PROJECT_ROOT / "frontend"
    migrations_dir: Path = PROJECT_ROOT / "migrations"
    viz: bool = True
    viz_port: int = Field(default=8081, ge=0, le=65535)
    max_concurrent_fits: int = Field(default_factory=lambda: available_cores(), ge=1)
    dask_scheduler: str | None = None
    require_auth_for_reads: bool = False
    session_ttl_s: float = Field(default=12 * 3600.0, gt=0.0, le=30 * 24 * 3600.0)
    auth_max_failures: int = Field(default=10, ge=1, le=10_000)
    auth_failure_window_s: float = Field(default=60.0, gt=0.0, le=24 * 3600.0)

    @property
    def token(self) -> str | None:
        """The API token in clear, or ``None`` when none is set."""
        if self.api_token is None:
            return None
        value = self.api_token.get_secret_value()
        return value or None

    @property
    def reads_need_auth(self) -> bool:
        """Whether reads need authentication too: off loopback (decided by the bind address, not
        the client's: behind a local proxy or tunnel every client looks like loopback) or when
        ``require_auth_for_reads`` asks for it."""
        return self.require_auth_for_reads or not is_loopback(self.host)

    def simulated_table(self) -> Table:
        """The simulated rig's table: read from ``sim_table_file``, or ``sim_table`` by name.

        Raises:
            ConfigurationError: An unknown name, or a table file that cannot be used (the
                message names the object and the field).
        """
        from hardware.errors import ConfigurationError as TableError
        from hardware.sim.materials import get_table
        from hardware.sim.table_file import read_table_file

        try:
            if self.sim_table_file is not None:
                return read_table_file(self.sim_table_file)
            return get_table(self.sim_table)
        except TableError as exc:
            field = "sim_table_file" if self.sim_table_file is not None else "sim_table"
            raise ConfigurationError(f"{field}: {exc}") from None

    def check_safe_to_serve(self) -> None:
        """Refuse to bind a non-loopback address without an API token.

        Raises:
            ConfigurationError: ``host`` is not a loopback address (or reads need auth) and no
                token is set, the database URL is not SQLite, or the simulated table is unusable.
        """
        if not self.database_url.startswith("sqlite"):
            raise ConfigurationError(
                f"database_url: only SQLite is supported, received {self.database_url!r}."
            )
        if not is_loopback(self.host) and self.token is None:
            raise ConfigurationError(
                f"Refusing to bind {self.host!r} without an API token: set "
                "ACTIVETOUCH_API_TOKEN (or --api-token), or bind 127.0.0.1."
            )
        if self.reads_need_auth and self.token is None:
            raise ConfigurationError(
                "require_auth_for_reads is set without an API token: set ACTIVETOUCH_API_TOKEN."
            )
        self.simulated_table()  # an unusable table refuses to serve, naming the object and field


def available_cores() -> int:
    """How many CPU cores this process may run on (its affinity, where the OS tells it)."""
    if hasattr(os, "sched_getaffinity"):
        return max(1, len(os.sched_getaffinity(0)))
    return max(1, os.cpu_count() or 1)


def is_loopback(host: str) -> bool:
    """Whether ``host`` is a loopback address (``localhost``, 127.0.0.0/8, ``::1``)."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False
