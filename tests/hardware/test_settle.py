"""The rest before each touch (``RigConfig.settle_s``): every touch starts from a rested sensor.

A heated fingertip's skin cools at every contact and recovers over seconds. Without the rest the
first touch of a session (rested) and the touches right after another one start from different
skin temperatures, so their thermal channels differ though the object and action are the same.
"""

from __future__ import annotations

import numpy as np
import pytest

from hardware.clock import VirtualClock
from hardware.errors import ConfigurationError, EmergencyStopped
from hardware.frames import CHANNELS
from hardware.records import TouchRecord
from hardware.rig import Rig, RigConfig, RigState
from hardware.sim.rig import in_process_rig
from hardware.teaching import teaching_trajectory

TEMPERATURE = CHANNELS.index("temperature_c")


def three_touches(settle_s: float) -> tuple[list[TouchRecord], list[float]]:
    """Three equal 4 s touches of the ceramic mug on a fresh rig; the records and the clock
    time between the end of one touch and the end of the next."""
    config = RigConfig(control_period_s=0.04, settle_s=settle_s)
    sim = in_process_rig(["paper_cup", "ceramic_mug"], seed=1, rig_config=config)
    trajectory = teaching_trajectory(dt_s=0.04, duration_s=4.0)
    records, ends = [], []
    try:
        with sim.rig.acquire("test") as lease:
            lease.connect()
            lease.move_to_slot(1)
            for _ in range(3):
                records.append(lease.touch(trajectory))
                ends.append(sim.devices.clock.now())
    finally:
        sim.close()
    return records, list(np.diff(ends))


def test_every_touch_starts_from_the_rested_skin_temperature() -> None:
    records, gaps_s = three_touches(RigConfig().settle_s)
    start_c = [r.tactile[0, TEMPERATURE] for r in records]
    spread_c = [r.tactile[:, TEMPERATURE].std() for r in records]
    assert max(start_c) - min(start_c) < 0.05
    np.testing.assert_allclose(spread_c, spread_c[0], rtol=0.05)
    assert min(gaps_s) >= RigConfig().settle_s + 4.0


def test_each_touch_records_when_it_started_on_the_rig_clock() -> None:
    """``started_s`` is the rig clock's time at the trajectory's start: consecutive touches
    start at least the rest and the touch apart (and not much more: the same clock)."""
    config = RigConfig()
    records, _ = three_touches(config.settle_s)
    started_s = [r.started_s for r in records]
    assert all(s is not None and np.isfinite(s) for s in started_s)
    gaps_s = np.diff(np.asarray(started_s, dtype=np.float64))
    assert np.all(gaps_s >= config.settle_s + records[0].duration_s)
    assert gaps_s.max() < config.settle_s + records[0].duration_s + 1.0


def test_without_the_rest_a_touch_right_after_another_starts_cooler() -> None:
    records, _ = three_touches(0.0)
    start_c = [r.tactile[0, TEMPERATURE] for r in records]
    spread_c = [r.tactile[:, TEMPERATURE].std() for r in records]
    assert start_c[1] < start_c[0] - 0.5  # the skin has not recovered from touch 1
    assert spread_c[1] < 0.7 * spread_c[0]


def test_a_rig_rested_longer_does_not_wait_again() -> None:
    config = RigConfig(control_period_s=0.04)
    sim = in_process_rig(["paper_cup"], seed=2, rig_config=config)
    trajectory = teaching_trajectory(dt_s=0.04, duration_s=4.0)
    clock = sim.devices.clock
    try:
        with sim.rig.acquire("test") as lease:
            lease.connect()
            clock.sleep(config.settle_s + 1.0)
            before = clock.now()
            lease.touch(trajectory)
            assert clock.now() - before < config.settle_s
    finally:
        sim.close()


class StoppingClock(VirtualClock):
    """A virtual clock that presses the rig's emergency stop once it passes ``stop_at_s``."""

    def __init__(self) -> None:
        super().__init__()
        self.rig: Rig | None = None
        self.stop_at_s = np.inf

    def sleep(self, duration_s: float) -> None:
        super().sleep(duration_s)
        if self.rig is not None and self.now() >= self.stop_at_s and not self.rig.estopped:
            self.rig.estop("operator pressed stop")


def test_an_emergency_stop_ends_the_rest() -> None:
    clock = StoppingClock()
    sim = in_process_rig(["paper_cup"], seed=3, clock=clock)
    clock.rig = sim.rig
    try:
        with sim.rig.acquire("test") as lease:
            lease.connect()
            clock.stop_at_s = clock.now() + 5.0  # a quarter into the rest
            with pytest.raises(EmergencyStopped):
                lease.touch(teaching_trajectory(dt_s=0.02, duration_s=4.0))
            assert clock.now() < clock.stop_at_s + 0.5
            assert sim.rig.state is RigState.ESTOPPED
    finally:
        sim.close()


@pytest.mark.parametrize("settle_s", [-1.0, float("nan"), float("inf")])
def test_the_rest_must_be_a_finite_non_negative_time(settle_s: float) -> None:
    with pytest.raises(ConfigurationError, match="settle_s"):
        RigConfig(settle_s=settle_s)
