"""The time a fit has left, from its elapsed time and fraction done (app/services/remaining.py)."""

from __future__ import annotations

import pytest

from app.services.remaining import RemainingTime, stage_of


def test_the_time_left_is_estimated_from_the_pace_and_counts_down() -> None:
    remaining = RemainingTime()
    assert remaining.update("fit", 0.0, 0.0) is None  # no progress yet
    assert remaining.update("fit", 0.25, 10.0) == pytest.approx(30.0)  # 10 s for a quarter
    # Nothing new: it counts down, it does not grow while the stage runs.
    assert remaining.update("fit", 0.25, 20.0) == pytest.approx(20.0)
    assert remaining.update("fit", 0.25, 50.0) == 0.0  # ran out: 0, not negative
    assert remaining.update("fit", 0.5, 60.0) == pytest.approx(60.0)  # a new estimate
    assert remaining.update("fit", 1.0, 70.0) == 0.0


def test_each_stage_is_estimated_from_its_own_start() -> None:
    remaining = RemainingTime()
    # The first stage from the run's start, the next from the last report before it.
    assert remaining.update("latent selection", 0.5, 100.0) == pytest.approx(100.0)
    assert remaining.update("latent selection", 1.0, 190.0) == 0.0
    assert remaining.update("fit", 0.0, 195.0) is None
    assert remaining.update("fit", 0.5, 200.0) == pytest.approx(10.0)  # 10 s for half the fit


def test_a_fraction_that_does_not_grow_changes_nothing() -> None:
    remaining = RemainingTime()
    remaining.update("fit", 0.5, 10.0)
    assert remaining.update("fit", 0.4, 12.0) == pytest.approx(8.0)
    assert remaining.update("fit", float("nan"), 14.0) == pytest.approx(6.0)


def test_the_stage_of_a_phase() -> None:
    assert stage_of("latent selection: ds=2, fold 1/5") == "latent selection"
    assert stage_of("independent: joint") == "fit"
    assert stage_of("done") == "fit"


def test_the_cli_bar_shows_the_estimate_it_is_given() -> None:
    import time

    from rich.progress import Progress

    from app.cli.output import RemainingColumn

    progress = Progress(RemainingColumn())
    estimated = progress.add_task("fit", total=1.0, ends_at=time.monotonic() + 65.4)
    plain = progress.add_task("other", total=10)
    column = RemainingColumn()
    assert column.render(progress.tasks[estimated]).plain == "0:01:05"
    assert column.render(progress.tasks[plain]).plain == "-:--:--"  # Rich's own, no estimate
