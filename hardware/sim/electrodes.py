"""The simulated sensor's whole-touch channels: an electrode array and a high-rate vibration.

A multimodal fingertip sensor records more than five channel
envelopes: an array of impedance electrodes under the skin and the raw vibration at kHz rates.
:class:`WholeTouchSensor` adds both to every tactile frame (``docs/tactile-frames.md``):

- ``electrode[0]`` … ``electrode[E-1]``: E electrodes on a ring under the pad. The normal force F
  is spread over them by the contact patch, a Gaussian of width ``contact_width`` (in electrode
  spacings) centred where the patch is: electrode i reads F · k_i / Σ_j k_j, so the electrodes
  always sum to F. The patch starts at a random place on each contact and travels with the
  sliding, one electrode spacing per ``electrode_pitch_mm`` slid. A narrow contact (an edge, a
  ridge) lights one or two electrodes at a time, a broad one many — but averaged over where the
  patch happens to be, every electrode reads F / E on every object.
- ``vibration@0`` … ``vibration@K-1``: K successive samples of the skin's vibration within one
  frame period (a series at K × the frame rate). Sliding at speed v over a surface whose fine
  texture has period λ excites a tone at f = v / λ of amplitude a · √F · v / (v + 10 mm/s): the
  same amplitude for every period, so the vibration's mean (0) and RMS are the same on every
  object and only its spectrum tells the textures apart.

A :class:`SurfaceDetail` per object gives its fine texture period and contact width; the preset
objects of the ``twins`` table (:data:`TWINS`) share one material, so their five paper channels
have the same means too, and only the whole touch tells them apart.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from hardware.errors import ConfigurationError
from hardware.frames import MAX_CHANNELS


@dataclass(frozen=True)
class SurfaceDetail:
    """What only the whole touch feels of a surface.

    Attributes:
        fine_period_mm: Period of the fine texture the raw vibration hears (f = v / λ).
        contact_width: Width (standard deviation) of the contact patch, in electrode spacings.
    """

    fine_period_mm: float
    contact_width: float

    def __post_init__(self) -> None:
        if not (self.fine_period_mm > 0 and self.contact_width > 0):
            raise ConfigurationError(
                f"SurfaceDetail: fine_period_mm and contact_width must be > 0, received "
                f"{self.fine_period_mm} and {self.contact_width}."
            )


#: Detail assumed for an object without one: a smooth surface, a broad contact.
PLAIN = SurfaceDetail(fine_period_mm=1.0, contact_width=2.0)


@dataclass(frozen=True)
class WholeTouchSensor:
    """The whole-touch channels added to each frame.

    Attributes:
        n_electrodes: Electrodes on the ring (E).
        vibration_samples_per_frame: Vibration samples per frame (K).
        electrode_pitch_mm: Sliding distance that moves the patch by one electrode.
        vibration_gain: a, the vibration amplitude per √N at fast sliding.
        electrode_noise: Standard deviation of each electrode's noise per frame (N).
        vibration_noise: Standard deviation of each vibration sample's noise.
    """

    n_electrodes: int = 8
    vibration_samples_per_frame: int = 16
    electrode_pitch_mm: float = 2.0
    vibration_gain: float = 0.05
    electrode_noise: float = 0.01
    vibration_noise: float = 0.01

    def __post_init__(self) -> None:
        extra = self.n_electrodes + self.vibration_samples_per_frame
        if self.n_electrodes < 1 or self.vibration_samples_per_frame < 1:
            raise ConfigurationError("WholeTouchSensor: at least one electrode and one sample.")
        if 5 + extra > MAX_CHANNELS:
            raise ConfigurationError(
                f"WholeTouchSensor: 5 + {extra} channels exceed a frame's {MAX_CHANNELS}."
            )

    @property
    def channel_names(self) -> tuple[str, ...]:
        """The added frame channels, in frame order (after the five paper channels)."""
        return tuple(f"electrode[{i}]" for i in range(self.n_electrodes)) + tuple(
            f"vibration@{k}" for k in range(self.vibration_samples_per_frame)
        )


class WholeTouchChannels:
    """The state of the whole-touch channels: where the patch is, the vibration's phase.

    Args:
        sensor: The channels' settings.
        rng: Their randomness (patch start, noise).
    """

    def __init__(self, sensor: WholeTouchSensor, rng: np.random.Generator) -> None:
        self.sensor = sensor
        self.rng = rng
        self._patch = 0.0
        self._phase = 0.0
        self._touching = False
        ring = np.arange(sensor.n_electrodes, dtype=np.float64)
        self._ring = ring

    def sample(
        self,
        force_n: float,
        slide_speed_mm_s: float,
        detail: SurfaceDetail | None,
        period_s: float,
    ) -> tuple[float, ...]:
        """The added channels of one frame.

        Args:
            force_n: Normal force at the frame.
            slide_speed_mm_s: Sliding speed.
            detail: The touched surface's detail (``None``: not touching an object).
            period_s: Time since the previous frame.

        Returns:
            E electrode readings then K vibration samples.
        """
        s = self.sensor
        touching = detail is not None and force_n > 0.1
        if touching and not self._touching:
            self._patch = float(self.rng.uniform(0.0, s.n_electrodes))
        self._touching = touching
        electrodes = s.electrode_noise * self.rng.standard_normal(s.n_electrodes)
        vibration = s.vibration_noise * self.rng.standard_normal(s.vibration_samples_per_frame)
        if touching and detail is not None:
            speed = abs(slide_speed_mm_s)
            self._patch = (self._patch + speed * period_s / s.electrode_pitch_mm) % s.n_electrodes
            distance = np.abs(self._ring - self._patch)
            distance = np.minimum(distance, s.n_electrodes - distance)
            kernel = np.exp(-0.5 * (distance / detail.contact_width) ** 2)
            electrodes += force_n * kernel / kernel.sum()
            frequency_hz = speed / detail.fine_period_mm
            amplitude = s.vibration_gain * math.sqrt(force_n) * speed / (speed + 10.0)
            step = period_s / s.vibration_samples_per_frame
            phases = self._phase + 2 * math.pi * frequency_hz * step * np.arange(
                1, s.vibration_samples_per_frame + 1
            )
            vibration += amplitude * np.sin(phases)
            self._phase = float(phases[-1] % (2 * math.pi))
        return tuple(float(v) for v in np.concatenate([electrodes, vibration]))


TWINS: dict[str, SurfaceDetail] = {
    "twin_fine_broad": SurfaceDetail(fine_period_mm=0.05, contact_width=2.0),
    "twin_coarse_broad": SurfaceDetail(fine_period_mm=0.2, contact_width=2.0),
    "twin_fine_edge": SurfaceDetail(fine_period_mm=0.05, contact_width=0.6),
    "twin_coarse_edge": SurfaceDetail(fine_period_mm=0.2, contact_width=0.6),
}
"""The ``twins`` table's objects: one material; fine or coarse texture, broad or edge contact."""


def surface_detail(name: str) -> SurfaceDetail | None:
    """The detail of a preset object, if it has one."""
    return TWINS.get(name)
