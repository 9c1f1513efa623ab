"""The scripted example drives trials through the REST API alone and names the right objects."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

from tests.app.conftest import TestClient

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "scripted_trial.py"


def load_example() -> ModuleType:
    spec = importlib.util.spec_from_file_location("scripted_trial", EXAMPLE)
    assert spec is not None
    assert spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules["scripted_trial"] = module
    spec.loader.exec_module(module)
    return module


def test_example_end_to_end_with_a_fit(client: TestClient) -> None:
    """Upload the robot's touches, fit, recognise: the whole pattern through the API."""
    example = load_example()
    trials = example.run(client, trials_per_object=1, seed=0)
    assert [t["result"]["object"] for t in trials] == ["O1", "O2", "O3", "O4"]
