"""What ``activetouch demo`` collects by default: the cushions, widely enough to reach inserts."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

from app.cli.demo import DEMO_DATASET_NAME, DemoOptions, DemoServer
from hardware.sim.materials import get_table
from hardware.sim.table_file import table_document


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


def test_a_table_file_gives_the_demo_its_objects_and_spread(tmp_path: Path) -> None:
    path = tmp_path / "shelf.json"
    path.write_text(json.dumps({**table_document(get_table("cushions")), "name": "shelf"}))
    server = DemoServer(DemoOptions(table_file=path, open_browser=False))
    assert server.settings.sim_table_file == path
    assert server.table == replace(get_table("cushions"), name="shelf")
    assert server.action_scale == 1.5
    assert server.dataset_name == f"{DEMO_DATASET_NAME} (shelf)"
