"""``activetouch collect``: touch objects on the rig (real ports or ``--sim``) into a training CSV.

::

    activetouch collect --sim --touches 20 --out data.csv
    activetouch collect --sim --object paper_cup --object stainless_cup --design shared \\
        --touches 16 --seed 3 --out cups.csv --json
    activetouch collect --turntable-port /dev/ttyACM0 --finger-port /dev/ttyUSB0 \\
        --tactile-port /dev/ttyUSB1 --object mug=0 --object glass=1 --touches 30 --out lab.csv

The touches come from :func:`app.services.collections.iter_collection`, the loop the server's
collection runs use, on a design of :mod:`core.evaluation.designs`: ``random`` draws a fresh action
x ~ N(0, σ² I) for every touch (the paper's design; object by object), ``shared`` touches every
object with the same M actions (a scrambled Sobol set of that prior; each object in its own
random order, so the drift is not learned as part of one action's response), which
lets the fit and the planner use the exact Kronecker path. ``adaptive`` touches each object
with the first half of its budget as ``random`` does, fits the model (ds = 2, ``fit``'s
defaults), then in rounds (:data:`app.services.collections.ADAPTIVE_ROUNDS`) touches every
object at the actions the planners would choose from the current model
(:func:`core.evaluation.adaptive_design.planner_round`), refitting between rounds; the same budget.
Without ``--design`` the design is ``adaptive``, or ``random`` where adaptive cannot run (fewer
than 3 touches), said in a note and in the summary's ``design_note``
(:func:`app.services.collections.default_design`).

Every touch records its placement in the CSV's ``placement`` column. ``--placements P`` places
each object P times and touches it N/P times in a row at each; by default P = N - N//4, three
placements for every four touches: half the touches in pairs, half placed anew
(:func:`app.services.collections.default_placements`): a recognition trial places its
object once and touches it several times, and the fit estimates from such runs how much one
placement (and the drift of its minutes) shifts a trial's touches alike (docs/calibration.md,
"Fix 1" and "Three placements for every four touches"). ``--placements N`` places every touch
anew. The adaptive design's stages each get placements of their own
(:func:`app.services.collections.stage_placements`).

Every touch also records when it was made in the CSV's ``time_s`` column: seconds from the start
of the collection's first touch to the start of this one, on the rig's clock (simulated seconds
with ``--sim``). The slow drift of the sensor and the room is shared by touches made close
together; ``fit`` estimates it from these times (:mod:`core.gp.drift_effect`). Its ``duration_s``
column records ``--duration`` on every row: an action means a trajectory of that duration, so
the model keeps it and every later touch to recognise with it (``evaluate --world rig``, the
server's trials) lasts as long.

Each touch is appended to the CSV (and, with ``--raw``, its raw tactile series to a raw-touch
file, JSON lines as ``docs/raw-touches.md`` describes, with the frame times and joint series
added) and flushed to disk the moment it is recorded. A device fault stops the collection: the rig
makes itself safe (feed hold, finger retracted or held), the files keep every touch recorded
before it, the message names the fault and the exit code is 1. Ctrl-C emergency-stops the rig,
keeps the files likewise and exits with 130. Exit code 2 is bad usage; every planned touch is
checked against the joint limits before the first one moves, so a touch the rig would refuse
is one too.
"""

from __future__ import annotations

import json
import os
import sys
import time
from collections import Counter
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, Literal, TextIO

import typer
from rich.markup import escape

from app.cli.options import AsJson, RigOptions, rig_options
from app.cli.output import fail
from app.cli.output import messages as console
from app.cli.rig import connected_rig, touch_actions

if TYPE_CHECKING:
    from app.rig.actions import TouchActions
    from app.rig.build import RigHandle
    from app.rig.collection import CollectedTouch
    from app.services.collections import AdaptiveRounds as NextRound
    from core.evaluation import CollectionDesign
    from hardware.rig import RigLease

#: Action designs of ``collect``.
DesignName = Literal["random", "shared", "adaptive"]


#: Exit code after Ctrl-C (128 + SIGINT), as a shell reports it.
INTERRUPTED_EXIT = 130


def parse_objects(specs: list[str], simulated: bool) -> list[tuple[str, int | None]]:
    """``NAME=SLOT`` (or, on a simulated rig, ``NAME`` alone) → (name, slot or None).

    Raises:
        typer.Exit: (code 2) a malformed item, a negative slot, or a name without a slot on a
            real rig.
    """
    parsed: list[tuple[str, int | None]] = []
    for spec in specs:
        name, separator, slot_text = spec.partition("=")
        name = name.strip()
        if not name:
            raise fail(f"--object {spec!r}: expected NAME=SLOT (the name is empty).", 2)
        if not separator:
            if not simulated:
                raise fail(
                    f"--object {spec!r}: give the slot as NAME=SLOT (only a simulated rig "
                    "knows where its objects stand).",
                    2,
                )
            parsed.append((name, None))
            continue
        try:
            slot = int(slot_text)
        except ValueError:
            raise fail(
                f"--object {spec!r}: the slot must be an integer, received {slot_text!r}.", 2
            ) from None
        if slot < 0:
            raise fail(f"--object {spec!r}: the slot must be ≥ 0, received {slot}.", 2)
        parsed.append((name, slot))
    return parsed


def resolve_slots(parsed: list[tuple[str, int | None]], handle: RigHandle) -> dict[str, int]:
    """Name → slot: slots given, or looked up on the simulated table; all checked on the rig.

    Without ``--object`` on a simulated rig, every object of its table is collected.

    Raises:
        typer.Exit: (code 2) an unknown simulated object, repeated names or slots, fewer than
            two objects, or a slot the turntable does not have.
    """
    from app.errors import BadInputError
    from app.services.collections import check_objects
    from hardware.errors import HardwareError

    table = handle.object_names
    if not parsed and table is not None:
        parsed = [(name, slot) for slot, name in enumerate(table)]
    pairs: list[tuple[str, int]] = []
    for name, slot in parsed:
        if slot is None:
            if table is None or name not in table:
                raise fail(
                    f"--object {name!r}: not on the simulated table; it holds "
                    f"{', '.join(table or [])} (or give NAME=SLOT).",
                    2,
                )
            slot = table.index(name)
        pairs.append((name, slot))
    try:
        check_objects(pairs)
    except BadInputError as exc:
        raise fail(f"--object: {exc.message}", 2) from None
    if len(pairs) < 2:
        raise fail(f"--object: a training set needs at least 2 objects, received {len(pairs)}.", 2)
    for name, slot in pairs:
        try:
            handle.rig.turntable.slot_angle(slot)
        except HardwareError as exc:
            raise fail(f"--object {name}={slot}: {exc}", 2) from None
    return dict(pairs)


def default_action_scale(options: RigOptions, given: float | None) -> float:
    """The design's spread: ``given``, else the simulated table's ``action_std``, else 1.0.

    A simulated table knows how far its objects' differences lie in the action space (a
    cushion's insert is reached only by deep presses); a real rig's objects are not known, so
    its default stays the unit spread.
    """
    if given is not None:
        return given
    if options.sim:
        from hardware.sim.materials import design_std

        return design_std(options.sim_table)
    return 1.0


def _stages(design: str, touches: int, placements: int | None) -> tuple[list[int], list[int]]:
    """Touches and placements per object of each stage of the collection.

    Raises:
        typer.Exit: (code 2) too few touches for the adaptive design, or ``placements`` outside
            what the stages allow.
    """
    from app.errors import BadInputError
    from app.services.collections import collection_stages
    from core.errors import InvalidInputError

    try:
        return collection_stages(design, touches, placements)
    except InvalidInputError as exc:
        raise fail(f"--touches: too few for --design adaptive ({exc})", 2) from None
    except BadInputError as exc:
        raise fail(f"--{exc.message}", 2) from None


def adaptive_plan(
    sizes: list[int],
    actions: TouchActions,
    handle: RigHandle,
    names: list[str],
    action_scale: float,
    seed: int,
) -> tuple[CollectionDesign, NextRound]:
    """The adaptive design's initial random half and the planner of its later rounds.

    Args:
        sizes: Touches per object of the initial design and of each round
            (:func:`app.services.collections.stage_sizes`).
    """
    from app.services.collections import AdaptiveRounds as NextRound

    plan = make_design("random", len(names), sizes[0], actions.action_dim, action_scale, seed)

    def check(design: CollectionDesign) -> None:
        check_plan(design, actions, handle, names)

    return plan, NextRound(names, sum(sizes), sizes[1:], seed, check)


def make_design(
    design: Literal["random", "shared"],
    n_objects: int,
    touches: int,
    action_dim: int,
    action_scale: float,
    seed: int,
) -> CollectionDesign:
    """The collection design: x ~ N(0, action_scale² I), fresh per touch or shared by all."""
    import numpy as np

    from core.evaluation import random_design, shared_design

    rng = np.random.default_rng(seed)
    mean, cov = np.zeros(action_dim), action_scale**2 * np.eye(action_dim)
    if design == "random":
        return random_design(n_objects, touches, mean, cov, rng)
    return shared_design(n_objects, touches, mean, cov, rng)


def check_plan(
    plan: CollectionDesign, actions: TouchActions, handle: RigHandle, names: list[str]
) -> None:
    """Check every planned touch against the joint limits before anything moves.

    Raises:
        typer.Exit: (code 2) a touch whose trajectory the rig would refuse.
    """
    from hardware.errors import UnsafeTrajectoryError
    from hardware.trajectories import check_trajectory

    joints = handle.rig.finger.joints
    for k, (obj, x) in enumerate(zip(plan.object_index, plan.actions, strict=True)):
        try:
            check_trajectory(actions.trajectory(x), actions.dt_s, joints)
        except UnsafeTrajectoryError as exc:
            raise fail(
                f"planned touch {k + 1} ({names[int(obj)]}, x = "
                f"{[round(float(v), 3) for v in x]}) would be refused: {exc} Use a smaller "
                "--action-scale or a longer --duration.",
                2,
            ) from None


def _open_new(path: Path, force: bool, option: str) -> TextIO:
    """Open ``path`` for writing; refuse to replace a file unless ``force``."""
    if path.exists() and not force:
        raise fail(f"{option} {path} exists; use --force to replace it.", 2)
    try:
        return path.open("w", newline="", encoding="utf-8")
    except OSError as exc:
        raise fail(f"{option}: cannot write {path}: {exc.strerror}", 2) from None


def _sync(stream: TextIO) -> None:
    """Flush to the OS and to disk: a crash loses at most the touch in flight."""
    stream.flush()
    os.fsync(stream.fileno())


@rig_options
def collect_command(
    options: RigOptions,
    out: Annotated[
        Path,
        typer.Option(
            "--out", help="Training CSV to write: object,placement,time_s,x_1..x_dx,y_1..y_dy."
        ),
    ],
    objects: Annotated[
        list[str] | None,
        typer.Option(
            "--object",
            help="NAME=SLOT (repeat). With --sim, NAME alone is an object of the simulated "
            "table; without --object, --sim collects every object on it.",
        ),
    ] = None,
    touches: Annotated[
        int, typer.Option("--touches", min=2, help="Touches per object (M for --design shared).")
    ] = 20,
    design: Annotated[
        DesignName | None,
        typer.Option(
            help="adaptive (default): half the touches random, then rounds at the actions the "
            "planners would choose from a model fitted to the touches so far; random: a fresh "
            "action x ~ N(0, scale² I) per touch (the paper's; the default's fallback with "
            "fewer than 3 touches); shared: the same M actions "
            "(scrambled Sobol) on every object (Kronecker fit)."
        ),
    ] = None,
    action_scale: Annotated[
        float | None,
        typer.Option(
            help="Standard deviation of each action component x_i (> 0). Default: with --sim "
            "the table's own spread (its action_std, which reaches where its objects differ), "
            "else 1.0."
        ),
    ] = None,
    seed: Annotated[
        int, typer.Option(help="Seed of the actions (and of the simulated world with --sim).")
    ] = 0,
    duration_s: Annotated[
        float, typer.Option("--duration", min=1.0, help="Touch duration in seconds.")
    ] = 14.4,
    raw: Annotated[
        Path | None,
        typer.Option(
            help="Also write each touch's raw tactile series (raw-touch JSON lines, "
            "docs/raw-touches.md) with its frame times and joint series."
        ),
    ] = None,
    force: Annotated[bool, typer.Option("--force", help="Replace existing output files.")] = False,
    placements: Annotated[
        int | None,
        typer.Option(
            "--placements",
            help="Place each object P times and touch it touches/P times in a row per "
            "placement (recorded in a 'placement' column; fit estimates from such runs how much "
            "one placement shifts a trial's touches alike). Default: P = --touches - --touches // "
            "4 (three placements for every four touches: half the touches in pairs, half "
            "placed anew); P = --touches places every touch anew.",
        ),
    ] = None,
    press_depth: Annotated[
        bool,
        typer.Option(
            "--press-depth/--no-press-depth",
            help="The press-depth component as a 7th action dimension (x_7 flexes the finger "
            "x_7 · 0.25° deeper while pressing, drawn like the others): the fit then learns how "
            "a placement's tilt moves the touches (docs/method.md (S4)). --no-press-depth: the "
            "six DMP components alone.",
        ),
    ] = True,
    as_json: AsJson = False,
) -> None:
    """Collect a training set on the rig: touch each object, write the training CSV."""
    options.check()
    sim, sim_transport = options.sim, options.sim_transport
    if action_scale is not None and not action_scale > 0:
        raise fail(f"--action-scale: must be > 0, received {action_scale}.", 2)
    design_note = None
    if design is None:
        from app.services.collections import default_design

        design, design_note = default_design(touches)
    sizes, stages = _stages(design, touches, placements)
    placements = sum(stages)
    action_scale = default_action_scale(options, action_scale)
    parsed = parse_objects(objects or [], simulated=sim)
    if not sim and len(parsed) < 2:
        raise fail("give at least two --object NAME=SLOT (or use --sim).", 2)
    for path, option in ((out, "--out"), (raw, "--raw")):
        if path is not None and path.exists() and not force:
            raise fail(f"{option} {path} exists; use --force to replace it.", 2)
    actions = touch_actions(duration_s, press_depth)
    with connected_rig(options, "activetouch collect") as (handle, lease):
        slots = resolve_slots(parsed, handle)
        next_round = None
        if design == "adaptive":
            plan, next_round = adaptive_plan(
                sizes, actions, handle, list(slots), action_scale, seed
            )
        else:
            plan = make_design(design, len(slots), touches, actions.action_dim, action_scale, seed)
        check_plan(plan, actions, handle, list(slots))
        if design_note is not None:
            console.print(f"[yellow]note:[/yellow] {escape(design_note)}.")
        channels = list(handle.rig.tactile.config.channel_names)
        summary: dict[str, Any] = {
            "out": str(out),
            "raw": None if raw is None else str(raw),
            "rig": f"simulated ({sim_transport})" if sim else "serial",
            "design": design,
            "design_note": design_note,
            "action_scale": action_scale,
            "seed": seed,
            "duration_s": duration_s,
            "action_dim": actions.action_dim,
            "observation_dim": len(channels),
            "channels": channels,
            "planned": touches * len(slots),
            "placements": placements,
        }
        recorded, error, code, seconds = _collect(
            handle, lease, actions, slots, plan, out, raw, force, stages, next_round, seed
        )
        summary["rig_state"] = str(handle.rig.state)
    counts = Counter(touch.object_name for touch in recorded)
    summary.update(
        recorded=len(recorded),
        complete=error is None,
        error=error,
        seconds=seconds,
        objects=[{"name": n, "slot": s, "touches": counts[n]} for n, s in slots.items()],
        # What read_training_csv (and fit) accept: 2 objects or more, each touched twice or more.
        fit_ready=len(counts) >= 2 and min(counts.values()) >= 2,
    )
    _report(summary, as_json)
    if code:
        raise typer.Exit(code=code)


def _collect(
    handle: RigHandle,
    lease: RigLease,
    actions: TouchActions,
    slots: dict[str, int],
    plan: CollectionDesign,
    out: Path,
    raw: Path | None,
    force: bool,
    placements: list[int],
    next_round: NextRound | None = None,
    seed: int = 0,
) -> tuple[list[CollectedTouch], str | None, int, float]:
    """Run the collection into the files; return the touches, the error, exit code, seconds.

    ``placements``: placements per object of each stage (the plan, then each round).
    """
    from app.cli.output import progress_bar
    from app.documents.raw_touches import raw_touch_from_record, raw_touch_line
    from app.documents.training_csv import TrainingCsvWriter
    from app.services.collections import iter_stages
    from app.services.rig import motion_series
    from core.errors import InvalidInputError
    from hardware.errors import HardwareError

    recorded: list[CollectedTouch] = []
    error: str | None = None
    code = 0
    started = time.perf_counter()
    csv_file = _open_new(out, force, "--out")
    raw_file = None if raw is None else _open_new(raw, force, "--raw")
    try:
        writer = TrainingCsvWriter(
            csv_file,
            actions.action_dim,
            len(handle.rig.tactile.config.channel_names),
            placements=True,
            times=True,
            duration_s=actions.duration_s,
        )
        _sync(csv_file)
        with progress_bar() as bar:
            total = plan.n_touches if next_round is None else len(slots) * next_round.touches
            task = bar.add_task("collect", total=total, status="connected")
            try:
                touches = iter_stages(
                    lease,
                    actions,
                    slots,
                    plan,
                    placements,
                    next_round,
                    seed,
                    lambda: bar.update(task, status="fitting the model to plan the next round"),
                )
                for touch in touches:
                    writer.write(
                        touch.object_name,
                        touch.action,
                        touch.record.observation,
                        touch.placement,
                        touch.time_s,
                    )
                    _sync(csv_file)
                    if raw_file is not None:
                        line = raw_touch_line(
                            touch.object_name,
                            touch.action,
                            raw_touch_from_record(touch.record),
                            index=touch.index,
                            placement=touch.placement,
                            time_s=touch.time_s,
                            duration_s=actions.duration_s,
                            observation=touch.record.observation.tolist(),
                            **motion_series(touch.record),
                        )
                        raw_file.write(json.dumps(line) + "\n")
                        _sync(raw_file)
                    recorded.append(touch)
                    bar.update(
                        task,
                        completed=len(recorded),
                        status=f"{escape(touch.object_name)} (slot {touch.slot:d})",
                    )
            except (HardwareError, InvalidInputError) as exc:
                error, code = f"{type(exc).__name__}: {exc}", 1
                bar.update(task, status="[red]stopped[/red]")
            except KeyboardInterrupt:
                handle.rig.estop("collection interrupted (Ctrl-C)")
                error, code = (
                    "interrupted (Ctrl-C); the rig was emergency-stopped",
                    INTERRUPTED_EXIT,
                )
                bar.update(task, status="[red]interrupted[/red]")
    finally:
        csv_file.close()
        if raw_file is not None:
            raw_file.close()
    return recorded, error, code, time.perf_counter() - started


def _report(summary: dict[str, Any], as_json: bool) -> None:
    """The summary: JSON on stdout with ``--json``, and a message on stderr."""
    if as_json:
        sys.stdout.write(json.dumps(summary) + "\n")
    kept = f"{summary['recorded']} of {summary['planned']} touches"
    if summary["error"] is not None:
        console.print(f"[red]collection stopped:[/red] {escape(str(summary['error']))}")
        console.print(
            f"the rig is {escape(str(summary['rig_state']))}; kept {escape(kept)} in "
            f"{escape(str(summary['out']))}"
            + (
                ""
                if summary["fit_ready"]
                else " (not yet a training set: it needs 2 objects or more, each touched twice "
                "or more)"
            )
        )
        return
    if not as_json:
        console.print(
            f"collected {escape(kept)} of {len(summary['objects']):d} objects in "
            f"{summary['seconds']:.1f} s → {escape(str(summary['out']))}"
        )
