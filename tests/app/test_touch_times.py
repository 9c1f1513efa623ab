"""Touch times (``time_s``, seconds since the collection's first touch) in the training CSV, the
raw-touch file and the collections that write them; the fit estimates the drift shared by
touches made close together from them (:mod:`core.gp.drift_effect`)."""

from __future__ import annotations

import dataclasses
import io
import json
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

from app.cli.main import app
from app.documents.errors import DocumentError
from app.documents.raw_touches import featurise, read_raw_touches
from app.documents.training_csv import (
    TIME_COLUMN,
    TrainingCsvWriter,
    read_training_csv,
    write_training_csv,
)
from app.rig.collection import CollectedTouch, since_first_touch
from core.evaluation.worlds import sample_experiment1
from core.features.pipeline import means_pipeline
from core.types import TrainingData
from hardware.errors import HardwareError
from hardware.records import TouchRecord
from tests.app.test_raw_touches import raw_file
from tests.conftest import SETTLE_S


def experiment1(touches_per_object: int = 3) -> TrainingData:
    return sample_experiment1(np.random.default_rng(5), touches_per_object=touches_per_object)


def timed(data: TrainingData, placements: bool = False) -> TrainingData:
    """``data`` with a touch every 24.1 s (and placements in pairs)."""
    return dataclasses.replace(
        data,
        touch_times_s=24.1 * np.arange(data.n_touches),
        placement_index=np.arange(data.n_touches) // 2 if placements else None,
    )


@pytest.mark.parametrize(
    ("placements", "lead"), [(False, "object,time_s,x_1"), (True, "object,placement,time_s,x_1")]
)
def test_csv_time_column_round_trips(placements: bool, lead: str) -> None:
    data = timed(experiment1(), placements)
    text = write_training_csv(data)
    assert text.splitlines()[0].startswith(lead)
    back = read_training_csv(text)
    assert back.touch_times_s is not None
    assert data.touch_times_s is not None
    np.testing.assert_array_equal(back.touch_times_s, data.touch_times_s)
    np.testing.assert_array_equal(back.actions, data.actions)
    np.testing.assert_array_equal(back.observations, data.observations)
    if placements:
        np.testing.assert_array_equal(back.placement_index, data.placement_index)
    else:
        assert back.placement_index is None


@settings(max_examples=40, deadline=None)
@given(
    st.lists(st.floats(allow_nan=False, allow_infinity=False, width=64), min_size=12, max_size=12)
)
def test_any_finite_times_round_trip_exactly(times_s: list[float]) -> None:
    data = dataclasses.replace(experiment1(), touch_times_s=np.asarray(times_s))
    back = read_training_csv(write_training_csv(data))
    assert back.touch_times_s is not None
    assert back.touch_times_s.tolist() == times_s


def test_a_csv_without_the_column_reads_as_before() -> None:
    data = experiment1()
    text = write_training_csv(data)
    assert TIME_COLUMN not in text
    back = read_training_csv(text)
    assert back.touch_times_s is None
    assert back.placement_index is None
    assert back.object_names == data.object_names
    np.testing.assert_array_equal(back.object_index, data.object_index)
    np.testing.assert_array_equal(back.actions, data.actions)
    np.testing.assert_array_equal(back.observations, data.observations)
    assert write_training_csv(back) == text


GOOD = "object,time_s,x_1,y_1\na,0.0,1,2\na,24.5,1,3\nb,49.0,2,2\n"


@pytest.mark.parametrize(
    ("text", "fragment", "row"),
    [
        (GOOD + "b,,2,3\n", "row 5, column time_s: '' is not a number", 5),
        (GOOD + "b,soon,2,3\n", "row 5, column time_s: 'soon' is not a number", 5),
        (GOOD.replace("24.5", "nan"), "row 3, column time_s: 'nan' is not finite", 3),
        (GOOD.replace("49.0", "-inf"), "row 4, column time_s: '-inf' is not finite", 4),
        ("object,x_1,time_s,y_1\na,1,0,2\n", "'time_s' must come right after 'object'", 1),
        ("object,time_s,placement,x_1,y_1\na,0,0,1,2\n", "'placement' must come right", 1),
    ],
)
def test_csv_time_errors_name_row_and_column(text: str, fragment: str, row: int) -> None:
    with pytest.raises(DocumentError, match=fragment) as info:
        read_training_csv(text)
    assert info.value.row == row
    assert info.value.column in (TIME_COLUMN, "placement")


def test_the_writer_needs_a_time_exactly_when_the_file_has_the_column() -> None:
    timed_writer = TrainingCsvWriter(io.StringIO(), 1, 1, times=True)
    for missing in (None, float("nan"), float("inf")):
        with pytest.raises(DocumentError, match="time_s of 'a': a finite number") as info:
            timed_writer.write("a", [1.0], [2.0], time_s=missing)
        assert info.value.column == TIME_COLUMN
    plain = TrainingCsvWriter(io.StringIO(), 1, 1)
    with pytest.raises(DocumentError, match="this file has no column"):
        plain.write("a", [1.0], [2.0], time_s=3.0)
    assert timed_writer.rows == plain.rows == 0


def record(started_s: float | None) -> TouchRecord:
    """A two-frame touch that started at ``started_s`` on the rig's clock."""
    return TouchRecord(
        slot=0,
        channel_names=("pressure_kpa",),
        joint_names=("j",),
        dt_s=0.01,
        commanded_deg=np.zeros((2, 1)),
        tactile_times_s=np.array([0.0, 0.01]),
        tactile=np.ones((2, 1)),
        tactile_sequence=np.arange(2),
        joint_times_s=np.zeros(0),
        joint_positions_deg=np.zeros((0, 1)),
        joint_currents_ma=np.zeros((0, 1)),
        started_s=started_s,
    )


def touches(*started_s: float | None) -> list[CollectedTouch]:
    return [
        CollectedTouch(k, len(started_s), "cup", 0, np.zeros(1), record(s))
        for k, s in enumerate(started_s)
    ]


def test_a_collection_dates_its_touches_from_its_first() -> None:
    dated = list(since_first_touch(touches(1000.25, 1024.5, 1049.0)))
    assert [t.time_s for t in dated] == [0.0, 24.25, 48.75]
    assert [t.index for t in dated] == [0, 1, 2]
    # Dating again (a stage inside a collection) counts from the new first touch.
    assert [t.time_s for t in since_first_touch(dated[1:])] == [0.0, 24.5]
    # A record without its start has no time; without the first's, none has.
    assert [t.time_s for t in since_first_touch(touches(5.0, None, 9.0))] == [0.0, None, 4.0]
    assert [t.time_s for t in since_first_touch(touches(None, 5.0))] == [None, None]
    with pytest.raises(HardwareError, match="started_s: must be finite"):
        record(float("nan"))


runner = CliRunner()


@pytest.mark.usefixtures("cli_rig_rest")  # 5 s before each touch, not 20 s
def test_collect_writes_each_touch_time_since_the_first(tmp_path: Path) -> None:
    out, raw = tmp_path / "timed.csv", tmp_path / "timed.jsonl"
    result = runner.invoke(
        app,
        ["collect", "--sim", "--duration", "5", "--object", "paper_cup", "--object",
         "stainless_cup", "--touches", "3", "--seed", "2",
         "--out", str(out), "--raw", str(raw)],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    assert out.read_text().splitlines()[0].startswith("object,placement,time_s,duration_s,x_1")
    data = read_training_csv(out.read_text())
    assert data.touch_duration_s == 5.0
    assert data.touch_times_s is not None
    times_s = data.touch_times_s
    assert times_s[0] == 0.0
    # Every touch rests SETTLE_S, then moves and touches for 5 s, on the simulated clock; the
    # adaptive design's round is dated from the collection's first touch, not its own.
    assert len(times_s) == 6
    assert np.all(np.diff(times_s) >= SETTLE_S + 5.0)
    lines = [json.loads(line) for line in raw.read_text().splitlines()]
    assert [line["time_s"] for line in lines] == times_s.tolist()
    assert {line["duration_s"] for line in lines} == {5.0}


def test_raw_touch_times_are_read_on_every_line_or_none() -> None:
    lines = raw_file(2).splitlines()
    timed_lines = [
        json.dumps({**json.loads(line), "time_s": 30.5 * k}) for k, line in enumerate(lines)
    ]
    touches_set = read_raw_touches("\n".join(timed_lines))
    assert touches_set.touch_times_s is not None
    assert touches_set.touch_times_s.tolist() == [30.5 * k for k in range(len(lines))]
    data = featurise(touches_set, means_pipeline(touches_set.touches[0]))
    assert data.touch_times_s is not None
    np.testing.assert_array_equal(data.touch_times_s, touches_set.touch_times_s)
    plain = read_raw_touches("\n".join(lines))
    assert plain.touch_times_s is None
    assert featurise(plain, means_pipeline(plain.touches[0])).touch_times_s is None
    for bad, needle in (
        ([*timed_lines[:2], lines[2], *timed_lines[3:]], "line 3: 'time_s' is missing"),
        ([lines[0], *timed_lines[1:]], "line 2: 'time_s' is given here but not on line 1"),
        ([*timed_lines[:1], lines[1].replace("{", '{"time_s": "soon", ', 1)], "line 2"),
        ([*timed_lines[:1], lines[1].replace("{", '{"time_s": NaN, ', 1)], "line 2"),
        ([*timed_lines[:1], lines[1].replace("{", '{"time_s": true, ', 1)], "line 2"),
        ([*timed_lines[:1], lines[1].replace("{", '{"time_s": 1e999, ', 1)], "line 2"),
    ):
        with pytest.raises(DocumentError, match=needle) as info:
            read_raw_touches("\n".join(bad))
        assert info.value.column == "time_s"
