"""Raw-touch files: reading, refusing bad input by line and channel, and the model's pipeline."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from app.documents.errors import DocumentError
from app.documents.model import model_from_document, model_to_document
from app.documents.raw_touches import (
    featurise,
    line_refusal,
    raw_channel_names,
    raw_touch_from_record,
    raw_touch_line,
    read_raw_touches,
)
from app.errors import BadInputError
from app.evaluation.spec import EvaluationSpec
from app.evaluation.worlds import table_objects
from core.errors import InvalidInputError
from core.features.pipeline import fit_features, means_pipeline
from core.features.raw import RawTouch, raw_touch
from core.gp.manifold import FitOptions, fit_manifold
from core.types import ManifoldModel, TrainingData
from hardware.records import TouchRecord
from hardware.sim.rig import table_channel_names

PATTERNS = {"fine": [1.0, 2.0, 3.0], "coarse": [3.0, 2.0, 1.0], "medium": [2.0, 2.0, 2.0]}


def touch_line(rng: np.random.Generator, name: str, frequency_hz: float, n_fast: int = 600) -> str:
    """One touch: 40 Hz pressure, 3 electrodes (pattern by object), a 1 kHz vibration."""
    x = rng.normal(size=2)
    t = np.arange(n_fast) / 1000.0
    touch = raw_touch(
        {
            "pressure_kpa": (40.0, 2.0 + 0.3 * x[0] + 0.05 * rng.normal(size=20)),
            "electrode": (40.0, PATTERNS[name] + 0.05 * rng.normal(size=(20, 3))),
            "vibration": (
                1000.0,
                np.sin(2 * np.pi * frequency_hz * (1 + 0.1 * x[1]) * t)
                + 0.1 * rng.normal(size=n_fast),
            ),
        }
    )
    return json.dumps(raw_touch_line(name, x, touch, note="ignored"))


def raw_file(touches_per_object: int = 10) -> str:
    rng = np.random.default_rng(3)
    lines = [
        touch_line(rng, name, frequency)
        for _ in range(touches_per_object)
        for name, frequency in (("fine", 200.0), ("coarse", 50.0), ("medium", 100.0))
    ]
    return "\n".join(lines) + "\n"


def test_a_raw_file_reads_into_touches_with_their_layout() -> None:
    touches = read_raw_touches(raw_file(4))
    assert touches.object_names == ("fine", "coarse", "medium")
    assert touches.actions.shape == (12, 2)
    assert touches.channel_names == ("pressure_kpa", "electrode", "vibration")
    assert touches.touches[0].channel("electrode").width == 3
    assert touches.lines == tuple(range(1, 13))


def _edit(text: str, line: int, change: object) -> str:
    rows = text.splitlines()
    item = json.loads(rows[line - 1])
    change(item)  # type: ignore[operator]
    rows[line - 1] = json.dumps(item)
    return "\n".join(rows)


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda i: i["channels"].pop("electrode"), r"line 5: .*missing \['electrode'\]"),
        (lambda i: i["channels"]["vibration"].pop("rate_hz"), "line 5: channel 'vibration'.*rate"),
        (
            lambda i: i["channels"]["pressure_kpa"]["samples"].__setitem__(3, float("nan")),
            r"line 5: channel 'pressure_kpa': a NaN or inf sample at index \[3\]",
        ),
        (
            lambda i: i["channels"]["electrode"]["samples"][2].pop(),
            "line 5: channel 'electrode': ragged",
        ),
        (lambda i: i["action"].append(1.0), "line 5: 'action' has 3 components"),
    ],
)
def test_bad_touches_are_refused_naming_the_line_and_the_channel(
    change: object, message: str
) -> None:
    with pytest.raises(DocumentError, match=message):
        read_raw_touches(_edit(raw_file(2), 5, change))


def test_a_series_shorter_than_the_window_is_refused_by_line_and_channel() -> None:
    rng = np.random.default_rng(0)
    text = raw_file(3) + touch_line(rng, "fine", 200.0, n_fast=100) + "\n"
    touches = read_raw_touches(text)
    with pytest.raises(InvalidInputError) as caught:
        fit_features(touches.touches, touches.object_index, "whole")
    error = line_refusal(touches, caught.value)
    assert "line 10" in str(error)
    assert "'vibration': 100 samples, shorter than the pipeline's window of 256" in str(error)
    pipeline = fit_features(touches.touches[:9], touches.object_index[:9], "whole", feature_dim=2)
    with pytest.raises(DocumentError, match="line 10: channel 'vibration'"):
        featurise(touches, pipeline)


def test_the_pipeline_travels_in_the_model_document_and_gives_identical_features() -> None:
    touches = read_raw_touches(raw_file(8))
    pipeline = fit_features(touches.touches, touches.object_index, "whole")
    data = featurise(touches, pipeline)
    model = fit_manifold(data, 2, np.random.default_rng(0), FitOptions(restarts=0))
    model = dataclasses.replace(model, features=pipeline)
    document = json.loads(json.dumps(model_to_document(model)))
    assert document["features"]["kind"] == "whole"
    assert document["features"]["selection"]["chosen"] == pipeline.output_dim
    loaded = model_from_document(document)
    assert loaded.features is not None
    again = np.stack([loaded.features.transform(t) for t in touches.touches])
    np.testing.assert_array_equal(again, data.observations)
    # A document without the field means channel means, as before.
    del document["features"]
    assert model_from_document(document).features is None


def test_a_rig_record_becomes_a_raw_touch_by_its_channel_names() -> None:
    n = 50
    frames = np.arange(n * 5, dtype=np.float64).reshape(n, 5)
    record = TouchRecord(
        slot=0,
        channel_names=("pressure_kpa", "electrode[0]", "electrode[1]", "vib@0", "vib@1"),
        joint_names=("j",),
        dt_s=0.01,
        commanded_deg=np.zeros((3, 1)),
        tactile_times_s=np.arange(n) / 100.0,
        tactile=frames,
        tactile_sequence=np.arange(n),
        joint_times_s=np.zeros(0),
        joint_positions_deg=np.zeros((0, 1)),
        joint_currents_ma=np.zeros((0, 1)),
    )
    touch = raw_touch_from_record(record)
    assert touch.names == ("pressure_kpa", "electrode", "vib")
    assert touch.channel("pressure_kpa").rate_hz == pytest.approx(100.0)
    np.testing.assert_array_equal(touch.channel("electrode").samples, frames[:, 1:3])
    vib = touch.channel("vib")
    assert vib.rate_hz == pytest.approx(200.0)
    np.testing.assert_array_equal(vib.samples, frames[:, 3:5].reshape(-1))


def test_a_line_of_the_older_collect_format_is_read_from_its_frames() -> None:
    n = 40
    frames = np.column_stack([np.linspace(1.0, 2.0, n), np.full(n, 3.0), np.full(n, 4.0)])
    old = {
        "object": "mug",
        "action": [0.5],
        "channel_names": ["pressure_kpa", "electrode[0]", "electrode[1]"],
        "tactile_times_s": (np.arange(n) / 50.0).tolist(),
        "tactile": frames.tolist(),
    }
    touches = read_raw_touches(json.dumps(old) + "\n")
    touch = touches.touches[0]
    assert touch.names == ("pressure_kpa", "electrode")
    assert touch.channel("pressure_kpa").rate_hz == pytest.approx(50.0)
    np.testing.assert_array_equal(touch.channel("electrode").samples, frames[:, 1:])
    # A new line with 'channels' and an old one with frames read alike, in one file.
    new = json.dumps(raw_touch_line("cup", [0.1], touch))
    both = read_raw_touches(json.dumps(old) + "\n" + new + "\n")
    assert both.object_names == ("mug", "cup")
    broken = {**old, "tactile": frames[:, :2].tolist()}
    with pytest.raises(DocumentError, match=r"line 2: frames: expected shape \(40, 3\)"):
        read_raw_touches(new + "\n" + json.dumps(broken) + "\n")


def twins_channel_model() -> ManifoldModel:
    """A small model (dx = 6) whose channel-means pipeline reads the twins table's channels."""
    rng = np.random.default_rng(0)

    def touch(level: float) -> RawTouch:
        slow = {n: (100.0, level + rng.normal(size=20)) for n in ("vibration_1", "vibration_2")}
        slow |= {n: (100.0, level + rng.normal(size=20)) for n in ("pressure_kpa", "heat_flux_mw")}
        return raw_touch(
            {
                **slow,
                "temperature_c": (100.0, 30 + rng.normal(size=20)),
                "electrode": (100.0, level + rng.normal(size=(20, 8))),
                "vibration": (1600.0, rng.normal(size=320)),
            }
        )

    index = np.repeat(np.arange(4), 5)
    touches = [touch(float(k)) for k in index]
    pipeline = fit_features(touches, index, "means")
    names = table_objects("twins")
    data = TrainingData(names, index, rng.normal(size=(20, 6)), pipeline.transform_many(touches))
    model = fit_manifold(data, 1, np.random.default_rng(0), FitOptions(restarts=0))
    return dataclasses.replace(model, features=pipeline)


def test_rig_trials_accept_a_model_whose_pipeline_reads_the_tables_channels() -> None:
    assert raw_channel_names(table_channel_names(table_objects("twins"))) == (
        "vibration_1", "vibration_2", "pressure_kpa", "heat_flux_mw", "temperature_c",
        "electrode", "vibration",
    )  # fmt: skip
    model = twins_channel_model()
    spec = EvaluationSpec("rig", 1, 1, ("passive",), table="twins")
    spec.check(model)  # 14 channel means of 7 channels
    with pytest.raises(BadInputError, match="the simulated rig has dx=6, dy=29"):
        spec.check(dataclasses.replace(model, features=None))  # y: the 29 frame channels
    other = read_raw_touches(raw_file(4))
    fitted = fit_features(other.touches, other.object_index, "means")
    with pytest.raises(BadInputError, match=r"the model's features read \['pressure_kpa'"):
        spec.check(dataclasses.replace(model, features=fitted))


def test_a_raw_files_placements_reach_the_training_data() -> None:
    lines = raw_file(4).splitlines()
    placed = [json.dumps({**json.loads(line), "placement": k % 2}) for k, line in enumerate(lines)]
    touches = read_raw_touches("\n".join(placed))
    assert touches.placement_index is not None
    assert touches.placement_index.tolist() == [k % 2 for k in range(12)]
    data = featurise(touches, means_pipeline(touches.touches[0]))
    np.testing.assert_array_equal(data.placement_index, touches.placement_index)
    # Without the key (or null on every line) there are none.
    assert read_raw_touches("\n".join(lines)).placement_index is None
    nulls = [json.dumps({**json.loads(line), "placement": None}) for line in lines]
    assert read_raw_touches("\n".join(nulls)).placement_index is None
    for bad in (True, 1.5, -1):
        edited = [*placed[:3], json.dumps({**json.loads(lines[3]), "placement": bad})]
        with pytest.raises(DocumentError, match="line 4: 'placement' must be an integer"):
            read_raw_touches("\n".join(edited))
    with pytest.raises(DocumentError, match="line 2: 'placement' is given here but not on line 1"):
        read_raw_touches("\n".join([lines[0], placed[1]]))
