"""Options that more than one ``activetouch`` command takes, written once.

The rig connection options (three ports, or ``--sim`` with its transport, seed and table) are
the fields of :class:`RigOptions`; :func:`rig_options` gives a command all of them and hands it
one :class:`RigOptions`. ``--table`` and ``--table-file`` are also taken alone by the commands
that simulate a rig without opening one (``evaluate``, ``paper exp2``, ``demo``):
:func:`table_choice` reads them.
"""

from __future__ import annotations

import functools
import inspect
from collections.abc import Callable
from dataclasses import dataclass, fields
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, Literal, TypeVar, get_type_hints

import typer

from app.cli.output import fail

if TYPE_CHECKING:  # the drivers are imported when a command runs, not when the CLI starts
    from app.rig.build import RigHandle
    from hardware.sim.materials import Table

PlacementOption = Annotated[
    str,
    typer.Option(
        help="Rig and model-world trials: place the object once per trial (trial) or anew "
        "before every touch (touch), as a collection does.",
    ),
]
"""``--placement``: see :class:`app.evaluation.spec.EvaluationSpec` (``trial`` by default)."""

TrialLikelihoodOption = Annotated[
    str,
    typer.Option(
        help="How the object posterior scores a trial's touches: joint (one Gaussian with the "
        "GP's full covariance, the default) or independent (a product over touches).",
    ),
]
"""``--trial-likelihood``: see :class:`app.evaluation.spec.EvaluationSpec`."""

PlanUnderOption = Annotated[
    str,
    typer.Option(
        help="The belief the active policy plans under: objects (the mixture over the learned "
        "objects the object posterior implies, the default) or gaussian (the paper's).",
    ),
]
"""``--plan-under``: see :class:`app.evaluation.spec.EvaluationSpec`."""

#: How a simulated rig is wired (the values of :class:`app.rig.build.SimulationMode`).
SimulationName = Literal["in-process", "pty"]

TableName = Annotated[
    str | None,
    typer.Option(
        "--table",
        help="Simulated rig: a named table of objects (default, paper, lookalike_cups, "
        "cushions, textures; see docs/simulation.md).",
    ),
]
TableFile = Annotated[
    Path | None,
    typer.Option(
        "--table-file",
        help="Simulated rig: your own objects, a JSON or TOML file (docs/simulation.md, "
        "'Your own objects'); instead of --table.",
        dir_okay=False,
    ),
]
AsJson = Annotated[bool, typer.Option("--json", help="Print a JSON document on stdout.")]


def table_choice(table: str | None, table_file: Path | None) -> str | Table | None:
    """The table ``--table`` / ``--table-file`` ask for: the name, the file's table, or ``None``.

    Raises:
        typer.Exit: (code 2) both options given, or a table file that cannot be used (the
            message names the object and the field).
    """
    if table_file is None:
        return table
    if table is not None:
        raise fail("give --table or --table-file, not both.")
    from hardware.sim.table_file import TableFileError, read_table_file

    try:
        return read_table_file(table_file)
    except TableFileError as exc:
        raise fail(f"--table-file {exc}") from None


@dataclass(frozen=True)
class RigOptions:
    """Where the rig is: three serial ports, or a simulation. Each field is one option.

    Attributes:
        turntable_port: GRBL controller port.
        finger_port: Dynamixel bus port.
        tactile_port: Tactile sensor port.
        sim: Simulate the rig instead.
        sim_transport: ``in-process`` or ``pty``.
        seed: Seed of the simulated world.
        table: Named table of the simulated rig (the default table when neither it nor
            ``table_file`` is given).
        table_file: A table file of the simulated rig.
        settle_s: Rest before each touch (:attr:`hardware.rig.RigConfig.settle_s`).
    """

    turntable_port: Annotated[
        str | None,
        typer.Option(
            "--turntable-port",
            envvar="ACTIVETOUCH_TURNTABLE_PORT",
            help="GRBL port, 115200 baud.",
        ),
    ] = None
    finger_port: Annotated[
        str | None,
        typer.Option(
            "--finger-port", envvar="ACTIVETOUCH_FINGER_PORT", help="Dynamixel bus port, 1 Mbaud."
        ),
    ] = None
    tactile_port: Annotated[
        str | None,
        typer.Option(
            "--tactile-port",
            envvar="ACTIVETOUCH_TACTILE_PORT",
            help="Tactile sensor, 460800 baud.",
        ),
    ] = None
    sim: Annotated[
        bool,
        typer.Option(
            "--sim",
            help="Use a simulated rig (its table: --table or --table-file; by default the "
            "paper's four cups in slots 0-3, then a ceramic mug, a wooden block and a foam "
            "sponge).",
        ),
    ] = False
    sim_transport: Annotated[
        SimulationName,
        typer.Option(
            "--sim-transport",
            help="in-process: simulated devices called directly; pty: emulators on "
            "pseudo-terminals, driven through pyserial.",
        ),
    ] = "in-process"
    seed: Annotated[int, typer.Option("--seed", help="Seed of the simulated world.")] = 0
    table: TableName = None
    table_file: TableFile = None
    settle_s: Annotated[
        float,
        typer.Option(
            "--settle",
            min=0.0,
            envvar="ACTIVETOUCH_SETTLE_S",
            help="Seconds the finger rests before each touch, counted from the end of the last "
            "(or from connecting), so that a heated sensor's skin recovers its temperature and "
            "every touch starts alike; set it to your sensor's recovery (0: no rest).",
        ),
    ] = 20.0

    @cached_property
    def sim_table(self) -> Table:
        """The simulated rig's table (exit 2 for an unknown name or an unusable file)."""
        from hardware.errors import ConfigurationError
        from hardware.sim.materials import DEFAULT_TABLE_NAME, get_table

        chosen = table_choice(self.table, self.table_file)
        try:
            return get_table(DEFAULT_TABLE_NAME if chosen is None else chosen)
        except ConfigurationError as exc:
            raise fail(f"--table: {exc}") from None

    def check(self) -> None:
        """Exit 2 when a real rig lacks a port or is given a table, or the table is unusable."""
        if self.sim:
            self.sim_table  # noqa: B018 - reads and checks the table now
            return
        if self.table is not None or self.table_file is not None:
            raise fail("--table and --table-file describe a simulated rig: add --sim.")
        from app.rig.build import missing_ports

        missing = missing_ports(self.turntable_port, self.finger_port, self.tactile_port)
        if missing:
            options = ", ".join(f"--{name}-port" for name in missing)
            raise fail(f"missing {options} (or use --sim).")

    def open(self) -> RigHandle:
        """Build the rig (not connected yet)."""
        from app.rig.build import RigPorts, SimulationMode, open_rig
        from hardware.rig import RigConfig

        self.check()
        if self.sim:
            return open_rig(
                simulate=SimulationMode(self.sim_transport),
                table=self.sim_table,
                seed=self.seed,
                rig_config=RigConfig(settle_s=self.settle_s),
            )
        assert self.turntable_port is not None
        assert self.finger_port is not None
        assert self.tactile_port is not None
        return open_rig(
            ports=RigPorts(self.turntable_port, self.finger_port, self.tactile_port),
            rig_config=RigConfig(settle_s=self.settle_s),
        )


Command = TypeVar("Command", bound=Callable[..., Any])


def rig_options(command: Command) -> Command:
    """Give a command every :class:`RigOptions` option; it receives them as one parameter.

    The command declares a parameter annotated ``RigOptions``; typer sees the options in its
    place (each field of :class:`RigOptions`, with its declaration). A command that declares one
    of those options itself (``collect``'s ``--seed`` also seeds its actions) keeps its own
    declaration, and the value fills the :class:`RigOptions` field too.
    """
    signature = inspect.signature(command)
    hints = get_type_hints(command, include_extras=True)
    (target,) = [name for name, hint in hints.items() if hint is RigOptions]
    option_hints = get_type_hints(RigOptions, include_extras=True)
    own = [
        p.replace(annotation=hints.get(name, p.annotation))
        for name, p in signature.parameters.items()
        if name != target
    ]
    own_names = {p.name for p in own}
    added = [
        inspect.Parameter(
            f.name,
            inspect.Parameter.KEYWORD_ONLY,
            default=f.default,
            annotation=option_hints[f.name],
        )
        for f in fields(RigOptions)
        if f.name not in own_names
    ]

    @functools.wraps(command)
    def wrapper(**kwargs: Any) -> Any:
        options = RigOptions(**{f.name: kwargs[f.name] for f in fields(RigOptions)})
        passed = {name: value for name, value in kwargs.items() if name in own_names}
        return command(**passed, **{target: options})

    parameters = [
        *(p for p in own if p.kind is not inspect.Parameter.KEYWORD_ONLY),
        *(p for p in own if p.kind is inspect.Parameter.KEYWORD_ONLY),
        *added,
    ]
    del wrapper.__wrapped__  # typer reads the signature below, not the command's
    wrapper.__signature__ = signature.replace(  # type: ignore[attr-defined]
        parameters=parameters
    )
    wrapper.__annotations__ = {
        **{p.name: p.annotation for p in parameters},
        "return": hints.get("return"),
    }
    return wrapper  # type: ignore[return-value]
