"""The scripted example drives trials through the REST API alone and names the right objects."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

from tests.app.conftest import TestClient, import_model

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "scripted_trial.py"


def load_example() -> ModuleType:
    spec = importlib.util.spec_from_file_location("scripted_trial", EXAMPLE)
    assert spec is not None
    assert spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules["scripted_trial"] = module
    spec.loader.exec_module(module)
    return module


def test_example_names_every_object(client: TestClient) -> None:
    example = load_example()
    model_id = import_model(client)
    trials = example.run(client, trials_per_object=1, seed=0, model_id=model_id)
    assert [t["target"] for t in trials] == ["O1", "O2", "O3", "O4"]
    assert all(t["status"] == "completed" for t in trials)
    assert [t["result"]["object"] for t in trials] == ["O1", "O2", "O3", "O4"]
