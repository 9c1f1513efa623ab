"""Features of a whole touch: raw tactile series in, a few learned numbers y out.

:mod:`core.features.raw` holds a raw touch (named channels, each a series with its sample rate),
:mod:`core.features.reducers` the well-known per-channel reducers (mean, RMS, standard deviation,
least-squares slope, Welch band powers and spectral centroid, an electrode array's normalised
pattern), and :mod:`core.features.pipeline` the pipeline a model carries: reducers, then
standardisation and a PCA reduction whose dimension is chosen by cross-validated recognition.
"""
