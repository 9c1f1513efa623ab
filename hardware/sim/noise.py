"""Sensor noise and slow drift of the simulated fingertip (see docs/simulation.md).

Three random processes, all driven by one :class:`numpy.random.Generator` (deterministic for a
seed) and advanced once per sensor sample:

- **frame noise**: every channel's per-frame noise, correlated across channels by
  :data:`FINGERTIP_CORRELATION` and in time by a first-order (AR(1)) filter of time constant
  ``frame_time_constant_s``;
- **contact offsets**: one correlated offset per contact, held from touch-down to lift-off (the
  skin seats a little differently every time), with the same channel correlation;
- **drift**: Ornstein–Uhlenbeck processes over minutes of simulated time — the heater's set
  point, the room (and so the objects') temperature, and the pressure transducer's baseline.

Channel order is the sensor's: vibration low band, vibration high band, pressure, heat flux,
temperature. The world (:mod:`hardware.sim.world`) scales the vibration channels' noise with the
normal force and feeds the two temperature drifts through its heat-exchange model, so heat flux
and temperature move together as two views of one exchange.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt
import scipy.signal

from hardware.errors import ConfigurationError

FloatArray = npt.NDArray[np.float64]

#: Residual correlation between the five channels of a real fingertip sensor (docs/method.md, "Real
#: tactile data": 0.69 between the two vibration features, 0.74 between vibration (the low band,
#: the "vibration mean") and pressure, 0.4–0.5 between heat flux and the others). The
#: high band–pressure entry is not reported; 0.51 ≈ 0.69 · 0.74 is what the two reported ones
#: imply through a common factor. The heat flux–temperature entry is −0.45: the magnitude is the
#: reported range, the sign the physics (more heat drawn, cooler skin); temperature's other
#: entries (−0.2) follow through heat flux (0.45 · −0.45).
FINGERTIP_CORRELATION: tuple[tuple[float, ...], ...] = (
    (1.00, 0.69, 0.74, 0.40, -0.20),
    (0.69, 1.00, 0.51, 0.40, -0.20),
    (0.74, 0.51, 1.00, 0.45, -0.20),
    (0.40, 0.40, 0.45, 1.00, -0.45),
    (-0.20, -0.20, -0.20, -0.45, 1.00),
)

#: Index of each drift process in :attr:`NoiseProcess.drift`.
DRIFT_CORE_C, DRIFT_AMBIENT_C, DRIFT_PRESSURE = 0, 1, 2


@dataclass(frozen=True)
class DriftModel:
    """Slow Ornstein–Uhlenbeck drift: stationary standard deviation and time constant of each.

    Attributes:
        core_temperature_std_c: Wander of the sensor heater's set point.
        core_temperature_time_s: Its correlation time.
        ambient_temperature_std_c: Wander of the room's (and every object's) temperature.
        ambient_temperature_time_s: Its correlation time.
        pressure_offset_std: Wander of the pressure transducer's baseline (channel units).
        pressure_offset_time_s: Its correlation time.
    """

    core_temperature_std_c: float = 0.08
    core_temperature_time_s: float = 240.0
    ambient_temperature_std_c: float = 0.25
    ambient_temperature_time_s: float = 900.0
    pressure_offset_std: float = 0.04
    pressure_offset_time_s: float = 600.0

    def __post_init__(self) -> None:
        for name in ("core_temperature", "ambient_temperature", "pressure_offset"):
            std = float(getattr(self, f"{name}_std" + ("_c" if "temperature" in name else "")))
            time_s = float(getattr(self, f"{name}_time_s"))
            if not std >= 0 or not time_s > 0:
                raise ConfigurationError(
                    f"drift {name}: std must be ≥ 0 and time > 0, received {std} and {time_s}."
                )

    @property
    def std(self) -> FloatArray:
        """Stationary standard deviations (core °C, ambient °C, pressure). Shape (3,)."""
        return np.array(
            [self.core_temperature_std_c, self.ambient_temperature_std_c, self.pressure_offset_std]
        )

    @property
    def time_s(self) -> FloatArray:
        """Correlation times, in the order of :attr:`std`. Shape (3,)."""
        return np.array(
            [
                self.core_temperature_time_s,
                self.ambient_temperature_time_s,
                self.pressure_offset_time_s,
            ]
        )


NO_DRIFT = DriftModel(0.0, 240.0, 0.0, 900.0, 0.0, 600.0)


def _check_correlation(matrix: FloatArray, size: int) -> None:
    if matrix.shape != (size, size):
        raise ConfigurationError(
            f"channel_correlation: expected shape ({size}, {size}), received {matrix.shape}."
        )
    if not np.allclose(matrix, matrix.T) or not np.allclose(np.diag(matrix), 1.0):
        raise ConfigurationError("channel_correlation: must be symmetric with a unit diagonal.")
    if np.linalg.eigvalsh(matrix).min() <= 0:
        raise ConfigurationError("channel_correlation: must be positive definite.")


@dataclass(frozen=True)
class NoiseModel:
    """Randomness of the simulated world.

    Attributes:
        channel_std: Per-frame noise of each channel (same order as the channels).
        contact_std: Per-contact offset of each channel, held for the whole contact.
        channel_correlation: Correlation between channels of both the frame noise and the
            contact offsets. Shape (C, C) as nested tuples.
        frame_time_constant_s: Correlation time of the frame noise (0: white).
        vibration_gain_per_n: The vibration channels' noise grows as (1 + gain · force): pressure
            scales the vibration.
        drift: Slow drift of temperatures and the pressure baseline.
        placement_std_deg: Spread of an object's contact angle each time the table brings it.
        slip_std_deg: Extra shift after each lift-off.
        object_temperature_std_c: Spread of the object's temperature per placement.
    """

    channel_std: tuple[float, ...] = (0.05, 0.05, 0.03, 2.0, 0.01)
    contact_std: tuple[float, ...] = (0.02, 0.02, 0.08, 1.5, 0.01)
    channel_correlation: tuple[tuple[float, ...], ...] = FINGERTIP_CORRELATION
    frame_time_constant_s: float = 0.05
    vibration_gain_per_n: float = 0.3
    drift: DriftModel = field(default_factory=DriftModel)
    placement_std_deg: float = 0.25
    slip_std_deg: float = 0.1
    object_temperature_std_c: float = 0.15

    def __post_init__(self) -> None:
        size = len(self.channel_std)
        if len(self.contact_std) != size:
            raise ConfigurationError(
                f"contact_std: one value per channel ({size}), received {len(self.contact_std)}."
            )
        if min((*self.channel_std, *self.contact_std)) < 0:
            raise ConfigurationError("channel_std and contact_std: must be ≥ 0.")
        _check_correlation(np.asarray(self.channel_correlation, dtype=np.float64), size)
        if self.frame_time_constant_s < 0 or self.vibration_gain_per_n < 0:
            raise ConfigurationError(
                "frame_time_constant_s and vibration_gain_per_n: must be ≥ 0, received "
                f"{self.frame_time_constant_s} and {self.vibration_gain_per_n}."
            )

    def covariance(self, std: tuple[float, ...]) -> FloatArray:
        """diag(std) R diag(std) for a vector of standard deviations. Shape (C, C)."""
        scale = np.asarray(std, dtype=np.float64)
        return np.asarray(self.channel_correlation) * np.outer(scale, scale)


#: The previous simulated world: independent white noise, no drift, no contact offsets.
INDEPENDENT_NOISE = NoiseModel(
    contact_std=(0.0, 0.0, 0.0, 0.0, 0.0),
    channel_correlation=tuple(tuple(1.0 if i == j else 0.0 for j in range(5)) for i in range(5)),
    frame_time_constant_s=0.0,
    vibration_gain_per_n=0.0,
    drift=NO_DRIFT,
)


class NoiseProcess:
    """The noise processes of one plant, advanced one sensor sample at a time.

    Rows are generated in batches (the sampler is a hot path): each batch filters white normal
    draws through the exact AR(1) / Ornstein–Uhlenbeck recursions
    z_{k+1} = a z_k + √(1 − a²) σ ξ_k, a = exp(−Δt / τ), carrying the filter state across batches,
    so the result does not depend on the batch size.

    Args:
        model: The noise model.
        rng: Source of randomness.
        period_s: Time between samples.
        batch: Rows per batch.
    """

    def __init__(
        self, model: NoiseModel, rng: np.random.Generator, period_s: float, batch: int = 512
    ) -> None:
        if not period_s > 0:
            raise ConfigurationError(f"period_s: must be positive, received {period_s}.")
        self.model = model
        self.rng = rng
        self.period_s = float(period_s)
        self.batch = int(batch)
        self.n_channels = len(model.channel_std)
        # diag(std) R diag(std) = (diag(std) L)(diag(std) L)ᵀ with R = L Lᵀ (zero stds allowed).
        root = np.linalg.cholesky(np.asarray(model.channel_correlation, dtype=np.float64))
        self._frame_root = np.asarray(model.channel_std)[:, None] * root
        self._contact_root = np.asarray(model.contact_std)[:, None] * root
        tau = model.frame_time_constant_s
        self._frame_decay = 0.0 if tau == 0 else math.exp(-self.period_s / tau)
        self._drift_decay = np.exp(-self.period_s / model.drift.time_s)
        drift_std = model.drift.std
        # Start at a stationary draw so the drift is stationary from the first sample.
        self._frame_state = self._frame_root @ rng.standard_normal(self.n_channels)
        self._drift_state = drift_std * rng.standard_normal(3)
        self._frames: list[list[float]] = []
        self._drifts: list[list[float]] = []
        self._index = 0

    def _refill(self) -> None:
        n, c = self.batch, self.n_channels
        white = self.rng.standard_normal((n, c + 3))
        frame_innovation = white[:, :c] @ self._frame_root.T
        a = self._frame_decay
        frames, _ = scipy.signal.lfilter(
            [math.sqrt(1.0 - a * a)],
            [1.0, -a],
            frame_innovation,
            axis=0,
            zi=a * self._frame_state[None, :],
        )
        self._frame_state = frames[-1]
        drifts = np.empty((n, 3))
        std = self.model.drift.std
        for k in range(3):
            b = float(self._drift_decay[k])
            drifts[:, k], _ = scipy.signal.lfilter(
                [math.sqrt(1.0 - b * b) * std[k]],
                [1.0, -b],
                white[:, c + k],
                zi=[b * self._drift_state[k]],
            )
        self._drift_state = drifts[-1].copy()
        self._frames = frames.tolist()
        self._drifts = drifts.tolist()
        self._index = 0

    def next_row(self) -> tuple[list[float], list[float]]:
        """Frame noise (C channels) and drift (core °C, ambient °C, pressure) at the next sample."""
        if self._index >= len(self._frames):
            self._refill()
        row = self._index
        self._index += 1
        return self._frames[row], self._drifts[row]

    def contact_offset(self) -> list[float]:
        """A fresh per-contact offset of the C channels."""
        draw = self._contact_root @ self.rng.standard_normal(self.n_channels)
        offset: list[float] = draw.tolist()
        return offset
