"""The CLI starts light: commands import their stack (web, DB, viser, numpy) when they run."""

from __future__ import annotations

import inspect
import json
import subprocess
import sys
from pathlib import Path
from typing import Any, get_args

import pytest
from typer.testing import CliRunner

from app.cli.bench import bench_command
from app.cli.demo import demo_command
from app.cli.main import app
from app.cli.options import SimulationName
from app.cli.serve import serve_command
from app.rig.build import SimulationMode
from tests.app.conftest import experiment1_csv

runner = CliRunner()
HEAVY = ("fastapi", "sqlalchemy", "alembic", "uvicorn", "viser", "httpx", "bench", "matplotlib")
PROJECT = Path(__file__).resolve().parents[2]

PROBE = """
import json, sys
from app.cli.main import app
loaded_at_start = sorted(m for m in {heavy!r} + ("numpy", "scipy") if m in sys.modules)
for args in {commands!r}:
    try:
        app(args)
    except SystemExit as exit:
        assert not exit.code, (args, exit.code)
print(json.dumps({{"start": loaded_at_start,
                  "after": sorted(m for m in {heavy!r} if m in sys.modules)}}))
"""


def probe(commands: list[list[str]]) -> dict[str, list[str]]:
    """Run CLI commands in a fresh interpreter; which heavy modules were imported."""
    code = PROBE.format(heavy=HEAVY, commands=commands)
    done = subprocess.run(
        [sys.executable, "-c", code], cwd=PROJECT, capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0, done.stderr
    result: dict[str, list[str]] = json.loads(done.stdout.splitlines()[-1])
    return result


def test_help_and_fit_import_neither_the_web_stack_nor_numpy_at_start(tmp_path: Path) -> None:
    data = tmp_path / "exp1.csv"
    data.write_text(experiment1_csv(seed=0, touches_per_object=4))
    loaded = probe(
        [
            ["--help"],
            ["fit", "--help"],
            ["collect", "--help"],
            ["export", "--help"],
            ["rig", "status", "--help"],
            [
                "fit",
                str(data),
                "--latent-dim",
                "1",
                "--restarts",
                "0",
                "--out",
                str(tmp_path / "m.json"),
            ],
        ]
    )
    assert loaded["start"] == []  # importing app.cli.main: typer and rich only
    assert loaded["after"] == []  # a fit needs numpy and the core, not the web stack
    assert json.loads((tmp_path / "m.json").read_text())["format"] == "activetouch-model/1"


@pytest.mark.parametrize(
    ("name", "function", "option"),
    [
        ("serve", serve_command, "--database-url"),
        ("demo", demo_command, "--viz-port"),
        ("bench", bench_command, "--quick"),
    ],
)
def test_forwarded_commands_keep_their_help_and_options(
    name: str, function: Any, option: str
) -> None:
    registered = {command.name: command for command in app.registered_commands}
    doc = inspect.getdoc(function)
    assert doc is not None
    assert " ".join((registered[name].help or "").split()) == " ".join(doc.split("\n\n")[0].split())
    shown = runner.invoke(app, [name, "--help"])
    assert shown.exit_code == 0, shown.output
    assert option in shown.output
    assert f"Usage: activetouch {name} [OPTIONS]" in shown.output  # its own usage line
    wrong = runner.invoke(app, [name, "--no-such-option"])
    assert wrong.exit_code == 2
    assert "No such option" in wrong.output


def test_a_forwarded_command_checks_its_values() -> None:
    result = runner.invoke(app, ["serve", "--hardware", "robot"])
    assert result.exit_code == 2
    assert "expected 'mock' or 'serial'" in result.output


def test_rig_transport_names_are_the_simulation_modes() -> None:
    assert set(get_args(SimulationName)) == {mode.value for mode in SimulationMode}
