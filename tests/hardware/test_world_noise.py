"""The simulated sensor's noise: correlated channels, slow bounded drift, reproducible."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from hardware.clock import VirtualClock
from hardware.errors import ConfigurationError
from hardware.sim.materials import get_object
from hardware.sim.noise import (
    FINGERTIP_CORRELATION,
    NO_DRIFT,
    DriftModel,
    NoiseModel,
    NoiseProcess,
)
from hardware.sim.world import Plant

R = np.asarray(FINGERTIP_CORRELATION)


def _frames(model: NoiseModel, n: int, seed: int = 0, period_s: float = 0.01) -> np.ndarray:
    process = NoiseProcess(model, np.random.default_rng(seed), period_s)
    return np.array([process.next_row()[0] for _ in range(n)])


def test_the_configured_correlation_is_the_reported_one_and_positive_definite() -> None:
    assert R[0, 1] == 0.69  # docs/method.md, "Real tactile data"
    assert R[0, 2] == 0.74
    assert all(0.4 <= abs(R[3, k]) <= 0.5 for k in (0, 1, 2, 4))
    assert np.linalg.eigvalsh(R).min() > 0.05


def test_frame_noise_has_the_configured_correlation_and_std() -> None:
    model = NoiseModel()
    rows = _frames(model, 60000)
    # AR(1) with a = exp(-0.01/0.05) ≈ 0.82: about 60000 · (1 - a)/(1 + a) ≈ 6000 effective
    # samples, a standard error of ≤ 0.013 on every correlation: 0.05 is ≥ 3.5 of them.
    assert np.max(np.abs(np.corrcoef(rows, rowvar=False) - R)) < 0.05
    np.testing.assert_allclose(rows.std(axis=0), model.channel_std, rtol=0.06)
    # Correlated in time as configured: lag-1 autocorrelation exp(-Δt/τ).
    lag = np.mean([np.corrcoef(rows[:-1, k], rows[1:, k])[0, 1] for k in range(5)])
    assert lag == pytest.approx(np.exp(-0.01 / 0.05), abs=0.02)


def test_contact_offsets_have_the_configured_correlation() -> None:
    model = NoiseModel()
    process = NoiseProcess(model, np.random.default_rng(1), 0.01)
    offsets = np.array([process.contact_offset() for _ in range(20000)])
    # Independent draws: standard error ≤ 0.007; tolerance 0.03.
    assert np.max(np.abs(np.corrcoef(offsets, rowvar=False) - R)) < 0.03
    np.testing.assert_allclose(offsets.std(axis=0), model.contact_std, rtol=0.03)


def test_another_correlation_is_honoured_and_bad_ones_are_refused() -> None:
    other = np.eye(5)
    other[0, 1] = other[1, 0] = -0.5
    model = NoiseModel(channel_correlation=tuple(map(tuple, other)), frame_time_constant_s=0.0)
    rows = _frames(model, 20000)
    assert np.corrcoef(rows, rowvar=False)[0, 1] == pytest.approx(-0.5, abs=0.03)
    bad = np.eye(5)
    bad[0, 1] = bad[1, 0] = 1.2
    with pytest.raises(ConfigurationError, match="positive definite"):
        NoiseModel(channel_correlation=tuple(map(tuple, bad)))
    with pytest.raises(ConfigurationError, match="contact_std"):
        NoiseModel(contact_std=(0.1, 0.1))


def test_drift_is_a_bounded_stationary_slow_process() -> None:
    drift = DriftModel()
    process = NoiseProcess(NoiseModel(drift=drift), np.random.default_rng(2), 1.0)
    values = np.array([process.next_row()[1] for _ in range(4 * 3600)])  # 4 h, one row per s
    std = drift.std
    # Bounded: an OU path of 4 h stays within 5 stationary std (P(exceed) < 1e-4 per τ).
    assert np.all(np.abs(values) < 5.0 * std)
    # Its spread is the configured one (loosely: 4 h hold only 16-60 correlation times).
    np.testing.assert_allclose(values.std(axis=0), std, rtol=0.5)
    # Slow: a minute apart the values are nearly the same; an hour apart nearly independent.
    for k, tau in enumerate(drift.time_s):
        minute = np.corrcoef(values[:-60, k], values[60:, k])[0, 1]
        assert minute == pytest.approx(np.exp(-60.0 / tau), abs=0.08)


def test_noise_and_drift_are_reproducible_for_a_seed() -> None:
    model = NoiseModel()
    a = NoiseProcess(model, np.random.default_rng(5), 0.5)
    b = NoiseProcess(model, np.random.default_rng(5), 0.5)
    c = NoiseProcess(model, np.random.default_rng(6), 0.5)
    rows_a = [a.next_row() for _ in range(1500)]
    rows_b = [b.next_row() for _ in range(1500)]
    rows_c = [c.next_row() for _ in range(1500)]
    assert rows_a == rows_b
    assert rows_a != rows_c


def test_batches_do_not_change_the_process() -> None:
    model = NoiseModel()
    small = NoiseProcess(model, np.random.default_rng(7), 0.01, batch=512)
    first = [small.next_row() for _ in range(1000)]
    again = NoiseProcess(model, np.random.default_rng(7), 0.01, batch=512)
    assert [again.next_row() for _ in range(1000)] == first


def _plant_samples(noise: NoiseModel, seconds: float, seed: int = 0) -> np.ndarray:
    clock = VirtualClock()
    plant = Plant({0: get_object("paper_cup")}, clock, np.random.default_rng(seed), noise=noise)
    samples: list[tuple[float, ...]] = []
    plant.attach_sampler(lambda _t, row: samples.append(row), 0.01)
    clock.sleep(seconds)
    plant.advance()
    return np.array(samples)


def test_the_world_samples_carry_the_configured_noise_off_contact() -> None:
    # Off contact (finger retracted), the clean channels are constant: what varies is noise.
    noise = dataclasses.replace(NoiseModel(), drift=NO_DRIFT)
    samples = _plant_samples(noise, 300.0)
    assert np.max(np.abs(np.corrcoef(samples, rowvar=False) - R)) < 0.05


def test_the_skin_temperature_follows_the_heater_drift() -> None:
    # Only the heater drifts: the temperature channel's slow part follows it (a 240 s drift
    # of 0.5 °C against a frame noise of 0.01 °C).
    drift = DriftModel(0.5, 240.0, 0.0, 900.0, 0.0, 600.0)
    samples = _plant_samples(NoiseModel(drift=drift), 1800.0, seed=3)
    minute_means = samples[: 180000 // 6000 * 6000, 4].reshape(-1, 6000).mean(axis=1)
    assert minute_means.std() > 0.1
    assert np.all(np.abs(minute_means - 33.0) < 5 * 0.5)
    replay = _plant_samples(NoiseModel(drift=drift), 1800.0, seed=3)
    np.testing.assert_array_equal(samples, replay)
