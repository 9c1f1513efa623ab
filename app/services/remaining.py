"""The time a fit (or the choice of its ds) has left, from its elapsed time and fraction done.

A fit reports the share of its work done (``FitProgress.fraction``: its stages weighted by
their usual share of the evaluations, :mod:`core.gp.fit_run`); ``--latent-dim auto`` the
share of its fold × candidate fits done. :class:`RemainingTime` turns that into seconds left:
the stage's total is estimated as elapsed / fraction whenever the fraction grows, and the
time left counts down from it between two such updates (it never grows while nothing
happens, and is 0 once the estimate has run out). Each stage (the selection, then the fit)
is estimated on its own, from its own start — the run's start for the first, the last report
of the stage before for the next — since their speeds differ.
"""

from __future__ import annotations

import math


class RemainingTime:
    """Seconds left of the stage running, updated with every progress report."""

    def __init__(self) -> None:
        self._stage: str | None = None
        self._stage_started_s = 0.0
        self._last_report_s = 0.0
        self._fraction = 0.0
        self._total_s: float | None = None

    def update(self, stage: str, fraction: float, elapsed_s: float) -> float | None:
        """The seconds ``stage`` has left at ``elapsed_s`` (seconds since the run started).

        Args:
            stage: Which stage runs (e.g. ``"latent selection"``, ``"fit"``); a new one starts
                a new estimate, timed from the previous report (the run's start for the
                first).
            fraction: Its share done, in [0, 1].
            elapsed_s: Seconds since the run started.

        Returns:
            Seconds left, or ``None`` before the stage has reported any progress.
        """
        if stage != self._stage:
            self._stage, self._stage_started_s = stage, self._last_report_s
            self._fraction, self._total_s = 0.0, None
        self._last_report_s = elapsed_s
        in_stage_s = elapsed_s - self._stage_started_s
        if math.isfinite(fraction) and fraction > self._fraction:
            self._fraction = min(fraction, 1.0)
            self._total_s = in_stage_s / self._fraction
        if self._total_s is None:
            return None
        return max(0.0, self._total_s - in_stage_s)


def stage_of(phase: str) -> str:
    """The stage a progress event's ``phase`` belongs to: ``"latent selection"`` or ``"fit"``."""
    return "latent selection" if phase.startswith("latent selection") else "fit"
