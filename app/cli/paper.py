"""``activetouch paper``: the paper's experiments, reproduced (:mod:`app.paper`).

Like every command module here it imports only typer and rich at start; each command imports its
stack when it runs.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Annotated, cast

import typer
from rich.markup import escape

from app.cli.options import (
    PlacementOption,
    TableFile,
    TableName,
    TrialLikelihoodOption,
    table_choice,
)
from app.cli.output import fail, progress_bar
from app.cli.output import messages as stderr
from app.cli.output import results as stdout

paper_app = typer.Typer(help="Reproduce the paper's experiments.", no_args_is_help=True)


@paper_app.command("exp1")
def paper_exp1(
    seeds: Annotated[int, typer.Option(min=1, help="Data seeds (fits).")] = 10,
    trials: Annotated[int, typer.Option(min=1, help="Trials per object per seed.")] = 5,
    steps: Annotated[int, typer.Option(min=1, help="T")] = 10,
    noise_std: Annotated[float, typer.Option(help="0.1 (std) or 0.316 (variance 0.1)")] = 0.1,
    restarts: Annotated[int, typer.Option(min=0, help="Random restarts per fit.")] = 4,
    trial_likelihood: TrialLikelihoodOption = "joint",
    as_json: Annotated[bool, typer.Option("--json", help="Print the figures as JSON.")] = False,
) -> None:
    """Experiment 1 end to end: manifold, random-latent baseline, recognition; vs the paper."""
    from app.paper.exp1 import run_experiment1
    from core.errors import CoreError
    from core.recognition import TRIAL_LIKELIHOODS

    if trial_likelihood not in TRIAL_LIKELIHOODS:
        raise fail(
            f"--trial-likelihood: {trial_likelihood!r} is not one of {list(TRIAL_LIKELIHOODS)}."
        )

    try:
        with progress_bar() as bar:
            task = bar.add_task("experiment 1", total=seeds, status="")

            def report(message: str, done: int) -> None:
                bar.update(task, completed=done, status=message)

            figures = run_experiment1(
                seeds=seeds,
                trials_per_object=trials,
                max_steps=steps,
                noise_std=noise_std,
                restarts=restarts,
                trial_likelihood=trial_likelihood,
                progress=report,
            )
    except CoreError as exc:
        raise fail(str(exc)) from None
    if as_json:
        sys.stdout.write(json.dumps(figures.to_dict()) + "\n")
    else:
        stdout.print(figures.table())


@paper_app.command("exp2")
def paper_exp2(
    table: TableName = None,
    table_file: TableFile = None,
    touches: Annotated[int, typer.Option(min=2, help="Random-design touches per object.")] = 100,
    action_scale: Annotated[
        float | None,
        typer.Option(
            min=0.01,
            help="Standard deviation of each action component (default: the table's own, "
            "`rig status --sim --table NAME`; the paper's cups 0.75, so active touches at the "
            "corner of the action box stay within the simulated servos' load limit).",
        ),
    ] = None,
    trials: Annotated[
        int, typer.Option(min=1, help="Trials per object, policy and observation source.")
    ] = 25,
    steps: Annotated[int, typer.Option(min=1, help="T")] = 15,
    restarts: Annotated[int, typer.Option(min=0, help="Random restarts of the fit.")] = 2,
    optimizer: Annotated[str, typer.Option(help="Fit optimiser: de (the paper's) or lbfgs.")] = (
        "de"
    ),
    sources: Annotated[
        str, typer.Option(help="Observation sources, comma-separated: model (the paper's), rig.")
    ] = "model,rig",
    seed: Annotated[int, typer.Option(min=0, help="Seed of design, world, fit and trials.")] = 0,
    workers: Annotated[
        int | None, typer.Option(min=1, help="Dask worker processes for the trials.")
    ] = None,
    placement: PlacementOption = "trial",
    figures: Annotated[
        Path | None, typer.Option(help="Write the PNG figures into this directory.")
    ] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print the evaluation reports.")] = False,
) -> None:
    """Experiment 2 on the simulated rig: collect, fit (ds = 2), active vs passive; vs the paper."""
    from app.errors import BadInputError, DeviceUnavailableError
    from app.evaluation.spec import PLACEMENTS, Placement
    from app.evaluation.worlds import table_objects
    from app.paper.exp2 import SOURCES, Experiment2Settings, run_experiment2, write_figures
    from core.errors import CoreError
    from hardware.errors import HardwareError

    chosen = tuple(s.strip() for s in sources.split(",") if s.strip())
    unknown = [s for s in chosen if s not in SOURCES]
    if unknown or not chosen:
        raise fail(f"--sources: {unknown or chosen} not sources; choose from {list(SOURCES)}.")
    if placement not in PLACEMENTS:
        raise fail(f"--placement: {placement!r} is not one of {list(PLACEMENTS)}.")
    if optimizer not in ("de", "lbfgs"):
        raise fail(f"--optimizer: {optimizer!r} is not one of [de, lbfgs].")
    chosen_table = table_choice(table, table_file) or "paper"  # the paper's four cups
    try:
        table_objects(chosen_table)
    except BadInputError as exc:
        raise fail(str(exc)) from None
    settings = Experiment2Settings(
        table=chosen_table,
        touches_per_object=touches,
        action_scale=action_scale,
        trials_per_target=trials,
        steps=steps,
        restarts=restarts,
        optimizer=optimizer,
        sources=chosen,
        seed=seed,
        workers=workers,
        placement=cast(Placement, placement),
    )
    try:
        with progress_bar() as bar:
            task = bar.add_task("experiment 2", total=1000, status="")

            def report(message: str, fraction: float) -> None:
                bar.update(task, completed=int(1000 * fraction), status=escape(message))

            result = run_experiment2(settings, progress=report)
        written = [] if figures is None else write_figures(result, figures)
    except (CoreError, BadInputError) as exc:
        raise fail(str(exc)) from None
    except DeviceUnavailableError as exc:  # the rig failed in a trial, other than by a refusal
        stderr.print(f"[red]error:[/red] {escape(exc.message)}")
        raise typer.Exit(code=1) from None
    except HardwareError as exc:  # the collection's touch refused (a refused trial goes on)
        stderr.print(
            f"[red]error:[/red] the simulated rig stopped: {escape(type(exc).__name__)}: "
            f"{escape(str(exc))} (a smaller --action-scale keeps the touches shallower)"
        )
        raise typer.Exit(code=1) from None
    for path in written:
        stderr.print(f"wrote {escape(str(path))}")
    stderr.print(f"experiment 2: {result.seconds:.1f} s wall time")
    if as_json:
        document = result.to_dict()
        document["figures"] = [str(p) for p in written]
        sys.stdout.write(json.dumps(document) + "\n")
    else:
        stdout.print(result.table())
