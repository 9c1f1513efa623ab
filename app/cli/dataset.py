"""``activetouch dataset``: make a simulated training set, or bring recorded touches into the
server's database.

::

    activetouch dataset simulate exp1 --out exp1.csv     # also: activetouch dataset exp1 --out …
    activetouch dataset import-raw lab.jsonl --name "lab fingertip"
    activetouch dataset import-raw lab.jsonl --db lab.db --features means --json

``import-raw`` stores a raw-touch file (JSON lines, ``docs/raw-touches.md``) in the database
``activetouch serve`` uses, exactly as ``POST /datasets`` with ``application/x-ndjson`` does
(:func:`app.services.datasets.create_from_raw`): y is each channel's mean and every series is
kept, so ``POST /models`` with ``features: "whole"`` can fit it again without touching the
objects again. The database is ``--db`` (a file or a ``sqlite:///`` URL), else
``ACTIVETOUCH_DATABASE_URL`` or ``.env``, else ``sqlite:///activetouch.db``; it is created (at
this version's schema) when no file is there, and refused when it holds another version's
schema.

Exit codes: 0 imported; 2 bad input — touches with different channel sets, a sample rate
missing, a series with NaN/inf or shorter than the pipeline's window (``--features whole``, the
default: one Welch segment of a vibration channel, 4 samples of any other), named by line and
channel; nothing is stored then.

This module imports only typer and rich at the top (the CLI starts light).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.markup import escape

from app.cli.export import Db, open_session
from app.cli.output import fail, read_text
from app.cli.output import results as stdout
from app.cli.raw_data import FeaturesName

#: The first arguments that name a world: ``dataset WORLD …`` is ``dataset simulate WORLD …``.
SIMULATED_WORLDS = ("exp1", "exp2")


class _DatasetGroup(typer.core.TyperGroup):
    """The ``dataset`` group; ``dataset exp1 …`` (its form before the group) runs ``simulate``."""

    def parse_args(self, ctx: Any, args: list[str]) -> list[str]:  # ctx: typer's click Context
        if args and args[0] in SIMULATED_WORLDS:
            args = ["simulate", *args]
        return super().parse_args(ctx, args)


dataset_app = typer.Typer(
    cls=_DatasetGroup,
    help="Make a simulated training set, or import recorded raw touches into the database.",
    no_args_is_help=True,
)


@dataset_app.command("import-raw")
def import_raw_command(
    path: Annotated[Path, typer.Argument(help="Raw-touch file (JSON lines, docs/raw-touches.md).")],
    name: Annotated[
        str | None, typer.Option(help="The dataset's name (default: the file's name).")
    ] = None,
    features: Annotated[
        FeaturesName,
        typer.Option(
            help="The pipeline the touches are meant for: whole refuses series shorter than "
            "its window (256 samples of a vibration channel, 4 of any other); means only "
            "empty ones."
        ),
    ] = "whole",
    db: Db = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print the dataset as JSON.")] = False,
) -> None:
    """Import raw touches into the server's database, to fit with features later."""
    from app.documents.training_csv import MAX_NAME_CHARACTERS
    from app.errors import AppError
    from app.services import datasets
    from app.services.events import EventBus
    from core.errors import CoreError

    text = read_text(path)
    label = (name if name is not None else path.name)[:MAX_NAME_CHARACTERS]
    try:
        upload = datasets.read_raw_upload(text, features)
    except CoreError as exc:  # checked before the database is opened: nothing is written
        raise fail(f"{path}: {exc}") from None
    with open_session(db, create=True) as (database, session):
        try:
            public = datasets.store_raw_upload(
                session, EventBus(database), upload, label, source="import"
            )
        except (CoreError, AppError) as exc:
            session.rollback()
            raise fail(f"{path}: {exc}") from None
    document: dict[str, Any] = public.model_dump(mode="json")
    if as_json:
        sys.stdout.write(json.dumps(document) + "\n")
        return
    stdout.print(
        f"imported {public.n_samples:d} touches of {len(public.objects):d} objects from "
        f"{escape(str(path))} as dataset {public.id:d} ({escape(public.name)!r}); fit it with "
        f'POST /models {{"dataset_id": {public.id:d}, "features": "{escape(str(features))}"}}'
    )
