"""The whole-touch feature pipeline: reducers against closed forms, PCA, dy selection."""

from __future__ import annotations

import numpy as np
import pytest

from core.errors import InvalidInputError
from core.features import reducers
from core.features.pipeline import (
    FeatureSettings,
    check_touches,
    discriminant_axes,
    fit_features,
    gaussian_classify,
    principal_axes,
    standardise,
)
from core.features.raw import RawTouch, raw_channel, raw_touch


def test_mean_rms_std_of_a_known_series() -> None:
    series = np.array([1.0, -1.0, 3.0, -3.0])
    assert reducers.mean(series) == pytest.approx([0.0])
    assert reducers.rms(series) == pytest.approx([np.sqrt(5.0)])
    assert reducers.std(series) == pytest.approx([np.sqrt(5.0)])
    vectors = np.array([[1.0, 2.0], [3.0, 6.0]])
    assert reducers.mean(vectors) == pytest.approx([2.0, 4.0])
    assert reducers.std(vectors) == pytest.approx([1.0, 2.0])


def test_slope_of_a_line_is_its_rate_per_second() -> None:
    rate_hz = 50.0
    times_s = np.arange(40) / rate_hz
    line = 3.0 - 0.7 * times_s
    assert reducers.slope(line, rate_hz) == pytest.approx([-0.7])
    two = np.stack([line, 2.0 * times_s], axis=1)
    assert reducers.slope(two, rate_hz) == pytest.approx([-0.7, 2.0])
    with pytest.raises(InvalidInputError, match="at least 2 samples"):
        reducers.slope(np.array([1.0]), rate_hz)


def test_welch_band_power_of_a_sine_is_half_its_squared_amplitude() -> None:
    rate_hz, segment = 2000.0, 256
    bin_hz = rate_hz / segment
    frequency_hz = 20 * bin_hz  # on a bin: no leakage beyond the Hann main lobe
    amplitude = 1.5
    t = np.arange(4096) / rate_hz
    sine = amplitude * np.sin(2 * np.pi * frequency_hz * t)
    freqs, psd = reducers.welch_spectrum(sine, rate_hz, segment)
    edges = np.array([0.0, frequency_hz - 4 * bin_hz, frequency_hz + 4 * bin_hz, rate_hz])
    powers = reducers.band_powers(freqs, psd, edges)
    # Parseval: a sine of amplitude A carries power A²/2, all of it near its frequency.
    assert powers[1] == pytest.approx(amplitude**2 / 2, rel=1e-3)
    assert powers[0] + powers[2] < 1e-6
    assert reducers.log_band_powers(freqs, psd, edges)[1] == pytest.approx(
        np.log(amplitude**2 / 2), abs=1e-3
    )
    assert reducers.spectral_centroid(freqs, psd) == pytest.approx(frequency_hz, rel=1e-6)


def test_spectral_centroid_of_a_known_spectrum() -> None:
    freqs = np.array([0.0, 10.0, 20.0, 30.0])
    psd = np.array([0.0, 1.0, 0.0, 3.0])
    assert reducers.spectral_centroid(freqs, psd) == pytest.approx((10 + 90) / 4)
    assert reducers.spectral_centroid(freqs, np.zeros(4)) == 0.0


def test_normalised_pattern_is_the_unit_vector_of_the_element_means() -> None:
    series = np.array([[3.0, 0.0, 4.0], [3.0, 0.0, 4.0]])
    assert reducers.normalised_pattern(series) == pytest.approx([0.6, 0.0, 0.8])
    assert reducers.normalised_pattern(2.0 * series) == pytest.approx([0.6, 0.0, 0.8])


def test_log_band_edges_run_from_the_first_bin_to_nyquist() -> None:
    edges = reducers.log_band_edges(2000.0, 256, 4)
    assert edges[0] == pytest.approx(2000.0 / 256)
    assert edges[-1] == pytest.approx(1000.0)
    assert np.allclose(np.diff(np.log(edges)), np.log(edges[1] / edges[0]))


def test_raw_channel_refuses_what_no_feature_can_be_made_of() -> None:
    with pytest.raises(InvalidInputError, match=r"'p'.*sample rate.*missing"):
        raw_channel("p", None, [1.0, 2.0])
    with pytest.raises(InvalidInputError, match=r"'p'.*> 0"):
        raw_channel("p", 0.0, [1.0, 2.0])
    with pytest.raises(InvalidInputError, match=r"'p'.*NaN or inf sample at index \[1\]"):
        raw_channel("p", 10.0, [1.0, float("nan")])
    with pytest.raises(InvalidInputError, match=r"'e'.*ragged"):
        raw_channel("e", 10.0, [[1.0, 2.0], [1.0]])
    assert raw_channel("e", 10.0, [[1.0, 2.0], [3.0, 4.0]]).width == 2


def _touch(rng: np.random.Generator, frequency_hz: float, pattern: np.ndarray) -> RawTouch:
    """A touch with a slow pressure channel, a 1 kHz vibration and a 4-element array."""
    t_slow = np.arange(50) / 50.0
    t_fast = np.arange(1024) / 1000.0
    vibration = np.sin(2 * np.pi * frequency_hz * t_fast + rng.uniform(0, 6.3))
    array = pattern[None, :] * (1.0 + 0.5 * np.sin(2 * np.pi * t_slow))[:, None]
    return raw_touch(
        {
            "pressure_kpa": (50.0, 2.0 + 0.05 * rng.normal(size=50)),
            "vibration": (1000.0, vibration + 0.05 * rng.normal(size=1024)),
            "electrode": (50.0, array + 0.02 * rng.normal(size=array.shape)),
        }
    )


def _two_objects(n: int) -> tuple[list[RawTouch], np.ndarray]:
    """Same channel means; the objects differ only in vibration frequency."""
    rng = np.random.default_rng(0)
    pattern = np.array([1.0, 2.0, 3.0, 4.0])
    touches = [_touch(rng, 40.0 if k % 2 else 200.0, pattern) for k in range(n)]
    return touches, np.arange(n) % 2


def test_means_fail_where_the_whole_touch_tells_the_objects_apart() -> None:
    touches, index = _two_objects(40)
    means = fit_features(touches, index, "means")
    whole = fit_features(touches, index, "whole", feature_dim=3)
    y_means = means.transform_many(touches)
    y_whole = whole.transform_many(touches)
    assert y_means.shape == (40, 6)  # pressure, vibration, 4 electrodes
    assert means.output_names[2:] == tuple(f"electrode[{i}]" for i in range(4))

    def accuracy(y: np.ndarray) -> float:
        picked = gaussian_classify(y[:20], index[:20], y[20:])
        return float(np.mean(picked == index[20:]))

    assert accuracy(y_whole) == 1.0
    assert accuracy(y_means) < 0.8


def test_whole_pipeline_names_and_selection() -> None:
    touches, index = _two_objects(30)
    pipeline = fit_features(touches, index, "whole", FeatureSettings(n_bands=4, folds=3))
    names = pipeline.reduced_names
    assert "centroid_hz:vibration" in names
    assert sum(n.startswith("log_power:vibration") for n in names) == 4
    assert sum(n.startswith("pattern:electrode") for n in names) == 4
    assert len(names) == 4 + (4 + 4 + 1) + (4 * 3 + 1)
    selection = pipeline.selection
    assert selection is not None
    assert pipeline.output_dim == selection.chosen
    chosen = next(c for c in selection.candidates if c.feature_dim == selection.chosen)
    assert chosen.mean == 1.0  # one touch's frequency is plain to see


def test_pca_with_all_components_reconstructs_the_standardised_features() -> None:
    rng = np.random.default_rng(1)
    reduced = rng.normal(size=(12, 5)) @ rng.normal(size=(5, 5))
    center, scale = standardise(reduced)
    z = (reduced - center) / scale
    axes, variance = principal_axes(z, 5)
    assert np.allclose(axes.T @ axes, np.eye(5))
    assert np.allclose((z @ axes) @ axes.T, z)
    assert np.allclose(variance, np.var(z @ axes, axis=0))
    assert np.all(np.diff(variance) <= 1e-12)


def test_pipeline_refuses_short_series_and_other_channels_naming_them() -> None:
    touches, index = _two_objects(10)
    pipeline = fit_features(touches, index, "whole", feature_dim=2)
    short = RawTouch(
        tuple(
            c if c.name != "vibration" else raw_channel("vibration", 1000.0, c.samples[:100])
            for c in touches[0].channels
        )
    )
    with pytest.raises(InvalidInputError, match=r"'vibration': 100 samples, shorter than.*256"):
        pipeline.transform(short)
    with pytest.raises(InvalidInputError, match=r"touch 2: .*missing \['electrode'\]"):
        fit_features([touches[0], RawTouch(touches[1].channels[:2])], index[:2], "whole")
    with pytest.raises(InvalidInputError, match="feature_dim"):
        fit_features(touches, index, "whole", feature_dim=40)


def test_check_touches_names_the_first_touch_a_pipeline_cannot_take() -> None:
    touches, _ = _two_objects(4)
    check_touches(touches, "whole")
    short = RawTouch(
        tuple(
            c if c.name != "vibration" else raw_channel("vibration", 1000.0, c.samples[:255])
            for c in touches[2].channels
        )
    )
    pressure_short = RawTouch(
        tuple(
            c if c.name != "pressure_kpa" else raw_channel("pressure_kpa", 50.0, c.samples[:3])
            for c in touches[1].channels
        )
    )
    with pytest.raises(InvalidInputError, match=r"^touch 3: channel 'vibration': 255 samples"):
        check_touches([*touches[:2], short, touches[3]], "whole")
    with pytest.raises(InvalidInputError, match=r"^touch 2: channel 'pressure_kpa': 3 samples"):
        check_touches([touches[0], pressure_short], "whole")
    check_touches([touches[0], short, pressure_short], "means")  # a mean needs one sample
    with pytest.raises(InvalidInputError, match=r"^touch 2: the channel set differs"):
        check_touches([touches[0], RawTouch(touches[1].channels[:2])], "means")


def test_lda_axis_of_two_objects_is_fishers_direction() -> None:
    rng = np.random.default_rng(2)
    within = np.array([[1.0, 0.8], [0.8, 1.0]])
    chol = np.linalg.cholesky(within)
    shift = np.array([1.0, 0.0])
    rows = np.concatenate(
        [rng.normal(size=(4000, 2)) @ chol.T, shift + rng.normal(size=(4000, 2)) @ chol.T]
    )
    index = np.repeat([0, 1], 4000)
    rows = rows - rows.mean(axis=0)
    axes, _ = discriminant_axes(rows, index, 1)
    fisher = np.linalg.solve(within, shift)
    cosine = abs(axes[:, 0] @ fisher) / np.linalg.norm(axes[:, 0]) / np.linalg.norm(fisher)
    assert cosine > 0.999
    residuals = rows - np.where(
        index[:, None] == 0, rows[index == 0].mean(0), rows[index == 1].mean(0)
    )
    assert np.var(residuals @ axes[:, 0]) == pytest.approx(1.0, rel=0.01)
    with pytest.raises(InvalidInputError, match="L − 1 = 1"):
        discriminant_axes(rows, index, 2)
