"""What ``activetouch demo`` collects by default: the cushions, widely enough to reach inserts."""

from __future__ import annotations

from app.cli.demo import DEMO_DATASET_NAME, DemoOptions, DemoServer
from hardware.sim.materials import get_table


def test_the_demo_collects_the_cushions_at_their_own_action_spread() -> None:
    server = DemoServer(DemoOptions(port=0, viz_port=0, open_browser=False))
    assert server.options.table == "cushions"
    assert server.settings.sim_table == "cushions"
    assert server.options.touches_per_object == 100
    assert server.action_scale == get_table("cushions").action_std == 1.5
    # Its dataset has its own name, so a database from an older demo is not mistaken for it.
    assert server.dataset_name == f"{DEMO_DATASET_NAME} (cushions)"


def test_a_given_spread_or_table_wins() -> None:
    chosen = DemoServer(DemoOptions(table="paper", action_scale=0.5, open_browser=False))
    assert chosen.action_scale == 0.5
    paper = DemoServer(DemoOptions(table="paper", open_browser=False))
    assert paper.action_scale == 0.75
    default = DemoServer(DemoOptions(table="default", open_browser=False))
    assert default.dataset_name == DEMO_DATASET_NAME
