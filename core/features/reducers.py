"""Per-channel reducers: well-known summaries of a tactile series.

Each takes a series of shape (n,) or (n, w) (w sensing elements) and returns one number per
element, except the spectral ones, which take a scalar series. Spectra come from Welch's method
(:func:`scipy.signal.welch`, Hann window, 50 % overlap, mean of the periodograms).
"""

from __future__ import annotations

import numpy as np
from scipy import signal

from core.errors import InvalidInputError
from core.validation import FloatArray

#: Added to band powers before the logarithm, so a silent band gives a finite feature.
LOG_FLOOR = 1e-12


def _columns(series: FloatArray) -> FloatArray:
    """The series as (n, w): a scalar series becomes one column."""
    return series[:, None] if series.ndim == 1 else series


def mean(series: FloatArray) -> FloatArray:
    """Mean over the samples. (n,) or (n, w) → (w,)."""
    return np.asarray(_columns(series).mean(axis=0), dtype=np.float64)


def rms(series: FloatArray) -> FloatArray:
    """Root mean square over the samples, √(mean x²). (n,) or (n, w) → (w,)."""
    return np.asarray(np.sqrt(np.mean(_columns(series) ** 2, axis=0)), dtype=np.float64)


def std(series: FloatArray) -> FloatArray:
    """Standard deviation over the samples (population, ddof = 0). (n,) or (n, w) → (w,)."""
    return np.asarray(_columns(series).std(axis=0), dtype=np.float64)


def slope(series: FloatArray, rate_hz: float) -> FloatArray:
    """Least-squares slope over the contact, per second. (n,) or (n, w) → (w,).

    The series is regressed on its sample times t_i = i / rate_hz: slope = cov(t, x) / var(t).

    Raises:
        InvalidInputError: Fewer than two samples.
    """
    columns = _columns(series)
    n = columns.shape[0]
    if n < 2:
        raise InvalidInputError(f"slope: needs at least 2 samples, received {n}.")
    times_s = np.arange(n, dtype=np.float64) / rate_hz
    coefficients = np.polynomial.polynomial.polyfit(times_s, columns, 1)
    return np.asarray(np.atleast_1d(coefficients[1]), dtype=np.float64)


def welch_spectrum(
    series: FloatArray, rate_hz: float, segment_samples: int
) -> tuple[FloatArray, FloatArray]:
    """Welch power spectral density of a scalar series.

    Args:
        series: The samples. Shape (n,), n ≥ ``segment_samples``.
        rate_hz: Sample rate.
        segment_samples: Length of each Welch segment.

    Returns:
        Frequencies in Hz, shape (segment_samples // 2 + 1,), and the one-sided PSD (units² per
        Hz) at them, after removing the series' mean.

    Raises:
        InvalidInputError: A vector series, or fewer samples than one segment.
    """
    if series.ndim != 1:
        raise InvalidInputError(f"welch_spectrum: expected a scalar series, shape {series.shape}.")
    if series.shape[0] < segment_samples:
        raise InvalidInputError(
            f"welch_spectrum: {series.shape[0]} samples, fewer than one segment of "
            f"{segment_samples}."
        )
    freqs, psd = signal.welch(series, fs=rate_hz, nperseg=segment_samples, detrend="constant")
    return np.asarray(freqs, dtype=np.float64), np.asarray(psd, dtype=np.float64)


def band_powers(freqs_hz: FloatArray, psd: FloatArray, edges_hz: FloatArray) -> FloatArray:
    """Power in each band [edges_k, edges_{k+1}): Σ PSD · Δf over the bins in the band.

    Args:
        freqs_hz: Equally spaced bin frequencies. Shape (m,).
        psd: Power spectral density at them. Shape (m,).
        edges_hz: Band edges, increasing. Shape (B + 1,).

    Returns:
        Band powers (units²). Shape (B,). A band with no bin has power 0.
    """
    step_hz = float(freqs_hz[1] - freqs_hz[0])
    band = np.searchsorted(edges_hz, freqs_hz, side="right") - 1
    inside = (band >= 0) & (band < len(edges_hz) - 1)
    powers = np.bincount(band[inside], weights=psd[inside], minlength=len(edges_hz) - 1)
    return np.asarray(powers * step_hz, dtype=np.float64)


def log_band_powers(freqs_hz: FloatArray, psd: FloatArray, edges_hz: FloatArray) -> FloatArray:
    """log(band power + :data:`LOG_FLOOR`) for each band. Shape (B,)."""
    return np.asarray(np.log(band_powers(freqs_hz, psd, edges_hz) + LOG_FLOOR), dtype=np.float64)


def spectral_centroid(freqs_hz: FloatArray, psd: FloatArray) -> float:
    """Power-weighted mean frequency Σ f P(f) / Σ P(f), in Hz (0 for a silent spectrum)."""
    total = float(psd.sum())
    if total <= 0.0:
        return 0.0
    return float(np.dot(freqs_hz, psd) / total)


def normalised_pattern(series: FloatArray) -> FloatArray:
    """An array's pattern: the mean of each element over the samples divided by its norm.

    Args:
        series: Shape (n, w).

    Returns:
        Unit vector of the per-element means (zeros if they are all zero). Shape (w,).
    """
    means = mean(series)
    norm = float(np.linalg.norm(means))
    return means / norm if norm > 0.0 else np.zeros_like(means)


def log_band_edges(rate_hz: float, segment_samples: int, n_bands: int) -> FloatArray:
    """Logarithmically spaced band edges from the first non-zero Welch bin to Nyquist.

    Returns:
        Shape (n_bands + 1,), in Hz; the last edge lies just above Nyquist so that bin is kept.
    """
    low_hz = rate_hz / segment_samples
    nyquist_hz = rate_hz / 2.0
    edges = np.geomspace(low_hz, nyquist_hz, n_bands + 1)
    edges[-1] = nyquist_hz * (1.0 + 1e-9)
    return np.asarray(edges, dtype=np.float64)
