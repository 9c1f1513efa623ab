"""The training CSV (docs/usage.md): header ``object,x_1,...,x_dx,y_1,...,y_dy``, one touch per row.

An optional ``placement`` column after ``object`` (integers ≥ 0) records which placement of its
object each touch met (``activetouch collect --placements``); the fit estimates the placement
effect from it (docs/calibration.md). An optional ``time_s`` column after those (finite seconds,
on every row or on none) records when each touch was made, in seconds since the collection's
first touch (``activetouch collect`` and the server's collections write it); the fit estimates
the drift shared by touches made close together from it (:mod:`core.gp.drift_effect`). An
optional ``duration_s`` column after those (the same finite seconds > 0 on every row, or none)
records how long each touch lasted as planned: an action means a trajectory of that duration,
so a model keeps it and recognition touches with it (``activetouch collect`` and the server's
collections write it).

:func:`read_training_csv` parses and checks a file; :class:`TrainingCsvWriter` appends rows as
touches arrive (a collection keeps what it recorded); :func:`write_training_csv` renders a whole
data set.
"""

from __future__ import annotations

import csv
import io
import math
import re
from collections.abc import Iterator
from typing import TextIO

import numpy as np
import numpy.typing as npt

from app.documents.errors import DocumentError
from core.errors import InvalidInputError
from core.types import TrainingData

_ACTION_COLUMN = re.compile(r"^x_(\d+)$")
_OBSERVATION_COLUMN = re.compile(r"^y_(\d+)$")

#: Longest object or dataset name, in characters (the API's limit too).
MAX_NAME_CHARACTERS = 200
#: How much of a cell an error message quotes.
_QUOTED_CHARACTERS = 40


def _quote(cell: str) -> str:
    """``repr`` of a cell for an error message, shortened when long."""
    if len(cell) <= _QUOTED_CHARACTERS:
        return repr(cell)
    return f"{cell[:_QUOTED_CHARACTERS]!r}… ({len(cell)} characters)"


def _oversized_field(text: str, line_number: int, columns: list[str]) -> DocumentError:
    """The error for a field over the ``csv`` module's size limit, naming its line and (when the
    line splits plainly on commas) its column."""
    limit = csv.field_size_limit()
    lines = io.StringIO(text, newline="").readlines()
    cells = lines[line_number - 1].split(",") if line_number <= len(lines) else []
    index = next((i for i, cell in enumerate(cells) if len(cell) > limit), None)
    column = columns[index] if index is not None and index < len(columns) else None
    where = f"CSV row {line_number}" + (f", column {column}" if column else "")
    return DocumentError(
        f"{where}: a field is longer than {limit} characters; a training CSV holds object "
        "names and numbers.",
        row=line_number,
        column=column,
    )


#: The optional column of placement numbers.
PLACEMENT_COLUMN = "placement"
#: The optional column of touch times (seconds since the collection's first touch).
TIME_COLUMN = "time_s"
#: The optional column of the touches' planned duration (seconds, one value for the file).
DURATION_COLUMN = "duration_s"
#: The optional columns, in the order they come after ``object``.
OPTIONAL_COLUMNS = (PLACEMENT_COLUMN, TIME_COLUMN, DURATION_COLUMN)


def _check_header(header: list[str]) -> tuple[int, int, frozenset[str]]:
    """Validate the CSV header; return (dx, dy, the optional columns it has)."""
    names = [h.strip() for h in header]
    if not names or names[0] != "object":
        raise DocumentError(
            f"CSV header: the first column must be 'object', found {names[:1] or 'nothing'}.",
            row=1,
            column=names[0] if names else None,
        )
    present = []
    for optional in OPTIONAL_COLUMNS:
        if len(names) > 1 and names[1] == optional:
            present.append(optional)
            names = [names[0], *names[2:]]
    for optional in OPTIONAL_COLUMNS:
        if optional in names[1:]:
            order = "".join(f"[,{c}]" for c in OPTIONAL_COLUMNS)
            raise DocumentError(
                f"CSV header: column {optional!r} must come right after 'object' (in the order "
                f"{', '.join(OPTIONAL_COLUMNS)}): expected object{order},x_1..x_dx,y_1..y_dy.",
                row=1,
                column=optional,
            )
    unknown = [
        n for n in names[1:] if not (_ACTION_COLUMN.match(n) or _OBSERVATION_COLUMN.match(n))
    ]
    if unknown:
        raise DocumentError(
            f"CSV header: unknown column(s) {unknown}; expected object,x_1..x_dx,y_1..y_dy.",
            row=1,
            column=unknown[0],
        )
    actions = [n for n in names[1:] if _ACTION_COLUMN.match(n)]
    observations = [n for n in names[1:] if _OBSERVATION_COLUMN.match(n)]
    expected = (
        ["object"]
        + [f"x_{i + 1}" for i in range(len(actions))]
        + [f"y_{i + 1}" for i in range(len(observations))]
    )
    if not actions or not observations or names != expected:
        wanted = (
            ",".join(expected)
            if actions and observations
            else "object,x_1..x_dx,y_1..y_dy with at least one x and one y"
        )
        raise DocumentError(f"CSV header: expected {wanted}, found {','.join(names)}.", row=1)
    return len(actions), len(observations), frozenset(present)


def read_training_csv(text: str) -> TrainingData:
    """Parse and validate a training CSV.

    Raises:
        DocumentError: Unknown or misordered columns, ragged rows, values that are not finite
            numbers, names over :data:`MAX_NAME_CHARACTERS`, fields over the ``csv`` module's
            size limit (the message names row and column), or too few objects / touches.
    """
    reader = csv.reader(io.StringIO(text, newline=""))
    columns: list[str] = []
    try:
        header = next(reader)
    except StopIteration:
        raise DocumentError("CSV: the file is empty; expected a header line.", row=1) from None
    except csv.Error:
        raise _oversized_field(text, reader.line_num, columns) from None
    dx, dy, optional = _check_header(header)
    columns = [h.strip() for h in header]
    try:
        return _read_rows(reader, columns, dx, dy, optional)
    except csv.Error:
        raise _oversized_field(text, reader.line_num, columns) from None


def _read_rows(
    rows: Iterator[list[str]], columns: list[str], dx: int, dy: int, optional: frozenset[str]
) -> TrainingData:
    """The data rows after the header (line 2 on), checked; ``optional``: the optional columns
    the header has (the time and duration columns are read with x and y: a finite number on
    every row)."""
    placed = PLACEMENT_COLUMN in optional
    timed = TIME_COLUMN in optional
    durated = DURATION_COLUMN in optional
    names: list[str] = []
    index: list[int] = []
    placements: list[int] = []
    values: list[list[float]] = []
    line_numbers: list[int] = []
    for line_number, row in enumerate(rows, start=2):
        if not row or all(not cell.strip() for cell in row):
            continue
        if len(row) != len(columns):
            raise DocumentError(
                f"CSV row {line_number}: has {len(row)} fields, the header has {len(columns)}.",
                row=line_number,
            )
        name = row[0].strip()
        if not name:
            raise DocumentError(
                f"CSV row {line_number}: the object name is empty.",
                row=line_number,
                column="object",
            )
        if len(name) > MAX_NAME_CHARACTERS:
            raise DocumentError(
                f"CSV row {line_number}, column object: the name {_quote(name)} is longer than "
                f"{MAX_NAME_CHARACTERS} characters.",
                row=line_number,
                column="object",
            )
        first = 1
        if placed:
            first = 2
            cell = row[1].strip()
            if not cell.isdigit():
                raise DocumentError(
                    f"CSV row {line_number}, column {PLACEMENT_COLUMN}: {cell!r} is not an "
                    "integer ≥ 0.",
                    row=line_number,
                    column=PLACEMENT_COLUMN,
                )
            placements.append(int(cell))
        numbers = []
        for column, cell in zip(columns[first:], row[first:], strict=True):
            try:
                number = float(cell)
            except ValueError:
                raise DocumentError(
                    f"CSV row {line_number}, column {column}: {_quote(cell)} is not a number.",
                    row=line_number,
                    column=column,
                ) from None
            if not math.isfinite(number):
                raise DocumentError(
                    f"CSV row {line_number}, column {column}: {_quote(cell)} is not finite.",
                    row=line_number,
                    column=column,
                )
            numbers.append(number)
        if name not in names:
            names.append(name)
        index.append(names.index(name))
        values.append(numbers)
        line_numbers.append(line_number)
    if not values:
        raise DocumentError("CSV: no data rows after the header.", row=2)
    array = np.asarray(values, dtype=np.float64)
    first = int(timed) + int(durated)
    duration_s = _duration(array[:, first - 1], line_numbers) if durated else None
    try:
        return TrainingData(
            object_names=tuple(names),
            object_index=np.asarray(index, dtype=np.int64),
            actions=array[:, first : first + dx],
            observations=array[:, first + dx : first + dx + dy],
            placement_index=np.asarray(placements, dtype=np.int64) if placed else None,
            touch_times_s=array[:, 0] if timed else None,
            touch_duration_s=duration_s,
        )
    except DocumentError:
        raise
    except InvalidInputError as exc:
        raise DocumentError(f"CSV: {exc}") from exc


def _duration(durations_s: npt.NDArray[np.float64], line_numbers: list[int]) -> float:
    """The file's touch duration from its ``duration_s`` column (rows in file order, on lines
    ``line_numbers``): one value > 0, the same on every row (an action means another touch at
    another duration)."""
    first = float(durations_s[0])
    if not first > 0:
        raise DocumentError(
            f"CSV row {line_numbers[0]}, column {DURATION_COLUMN}: {first!r} is not a "
            "duration > 0 seconds.",
            row=line_numbers[0],
            column=DURATION_COLUMN,
        )
    differs = np.flatnonzero(durations_s != first)
    if differs.size:
        line = line_numbers[int(differs[0])]
        raise DocumentError(
            f"CSV row {line}, column {DURATION_COLUMN}: {float(durations_s[differs[0]])!r} "
            f"differs from row {line_numbers[0]}'s {first!r}; every touch of a training set "
            "must last the same (an action means a trajectory of that duration).",
            row=line,
            column=DURATION_COLUMN,
        )
    return first


def training_csv_header(
    action_dim: int,
    observation_dim: int,
    placements: bool = False,
    times: bool = False,
    durations: bool = False,
) -> list[str]:
    """The CSV header ``object,x_1..x_dx,y_1..y_dy`` (``object,placement,…`` with placements,
    ``object[,placement],time_s,…`` with times, ``…[,time_s],duration_s,…`` with the touch
    duration)."""
    return (
        ["object"]
        + ([PLACEMENT_COLUMN] if placements else [])
        + ([TIME_COLUMN] if times else [])
        + ([DURATION_COLUMN] if durations else [])
        + [f"x_{i + 1}" for i in range(action_dim)]
        + [f"y_{i + 1}" for i in range(observation_dim)]
    )


class TrainingCsvWriter:
    """Write a training CSV touch by touch: the header at once, then one row per :meth:`write`.

    Floats are written with ``repr``, so they round-trip exactly. Rows are not validated as a
    whole (a partial collection may have an object with one touch); :func:`read_training_csv`
    checks the file when it is used.

    Args:
        stream: Text stream to write to (opened with ``newline=""`` for a file).
        action_dim: dx.
        observation_dim: dy.
        placements: Write the ``placement`` column (every :meth:`write` then gives one).
        times: Write the ``time_s`` column (every :meth:`write` then gives one).
        duration_s: The touches' planned duration: written in the ``duration_s`` column of
            every row (``None``: no such column).
    """

    def __init__(
        self,
        stream: TextIO,
        action_dim: int,
        observation_dim: int,
        placements: bool = False,
        times: bool = False,
        duration_s: float | None = None,
    ) -> None:
        if action_dim < 1 or observation_dim < 1:
            raise DocumentError(
                f"CSV: needs dx ≥ 1 and dy ≥ 1, received dx={action_dim}, dy={observation_dim}."
            )
        if duration_s is not None and not (math.isfinite(duration_s) and duration_s > 0):
            raise DocumentError(
                f"CSV: {DURATION_COLUMN} must be a finite number > 0, received {duration_s!r}.",
                column=DURATION_COLUMN,
            )
        self.duration_s = None if duration_s is None else float(duration_s)
        self.action_dim = int(action_dim)
        self.observation_dim = int(observation_dim)
        self.placements = bool(placements)
        self.times = bool(times)
        self.rows = 0
        self._writer = csv.writer(stream, lineterminator="\n")
        self._writer.writerow(
            training_csv_header(
                self.action_dim,
                self.observation_dim,
                self.placements,
                self.times,
                self.duration_s is not None,
            )
        )

    def write(
        self,
        name: str,
        action: npt.ArrayLike,
        observation: npt.ArrayLike,
        placement: int | None = None,
        time_s: float | None = None,
    ) -> None:
        """Append one touch: object ``name``, action (dx,), observation (dy,), its placement
        and when it was made (seconds).

        Raises:
            DocumentError: An empty name, wrong lengths, values that are not finite, or a
                placement or time missing (or given) against the header.
        """
        if self.placements != (placement is not None) or (placement is not None and placement < 0):
            raise DocumentError(
                f"CSV: placement of {name!r}: "
                + ("an integer ≥ 0 is needed" if self.placements else "this file has no column")
                + f", received {placement!r}.",
                column=PLACEMENT_COLUMN,
            )
        if self.times != (time_s is not None) or (time_s is not None and not math.isfinite(time_s)):
            raise DocumentError(
                f"CSV: {TIME_COLUMN} of {name!r}: "
                + ("a finite number is needed" if self.times else "this file has no column")
                + f", received {time_s!r}.",
                column=TIME_COLUMN,
            )
        x = np.asarray(action, dtype=np.float64).reshape(-1)
        y = np.asarray(observation, dtype=np.float64).reshape(-1)
        if not name.strip():
            raise DocumentError("CSV: the object name is empty.", column="object")
        for what, values, expected in (
            ("action", x, self.action_dim),
            ("observation", y, self.observation_dim),
        ):
            if values.shape[0] != expected:
                raise DocumentError(
                    f"CSV: {what} of {name!r} has {values.shape[0]} values, expected {expected}."
                )
            if not np.all(np.isfinite(values)):
                raise DocumentError(f"CSV: {what} of {name!r} is not finite: {values.tolist()}.")
        lead = [name] if placement is None else [name, str(int(placement))]
        if time_s is not None:
            lead.append(repr(float(time_s)))
        if self.duration_s is not None:
            lead.append(repr(self.duration_s))
        self._writer.writerow([*lead, *map(repr, map(float, x)), *map(repr, map(float, y))])
        self.rows += 1


def write_training_csv(data: TrainingData) -> str:
    """Render training data as CSV text (floats written with ``repr``, so they round-trip), with
    the ``placement``, ``time_s`` and ``duration_s`` columns when the data records them."""
    out = io.StringIO()
    placed = data.placement_index is not None
    timed = data.touch_times_s is not None
    writer = TrainingCsvWriter(
        out, data.action_dim, data.observation_dim, placed, timed, data.touch_duration_s
    )
    placements: list[int | None] = (
        data.placement_index.tolist()
        if data.placement_index is not None
        else [None] * data.n_touches
    )
    times_s: list[float | None] = (
        data.touch_times_s.tolist() if data.touch_times_s is not None else [None] * data.n_touches
    )
    for obj, x, y, p, t in zip(
        data.object_index, data.actions, data.observations, placements, times_s, strict=True
    ):
        writer.write(data.object_names[obj], x, y, p, t)
    return out.getvalue()
