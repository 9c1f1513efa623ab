"""The dashboard's pure JavaScript helpers (frontend/js/lib), run by Node's test runner."""

from __future__ import annotations

import shutil
import subprocess

import pytest

from tests.e2e.conftest import ROOT


def test_frontend_unit_tests() -> None:
    """`node --test frontend/tests/`: ellipse, ETA, accuracy by touches, CSV, trajectories."""
    node = shutil.which("node")
    if node is None:
        pytest.fail("node is missing: the dashboard's unit tests need Node.js (>= 18)")
    completed = subprocess.run(
        [node, "--test", "tests/"],
        cwd=ROOT / "frontend",
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert completed.returncode == 0, completed.stdout + completed.stderr
    assert "# fail 0" in completed.stdout
