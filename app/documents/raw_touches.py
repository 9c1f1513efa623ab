"""Raw touches as data (JSON lines, ``docs/raw-touches.md``): one touch per line.

Each line is a JSON object::

    {"object": "mug", "action": [0.1, -0.3],
     "channels": {"pressure_kpa": {"rate_hz": 100, "samples": [1.2, 1.3, ...]},
                  "electrode":    {"rate_hz": 100, "samples": [[0.1, 0.4, ...], ...]},
                  "vibration":    {"rate_hz": 1600, "samples": [0.01, -0.02, ...]}}}

A channel is a series of n samples, each a number or a vector of one common width (an
electrode array), with its sample rate in Hz. An optional ``placement`` (an integer ≥ 0, on
every line or on none) says which placement of its object the touch met, as the training CSV's
``placement`` column does; the fit estimates the placement effect from it. An optional ``time_s``
(a finite number, on every line or on none) says when the touch was made, in seconds since the
collection's first touch, as the training CSV's ``time_s`` column does; the fit estimates the
drift shared by touches made close together from it (:mod:`core.gp.drift_effect`). An optional
``duration_s`` (seconds > 0, the same on every line, or on none) says how long each touch lasted
as planned, as the training CSV's ``duration_s`` column does. Other keys
(``collect --raw`` adds the frame times, joint series and the channel means) are kept by nobody
and ignored here.

:func:`read_raw_touches` parses a whole file and refuses it, naming the line and the channel,
when touches have different channel sets, a sample rate is missing, a series holds NaN/inf or
ragged vectors; :func:`featurise` applies a feature pipeline and refuses a series shorter than
its window likewise. Nothing is half-read: either every touch is good or an error is raised.
"""

from __future__ import annotations

import json
import math
import re
import reprlib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from app.documents.errors import DocumentError
from core.errors import InvalidInputError
from core.features.pipeline import FeaturePipeline
from core.features.raw import RawChannel, RawTouch, check_same_layout, raw_channel
from core.types import TrainingData
from core.validation import FloatArray, IntArray
from hardware.records import TouchRecord

#: A frame channel ``NAME[i]`` is element i of the vector channel NAME (an electrode array).
_ELEMENT = re.compile(r"^(?P<name>.+)\[(?P<index>\d+)\]$")
#: A frame channel ``NAME@k`` is the k-th of K samples of NAME taken within one frame period.
_SUBSAMPLE = re.compile(r"^(?P<name>.+)@(?P<index>\d+)$")


@dataclass(frozen=True)
class RawTouchSet:
    """Raw touches read from a file.

    Attributes:
        object_names: Distinct object names, in order of first appearance. Length L.
        object_index: Object of each touch. Shape (N,).
        actions: Action x of each touch. Shape (N, dx).
        touches: The touches, one channel layout. Length N.
        lines: Line of the file each touch came from. Length N.
        placement_index: Placement of its object each touch met, when every line gave one.
            Shape (N,).
        touch_times_s: When each touch was made (seconds, one clock), when every line gave it.
            Shape (N,).
        touch_duration_s: How long every touch lasted as planned (seconds), when every line
            gave it.
    """

    object_names: tuple[str, ...]
    object_index: IntArray
    actions: FloatArray
    touches: tuple[RawTouch, ...]
    lines: tuple[int, ...]
    placement_index: IntArray | None = None
    touch_times_s: FloatArray | None = None
    touch_duration_s: float | None = None

    @property
    def channel_names(self) -> tuple[str, ...]:
        """The channels every touch has."""
        return self.touches[0].names


def _line_error(line: int, message: str, column: str | None = None) -> DocumentError:
    return DocumentError(f"raw touches, line {line}: {message}", row=line, column=column)


def _check_all_or_none(
    key: str, what: str, value: object, earlier: list[Any], line: int, lines: list[int]
) -> None:
    """An optional ``key`` (``placement``, ``time_s``) is given on every line or on none: refuse
    ``value`` of ``line`` if it differs in that from the first line's (``earlier[0]``)."""
    if earlier and (value is None) != (earlier[0] is None):
        raise _line_error(
            line,
            f"'{key}' is {'missing' if value is None else 'given'} here but "
            f"{'not ' if earlier[0] is None else ''}on line {lines[0]}; give every "
            f"touch {what} or none.",
            key,
        )


def _read_channels(value: Any, line: int) -> RawTouch:
    if not isinstance(value, Mapping) or not value:
        raise _line_error(
            line, "'channels' must be a non-empty object of name → series.", "channels"
        )
    channels = []
    for name, spec in value.items():
        if not isinstance(spec, Mapping):
            raise _line_error(
                line, f"channel {name!r}: expected {{'rate_hz': ..., 'samples': [...]}}.", name
            )
        if "samples" not in spec:
            raise _line_error(line, f"channel {name!r}: the series ('samples') is missing.", name)
        try:
            channels.append(raw_channel(str(name), spec.get("rate_hz"), spec["samples"]))
        except InvalidInputError as exc:
            raise _line_error(line, str(exc), name) from None
    return RawTouch(tuple(channels))


#: The keys of a line written by ``collect --raw`` before it wrote ``channels``: the frames.
_FRAME_KEYS = ("channel_names", "tactile_times_s", "tactile")


def frames_touch(item: Mapping[str, Any]) -> RawTouch:
    """A touch from its frames: ``channel_names``, ``tactile_times_s`` and ``tactile`` (a rig
    collection's stored sample, or a line ``collect --raw`` wrote before it wrote ``channels``).

    Raises:
        InvalidInputError: A frame key missing, frames that are not numbers or not (n, C), or
            channel names :func:`raw_touch_from_frames` cannot group.
    """
    missing = [key for key in _FRAME_KEYS if key not in item]
    if missing:
        raise InvalidInputError(f"the frames: {missing} missing.")
    names = item["channel_names"]
    if not isinstance(names, list) or not all(isinstance(n, str) for n in names):
        raise InvalidInputError("'channel_names' must be a list of names.")
    try:
        times_s = np.asarray(item["tactile_times_s"], dtype=np.float64)
        frames = np.asarray(item["tactile"], dtype=np.float64)
    except (TypeError, ValueError):
        raise InvalidInputError(
            "the frames ('tactile', 'tactile_times_s') are not numbers."
        ) from None
    if times_s.ndim != 1 or frames.ndim != 2:
        raise InvalidInputError(
            "'tactile_times_s' must be a list of times and 'tactile' a list of frames."
        )
    return raw_touch_from_frames(names, times_s, frames)


def stored_touch(raw: Mapping[str, Any]) -> RawTouch:
    """A stored sample's raw touch: its ``channels`` (an upload of raw touches), else its frames
    (a rig collection, :func:`frames_touch`).

    Raises:
        InvalidInputError: Neither is there, or they are malformed (the channel named).
    """
    if "channels" in raw:
        channels = raw["channels"]
        if not isinstance(channels, Mapping) or not all(
            isinstance(spec, Mapping) and "samples" in spec for spec in channels.values()
        ):
            raise InvalidInputError("'channels' must map names to {rate_hz, samples}.")
        return RawTouch(
            tuple(
                raw_channel(str(name), spec.get("rate_hz"), spec["samples"])
                for name, spec in channels.items()
            )
        )
    return frames_touch(raw)


def read_raw_touches(text: str) -> RawTouchSet:
    """Parse and check a raw-touch file (JSON lines).

    A line without ``channels`` but with the frames ``channel_names``, ``tactile_times_s`` and
    ``tactile`` (what ``collect --raw`` wrote before) is read from its frames
    (:func:`frames_touch`).

    Raises:
        DocumentError: A line that is not a JSON object, a missing or empty object name, an
            action of another length than the first line's or not finite, a channel set or
            width different from the first touch's, a missing sample rate, NaN/inf or ragged
            series, a ``placement`` that is not an integer ≥ 0, a ``time_s`` that is not a
            finite number or a ``duration_s`` that is not one > 0, any of them given on some
            lines but not on others, or durations that differ. The message names the line and
            the channel (or key).
    """
    names: list[str] = []
    index: list[int] = []
    actions: list[list[float]] = []
    touches: list[RawTouch] = []
    lines: list[int] = []
    placements: list[int | None] = []
    times_s: list[float | None] = []
    durations_s: list[float | None] = []
    for line, content in enumerate(text.splitlines(), start=1):
        if not content.strip():
            continue
        try:
            item = json.loads(content)
        except json.JSONDecodeError as exc:
            raise _line_error(line, f"not JSON ({exc.msg}).") from None
        if not isinstance(item, Mapping):
            raise _line_error(line, "expected a JSON object.")
        name = item.get("object")
        if not isinstance(name, str) or not name.strip():
            raise _line_error(line, "'object' must be a non-empty name.", "object")
        action = item.get("action")
        if not isinstance(action, list) or not action:
            raise _line_error(line, "'action' must be a non-empty list of numbers.", "action")
        try:
            x = np.asarray(action, dtype=np.float64)
        except (TypeError, ValueError):
            raise _line_error(line, "'action' must be a list of numbers.", "action") from None
        if x.ndim != 1 or not np.all(np.isfinite(x)):
            raise _line_error(line, "'action' must be a list of finite numbers.", "action")
        if actions and len(x) != len(actions[0]):
            raise _line_error(
                line,
                f"'action' has {len(x)} components, the first touch's has {len(actions[0])}.",
                "action",
            )
        if "channels" in item:
            touch = _read_channels(item["channels"], line)
        elif all(key in item for key in _FRAME_KEYS):
            try:
                touch = frames_touch(item)
            except InvalidInputError as exc:
                raise _line_error(line, str(exc), "tactile") from None
        else:
            raise _line_error(line, "'channels' is missing.", "channels")
        if touches:
            try:
                check_same_layout(touches[0], touch)
            except InvalidInputError as exc:
                raise _line_error(line, str(exc), "channels") from None
        placement = _placement(item.get("placement"), line)
        _check_all_or_none("placement", "a placement", placement, placements, line, lines)
        time_s = _time_s(item.get("time_s"), line)
        _check_all_or_none("time_s", "a time", time_s, times_s, line, lines)
        duration_s = _duration_s(item.get("duration_s"), line)
        _check_all_or_none("duration_s", "a duration", duration_s, durations_s, line, lines)
        if durations_s and duration_s != durations_s[0]:
            raise _line_error(
                line,
                f"'duration_s' is {duration_s!r} here but {durations_s[0]!r} on line {lines[0]}; "
                "every touch of a training set must last the same (an action means a "
                "trajectory of that duration).",
                "duration_s",
            )
        name = name.strip()
        if name not in names:
            names.append(name)
        index.append(names.index(name))
        actions.append(x.tolist())
        touches.append(touch)
        lines.append(line)
        placements.append(placement)
        times_s.append(time_s)
        durations_s.append(duration_s)
    if not touches:
        raise DocumentError("raw touches: the file holds no touch.", row=1)
    return RawTouchSet(
        tuple(names),
        np.asarray(index, dtype=np.int64),
        np.asarray(actions, dtype=np.float64),
        tuple(touches),
        tuple(lines),
        None if placements[0] is None else np.asarray(placements, dtype=np.int64),
        None if times_s[0] is None else np.asarray(times_s, dtype=np.float64),
        durations_s[0],
    )


def _placement(value: Any, line: int) -> int | None:
    """A line's ``placement``: ``None`` (absent or null) or an integer ≥ 0."""
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise _line_error(
            line,
            f"'placement' must be an integer ≥ 0 (or left out), received {reprlib.repr(value)}.",
            "placement",
        )
    return value


def _seconds(value: Any) -> float:
    """``value`` as a float, NaN for anything that is not a finite-able number."""
    try:
        return float(value) if not isinstance(value, bool | str) else math.nan
    except (TypeError, ValueError, OverflowError):  # a list, an object, an int beyond a float
        return math.nan


def _time_s(value: Any, line: int) -> float | None:
    """A line's ``time_s``: ``None`` (absent or null) or a finite number of seconds."""
    if value is None:
        return None
    number = _seconds(value)
    if not math.isfinite(number):
        raise _line_error(
            line,
            f"'time_s' must be a finite number of seconds (or left out), received "
            f"{reprlib.repr(value)}.",
            "time_s",
        )
    return number


def _duration_s(value: Any, line: int) -> float | None:
    """A line's ``duration_s``: ``None`` (absent or null) or a finite number of seconds > 0."""
    if value is None:
        return None
    number = _seconds(value)
    if not (math.isfinite(number) and number > 0):
        raise _line_error(
            line,
            f"'duration_s' must be a finite number of seconds > 0 (or left out), received "
            f"{reprlib.repr(value)}.",
            "duration_s",
        )
    return number


def featurise(touches: RawTouchSet, pipeline: FeaturePipeline) -> TrainingData:
    """The touches as training data: y of each touch through ``pipeline``.

    Raises:
        DocumentError: A touch the pipeline refuses (a series shorter than its window, another
            channel set); the message names its line and channel.
    """
    rows = []
    for line, touch in zip(touches.lines, touches.touches, strict=True):
        try:
            rows.append(pipeline.transform(touch))
        except InvalidInputError as exc:
            raise _line_error(line, str(exc)) from None
    try:
        return TrainingData(
            object_names=touches.object_names,
            object_index=touches.object_index,
            actions=touches.actions,
            observations=np.asarray(rows, dtype=np.float64),
            placement_index=touches.placement_index,
            touch_times_s=touches.touch_times_s,
            touch_duration_s=touches.touch_duration_s,
        )
    except InvalidInputError as exc:
        raise DocumentError(f"raw touches: {exc}") from exc


def line_refusal(touches: RawTouchSet, error: InvalidInputError) -> DocumentError:
    """An error of a pipeline fit (``touch k: …``) restated with the touch's line."""
    match = re.match(r"^touch (\d+): (.*)$", str(error), flags=re.DOTALL)
    if match is None:
        return DocumentError(f"raw touches: {error}")
    k = int(match.group(1))
    line = touches.lines[k - 1] if 1 <= k <= len(touches.lines) else k
    return _line_error(line, match.group(2))


def channels_field(touch: RawTouch) -> dict[str, dict[str, Any]]:
    """A touch's ``channels`` as written in a raw-touch line."""
    return {c.name: {"rate_hz": c.rate_hz, "samples": c.samples.tolist()} for c in touch.channels}


def raw_touch_line(
    object_name: str, action: Sequence[float] | FloatArray, touch: RawTouch, **extra: Any
) -> dict[str, Any]:
    """One raw-touch line (a JSON-ready dict); ``extra`` keys are added as they are."""
    return {
        "object": object_name,
        "action": [float(v) for v in action],
        "channels": channels_field(touch),
        **extra,
    }


def frame_rate_hz(times_s: FloatArray) -> float:
    """Frame rate of a recorded stream: frames per second between its first and last frame.

    Raises:
        InvalidInputError: Fewer than two frames, or no time between them.
    """
    if len(times_s) < 2 or not times_s[-1] > times_s[0]:
        raise InvalidInputError("the touch recorded fewer than two frames; no sample rate.")
    return float((len(times_s) - 1) / (times_s[-1] - times_s[0]))


def _frame_group(channel: str) -> tuple[str, str, int]:
    """(kind, channel name, position) of a frame channel: vector, subsample or scalar."""
    element = _ELEMENT.match(channel)
    if element is not None:
        return "vector", element.group("name"), int(element.group("index"))
    subsample = _SUBSAMPLE.match(channel)
    if subsample is not None:
        return "subsample", subsample.group("name"), int(subsample.group("index"))
    return "scalar", channel, 0


def raw_channel_names(frame_channels: Sequence[str]) -> tuple[str, ...]:
    """The raw channels frames of these channels make (:func:`raw_touch_from_frames`), in order."""
    names: list[str] = []
    for channel in frame_channels:
        name = _frame_group(channel)[1]
        if name not in names:
            names.append(name)
    return tuple(names)


def raw_touch_from_record(record: TouchRecord) -> RawTouch:
    """A rig touch as a raw touch: frame channels grouped by name.

    Frame channels named ``NAME[i]`` form the vector channel NAME (element i), those named
    ``NAME@k`` the k-th of K samples of NAME within one frame period (a series at K times the
    frame rate); any other frame channel is a scalar channel at the frame rate, estimated from
    the frame times (:func:`frame_rate_hz`).

    Raises:
        InvalidInputError: Fewer than two frames, or a group whose indices are not 0..K-1.
    """
    return raw_touch_from_frames(record.channel_names, record.tactile_times_s, record.tactile)


def raw_touch_from_frames(
    channel_names: Sequence[str], times_s: FloatArray, frames: FloatArray
) -> RawTouch:
    """Frames (n, C) of channels named as :func:`raw_touch_from_record` says, as a raw touch.

    Raises:
        InvalidInputError: Fewer than two frames, frames not (n, C), or a group whose indices
            are not 0..K-1.
    """
    if frames.ndim != 2 or frames.shape != (len(times_s), len(channel_names)):
        raise InvalidInputError(
            f"frames: expected shape ({len(times_s)}, {len(channel_names)}), received "
            f"{frames.shape}."
        )
    rate = frame_rate_hz(times_s)
    groups: dict[str, tuple[str, dict[int, int]]] = {}
    order: list[str] = []
    for column, channel in enumerate(channel_names):
        kind, name, position = _frame_group(channel)
        if name not in groups:
            groups[name] = (kind, {})
            order.append(name)
        elif groups[name][0] != kind or kind == "scalar":
            raise InvalidInputError(f"frame channel {channel!r}: mixes channel kinds of {name!r}.")
        groups[name][1][position] = column
    channels: list[RawChannel] = []
    for name in order:
        kind, columns = groups[name]
        if sorted(columns) != list(range(len(columns))):
            raise InvalidInputError(
                f"frame channels of {name!r}: indices {sorted(columns)}, expected "
                f"0..{len(columns) - 1}."
            )
        block = frames[:, [columns[i] for i in range(len(columns))]]
        if kind == "scalar":
            channels.append(raw_channel(name, rate, block[:, 0]))
        elif kind == "vector":
            channels.append(raw_channel(name, rate, block))
        else:
            channels.append(raw_channel(name, rate * len(columns), block.reshape(-1)))
    return RawTouch(tuple(channels))


def record_observation(record: TouchRecord, pipeline: FeaturePipeline | None) -> FloatArray:
    """y of a rig touch: the model's feature pipeline, or the channel means without one.

    Raises:
        InvalidInputError: The pipeline refuses the touch (another channel set, too short).
    """
    if pipeline is None:
        return record.observation
    return pipeline.transform(raw_touch_from_record(record))
