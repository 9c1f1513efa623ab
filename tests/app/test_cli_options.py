"""The rig options written once: every command that opens a rig gets all of them."""

from __future__ import annotations

from typing import Annotated

import typer
from typer.testing import CliRunner

from app.cli.main import app
from app.cli.options import RigOptions, rig_options

runner = CliRunner()


def test_a_command_gets_every_rig_option_and_may_share_one() -> None:
    seen: list[tuple[RigOptions, int, str]] = []
    toy = typer.Typer()

    @toy.command()
    @rig_options
    def command(
        name: Annotated[str, typer.Argument()],
        rig: RigOptions,
        seed: Annotated[int, typer.Option(help="Seed of this command and of the world.")] = 0,
    ) -> None:
        seen.append((rig, seed, name))

    result = runner.invoke(
        toy, ["cup", "--sim", "--seed", "5", "--table", "paper", "--sim-transport", "pty"]
    )
    assert result.exit_code == 0, result.output
    assert seen == [(RigOptions(sim=True, seed=5, table="paper", sim_transport="pty"), 5, "cup")]


def test_every_rig_command_takes_the_same_rig_options() -> None:
    from typer.main import get_command

    options = {"--turntable-port", "--finger-port", "--tactile-port", "--sim", "--sim-transport"}
    options |= {"--seed", "--table", "--table-file", "--settle"}
    group = get_command(app)
    rig = group.commands["rig"]  # type: ignore[attr-defined]
    commands = [rig.commands[name] for name in ("status", "home", "slot", "touch", "estop")]
    commands.append(group.commands["collect"])  # type: ignore[attr-defined]
    for command in commands:
        names = {opt for param in command.params for opt in param.opts}
        assert options <= names, (command.name, options - names)


def test_the_rest_before_a_touch_reaches_the_rig_from_the_options_and_the_server() -> None:
    from app.config import Settings
    from app.services.rig import RigService

    handle = RigOptions(sim=True, settle_s=3.5).open()
    try:
        assert handle.rig.config.settle_s == 3.5
    finally:
        handle.close()
    refused = runner.invoke(app, ["rig", "status", "--sim", "--settle", "-1"])
    assert refused.exit_code == 2
    assert "--settle" in " ".join(refused.output.split())
    service = RigService(Settings(hardware="mock", settle_s=0.0), None, None)  # type: ignore[arg-type]
    handle = service.handle()  # builds the rig from the settings alone
    try:
        assert handle.rig.config.settle_s == 0.0
    finally:
        handle.close()
