"""A raw touch: named tactile channels, each a series with its sample rate.

A channel is a series of n samples, either scalar (shape (n,)) or a vector per sample such as an
electrode array (shape (n, width)). The checks here refuse what no feature can be computed from
and name the channel: a missing or non-positive sample rate, NaN/inf samples, ragged vectors.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from core.errors import InvalidInputError
from core.validation import FloatArray


@dataclass(frozen=True)
class RawChannel:
    """One channel of a touch.

    Attributes:
        name: Channel name.
        rate_hz: Sample rate (> 0).
        samples: The series. Shape (n,) for a scalar channel, (n, width) for a vector one.
    """

    name: str
    rate_hz: float
    samples: FloatArray

    @property
    def width(self) -> int:
        """1 for a scalar channel, else the length of each sample's vector."""
        return 1 if self.samples.ndim == 1 else int(self.samples.shape[1])

    @property
    def n_samples(self) -> int:
        """Number of samples n."""
        return int(self.samples.shape[0])

    @property
    def is_vector(self) -> bool:
        """Whether each sample is a vector (an array of sensing elements)."""
        return self.samples.ndim == 2


@dataclass(frozen=True)
class RawTouch:
    """The channels of one touch, in a fixed order.

    Attributes:
        channels: The channels; names are distinct.
    """

    channels: tuple[RawChannel, ...]

    def __post_init__(self) -> None:
        names = [c.name for c in self.channels]
        if not names:
            raise InvalidInputError("raw touch: it has no channel.")
        repeated = sorted({n for n in names if names.count(n) > 1})
        if repeated:
            raise InvalidInputError(f"raw touch: channel names repeated: {repeated}.")

    @property
    def names(self) -> tuple[str, ...]:
        """Channel names, in order."""
        return tuple(c.name for c in self.channels)

    def channel(self, name: str) -> RawChannel:
        """The channel called ``name``.

        Raises:
            InvalidInputError: The touch has no such channel.
        """
        for c in self.channels:
            if c.name == name:
                return c
        raise InvalidInputError(f"raw touch: no channel {name!r} (it has {list(self.names)}).")


def raw_channel(name: str, rate_hz: object, samples: object) -> RawChannel:
    """Check and build one channel.

    Args:
        name: Channel name (used in every message).
        rate_hz: Sample rate, a positive finite number.
        samples: Nested sequences of numbers: n numbers, or n vectors of one common width.

    Raises:
        InvalidInputError: A missing or non-positive rate, no samples, ragged vectors, more than
            two dimensions, or a NaN/inf sample (the message gives its index).
    """
    if rate_hz is None or isinstance(rate_hz, bool):
        raise InvalidInputError(f"channel {name!r}: the sample rate (rate_hz) is missing.")
    try:
        rate = float(rate_hz)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise InvalidInputError(
            f"channel {name!r}: the sample rate must be a number, received {rate_hz!r}."
        ) from None
    if not (np.isfinite(rate) and rate > 0):
        raise InvalidInputError(f"channel {name!r}: the sample rate must be > 0, received {rate}.")
    if isinstance(samples, Sequence) and not isinstance(samples, str) and samples:
        lengths = {len(s) if isinstance(s, Sequence) else -1 for s in samples}
        if len(lengths) > 1:
            raise InvalidInputError(
                f"channel {name!r}: ragged series (samples of different lengths, or numbers "
                "mixed with vectors)."
            )
    try:
        array = np.asarray(samples, dtype=np.float64)
    except (TypeError, ValueError):
        raise InvalidInputError(
            f"channel {name!r}: the series could not be read as numbers (ragged vectors?)."
        ) from None
    if array.ndim not in (1, 2) or array.shape[0] == 0 or (array.ndim == 2 and array.shape[1] == 0):
        raise InvalidInputError(
            f"channel {name!r}: expected a series of shape (n,) or (n, width) with n ≥ 1, "
            f"received shape {array.shape}."
        )
    if not np.all(np.isfinite(array)):
        bad = ", ".join(str(int(i)) for i in np.argwhere(~np.isfinite(array))[0])
        raise InvalidInputError(f"channel {name!r}: a NaN or inf sample at index [{bad}].")
    array.flags.writeable = False
    return RawChannel(name, rate, array)


def check_same_layout(reference: RawTouch, touch: RawTouch) -> None:
    """Require ``touch`` to have the channels of ``reference``: same names, order and widths.

    Raises:
        InvalidInputError: A channel missing, extra or of another width (named).
    """
    missing = [n for n in reference.names if n not in touch.names]
    extra = [n for n in touch.names if n not in reference.names]
    if missing or extra:
        raise InvalidInputError(
            "the channel set differs from the first touch's "
            f"({list(reference.names)}): missing {missing}, extra {extra}."
        )
    for ref in reference.channels:
        got = touch.channel(ref.name)
        if got.is_vector != ref.is_vector or got.width != ref.width:
            raise InvalidInputError(
                f"channel {ref.name!r}: width {got.width if got.is_vector else 'scalar'}, the "
                f"first touch's is {ref.width if ref.is_vector else 'scalar'}."
            )


def raw_touch(channels: Mapping[str, tuple[object, object]]) -> RawTouch:
    """A raw touch from name → (rate_hz, samples), checked channel by channel."""
    return RawTouch(tuple(raw_channel(n, r, s) for n, (r, s) in channels.items()))
