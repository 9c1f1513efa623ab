"""Where the ``activetouch`` commands print (one pair of consoles for every command).

* :data:`results` — stdout: what a command produces, when it is not ``--json``.
* :data:`messages` — stderr: progress, status lines, warnings and errors.
* :func:`progress_bar` and :func:`fail` — a progress bar and a one-line error, both on stderr;
  :func:`read_text` and :func:`write_text` — a file, or that one-line error saying why not.

Both soft-wrap (a long path or action is never folded mid-word when redirected). Redirected,
Rich would draw tables 80 columns wide and fold every row, so :data:`results` is 120 wide then.
Values interpolated into a printed string must go through ``rich.markup.escape`` or carry a
numeric format spec: Rich reads ``[...]`` as markup (a path ``run[final].csv`` would lose
``[final]``, an array ``[nan 1.]`` vanishes, ``[/b]`` raises). ``tests/app/test_cli_markup.py``
checks every f-string handed to Rich in ``app/``.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import typer
from rich.console import Console
from rich.markup import escape
from rich.progress import (
    BarColumn,
    Progress,
    Task,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)
from rich.text import Text

results = Console(soft_wrap=True, width=None if sys.stdout.isatty() else 120)
messages = Console(stderr=True, soft_wrap=True)


class RemainingColumn(TimeRemainingColumn):
    """Time remaining: the task's own estimate when it gives one (field ``ends_at``, a
    ``time.monotonic()`` instant, e.g. from :class:`app.services.remaining.RemainingTime`),
    counting down between updates; otherwise Rich's, from the task's speed."""

    def render(self, task: Task) -> Text:
        ends_at = task.fields.get("ends_at")
        if ends_at is None:
            return super().render(task)
        seconds = max(0, round(ends_at - time.monotonic()))
        minutes, seconds = divmod(seconds, 60)
        hours, minutes = divmod(minutes, 60)
        return Text(f"{hours:d}:{minutes:02d}:{seconds:02d}", style="progress.remaining")


def progress_bar(disable: bool = False) -> Progress:
    """A rich progress bar on stderr."""
    return Progress(
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        TextColumn("{task.fields[status]}"),
        TimeElapsedColumn(),
        RemainingColumn(),
        console=messages,
        disable=disable,
        transient=False,
    )


def fail(message: str, code: int = 2) -> typer.Exit:
    """Print a one-line error to stderr and return the exit to raise (2: bad usage)."""
    messages.print(f"[red]error:[/red] {escape(message)}")
    return typer.Exit(code=code)


def read_text(path: Path, option: str = "") -> str:
    """The UTF-8 text of ``path``, or a one-line error (exit 2) saying why it cannot be read.

    Args:
        path: The file.
        option: The option that named it (``"--data"``), to start the message.
    """
    where = f"{option}: " if option else ""
    try:
        return path.read_text(encoding="utf-8-sig")
    except OSError as exc:
        raise fail(f"{where}cannot read {path}: {exc.strerror}") from None
    except UnicodeDecodeError as exc:
        raise fail(f"{where}{path} is not UTF-8 text ({exc.reason} at byte {exc.start})") from None


def write_text(path: Path, text: str, option: str = "") -> None:
    """Write ``text`` to ``path`` (UTF-8), or a one-line error (exit 2) saying why not."""
    where = f"{option}: " if option else ""
    try:
        path.write_text(text, encoding="utf-8")
    except OSError as exc:
        raise fail(f"{where}cannot write {path}: {exc.strerror}") from None
