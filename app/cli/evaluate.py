"""``activetouch evaluate``: how many touches each policy needs on a model's objects.

::

    activetouch evaluate --model exp1.json --world exp1 --trials 250 --steps 10 --workers 2
    activetouch evaluate --model rig.json --world replay --data held_out.csv --json --out r.json
    activetouch evaluate --model m.json --world model --scheduler tcp://host:8786 --plot c.png

Trials run in process, on a ``LocalCluster`` of ``--workers`` single-threaded processes, or on an
existing Dask scheduler (:mod:`app.evaluation.runner`). A progress bar (trials done, ETA) goes to
stderr; ``--json`` prints only the ``activetouch-evaluation/2`` report on stdout (with each
policy's calibration: reliability tables, ECE, Brier score, log-loss and "sure and wrong", over
every trial and touch, at T and by touch); the table shows the ECE and "sure and wrong" (answers
given with p ≥ ``--confidence``, and how many of them were wrong) over every trial and touch.
``--stop-at-confidence`` also ends a trial once its answer reaches that probability (recorded
in the report and said under the table). ``--out`` and ``--plot`` are written once the
evaluation has finished (nothing half-written). Bad input exits with 2 and a message naming it;
Ctrl-C exits with 130 and writes nothing.

On the ``rig`` world a trial whose touch the rig refuses (a servo overload, ...) is counted in
the table's "refused" column and left out of the accuracy (over the "completed" trials); a rig
failure that is not such a refusal exits with 1 naming the trial, touch and device error.

This module imports only typer and rich at the top (the CLI starts light).
"""

from __future__ import annotations

import json
import os
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, cast

import typer
from rich.markup import escape
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)
from rich.table import Table

from app.cli.options import (
    PlacementOption,
    PlanUnderOption,
    TableFile,
    TableName,
    TrialLikelihoodOption,
    table_choice,
)
from app.cli.output import messages as stderr
from app.cli.output import results as stdout

if TYPE_CHECKING:
    pass


def fail(message: str, code: int = 2) -> typer.Exit:
    """Print a one-line error to stderr and return the exit to raise."""
    stderr.print(f"[red]error:[/red] {escape(message)}")
    return typer.Exit(code=code)


def split_names(value: str | None, option: str) -> tuple[str, ...] | None:
    """``"a,b"`` → ``("a", "b")``; ``None`` stays ``None``.

    Raises:
        typer.Exit: An empty name (exit 2).
    """
    if value is None:
        return None
    names = tuple(part.strip() for part in value.split(","))
    if not names or any(not n for n in names):
        raise fail(f"{option}: expected comma-separated names, received {value!r}")
    return names


def write_atomically(path: Path, write: Callable[[Path], None]) -> None:
    """Write through a temporary file in the same folder, then rename: never half a file."""
    handle, temporary = tempfile.mkstemp(
        dir=path.parent, prefix=f".{path.name}.", suffix=f".tmp{path.suffix}"
    )
    os.close(handle)
    try:
        write(Path(temporary))
        os.replace(temporary, path)
    except BaseException:
        Path(temporary).unlink(missing_ok=True)
        raise


def check_output(path: Path | None, option: str) -> None:
    """Exit 2 now if an output could not be written later."""
    if path is not None and not path.parent.is_dir():
        raise fail(f"{option}: the folder {path.parent} does not exist")


def calibration_cells(summary: dict[str, Any]) -> tuple[str, str]:
    """(ECE, "sure and wrong") of a policy over every (trial, touch): "0.031" and
    "3 of 120 (2.5 %)"; dashes for a summary without calibration (an ``/1`` document) or no
    sure answer."""
    calibration = summary.get("calibration")
    if not calibration:
        return "—", "—"
    scored = calibration["all_touches"]
    ece = "—" if scored["ece"] is None else f"{scored['ece']:.3f}"
    sure = scored["sure_and_wrong"]
    share = sure["share_wrong"]
    wrong = f"{sure['wrong']:d} of {sure['sure']:d}" + (
        "" if share is None else f" ({100 * share:.1f} %)"
    )
    return ece, wrong


def sampling_noise_line(document: dict[str, Any]) -> str:
    """ "ECE from sampling alone, were the answers calibrated (mean, 95th percentile): active
    0.041, 0.063; ..." for the policies whose report has it; "" for none."""
    parts = []
    for name, summary in document["policies"].items():
        scored = (summary.get("calibration") or {}).get("all_touches") or {}
        null = scored.get("ece_if_calibrated")
        if null:
            parts.append(f"{name} {null['mean']:.3f}, {null['p95']:.3f}")
    if not parts:
        return ""
    return (
        "ECE that sampling alone gives these answers were they calibrated (mean, 95th "
        "percentile): " + "; ".join(parts)
    )


def summary_table(document: dict[str, Any]) -> Table:
    """Accuracy by touch, at T with its interval, calibration (ECE and "sure and wrong" over
    every trial and touch), touches to confidence, per object."""
    steps = int(document["steps"])
    table = Table(
        title=f"{escape(str(document['world']))}: {document['trials_per_target']:d} trials per "
        f"target, T = {steps:d}, seed {document['seed']:d}, {document['workers']:d} worker(s), "
        f"{document['seconds']:.1f} s",
        caption="ECE: expected calibration error; sure and wrong: of the answers given with "
        f"p ≥ {document['confidence']:g}, the wrong ones (both over every trial and touch)."
        + (
            f" Trials stop once the answer reaches p ≥ {document['confidence']:g} (its answer "
            "carried forward to T)."
            if document.get("stop_at_confidence")
            else ""
        ),
        caption_justify="left",
    )
    table.add_column("policy")
    table.add_column("accuracy % by touch 1..T")
    table.add_column("at T (95 % interval)", justify="right")
    table.add_column("ECE", justify="right", no_wrap=True)
    table.add_column("sure and wrong", justify="right", no_wrap=True)
    table.add_column(f"median touches to p ≥ {document['confidence']:g}", justify="right")
    table.add_column("per object at T (%)")
    table.add_column("completed", justify="right")
    table.add_column("refused", justify="right")
    refused: dict[str, int] = document.get("refused_by_policy", {})
    for name, summary in document["policies"].items():
        curve = " ".join(f"{100 * a:.0f}" for a in summary["accuracy_by_touch"])
        lo, hi = summary["accuracy_interval"][-1]
        median = summary["median_touches_to_confidence"]
        per_object = ", ".join(
            f"{escape(obj)} {100 * item['accuracy']:.0f}"
            for obj, item in summary["per_object"].items()
        )
        table.add_row(
            escape(name),
            curve,
            f"{100 * summary['accuracy_by_touch'][-1]:.1f} ({100 * lo:.1f}–{100 * hi:.1f})",
            *calibration_cells(summary),
            "never (half or more)" if median is None else f"{median:.1f}",
            per_object,
            f"{summary['trials']:d}",
            f"{refused.get(name, 0):d}",
        )
    for name, count in refused.items():
        if name not in document["policies"] and count:  # every trial of it was refused
            table.add_row(escape(name), "—", "—", "—", "—", "—", "—", "0", f"{count:d}")
    return table


def evaluate_command(
    model_path: Annotated[Path, typer.Option("--model", help="Model document (JSON).")],
    world: Annotated[
        str, typer.Option(help="exp1, exp2, rig (simulated, in process), model or replay.")
    ],
    data: Annotated[
        Path | None,
        typer.Option(
            help="Held-out touches of a replay, never used to fit: a training CSV, or a raw-touch "
            "file (docs/raw-touches.md) featurised by the model's own pipeline."
        ),
    ] = None,
    targets: Annotated[
        str | None, typer.Option(help="Objects to recognise, a,b (default: every object).")
    ] = None,
    policies: Annotated[str, typer.Option(help="Policies, comma-separated.")] = "active,passive",
    trials: Annotated[int, typer.Option(help="Trials per target and policy.")] = 25,
    steps: Annotated[int, typer.Option(help="T, touches per trial at most.")] = 10,
    confidence: Annotated[
        float, typer.Option(help="Probability for 'touches to confidence' and the comparison.")
    ] = 0.95,
    stop_at_confidence: Annotated[
        bool,
        typer.Option(
            "--stop-at-confidence",
            help="Also stop a trial once its answer's probability reaches --confidence (the "
            "answer is carried forward to T; the trial records the stop).",
        ),
    ] = False,
    seed: Annotated[int, typer.Option(help="Seed of every trial's SeedSequence.")] = 0,
    table: TableName = None,
    table_file: TableFile = None,
    placement: PlacementOption = "trial",
    trial_likelihood: TrialLikelihoodOption = "joint",
    plan_under: PlanUnderOption = "objects",
    workers: Annotated[
        int | None, typer.Option(help="Run on a LocalCluster of K single-threaded processes.")
    ] = None,
    scheduler: Annotated[
        str | None, typer.Option(help="Run on an existing Dask scheduler, tcp://host:8786.")
    ] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print only the JSON report.")] = False,
    out: Annotated[Path | None, typer.Option(help="Write the JSON report here.")] = None,
    plot: Annotated[
        Path | None, typer.Option(help="Write the accuracy curves and per-object bars (PNG).")
    ] = None,
) -> None:
    """Evaluate policies on a model: accuracy by touch with intervals, calibration, per object,
    confusion."""
    from app.cli.main import load_model
    from app.cli.raw_data import replay_touches
    from app.errors import AppError, DeviceUnavailableError
    from app.evaluation.runner import run_evaluation
    from app.evaluation.spec import EvaluationSpec, Placement, world_name
    from core.errors import CoreError
    from core.recognition import PlanningBelief, TrialLikelihood

    if workers is not None and scheduler is not None:
        raise fail("--workers and --scheduler: give one (a local cluster or an existing one)")
    check_output(out, "--out")
    check_output(plot, "--plot")
    chosen_table = table_choice(table, table_file)
    model = load_model(model_path)
    replay = replay_touches(data, model) if data is not None else None
    try:
        known_world = world_name(world)
    except AppError as exc:
        raise fail(_message(exc)) from None
    spec = EvaluationSpec(
        world=known_world,
        trials_per_target=trials,
        steps=steps,
        policies=split_names(policies, "--policies") or (),
        confidence=confidence,
        seed=seed,
        targets=split_names(targets, "--targets"),
        table=chosen_table,
        placement=cast(Placement, placement),
        trial_likelihood=cast(TrialLikelihood, trial_likelihood),
        plan_under=cast(PlanningBelief, plan_under),
        stop_at_confidence=stop_at_confidence,
    )
    try:
        spec.check(model, replay)
    except (AppError, CoreError) as exc:
        raise fail(_message(exc)) from None
    total = len(spec.policies) * len(spec.target_names(model)) * trials
    progress = Progress(
        TextColumn("[bold]evaluate"),
        BarColumn(),
        MofNCompleteColumn(),
        TextColumn("trials"),
        TimeElapsedColumn(),
        TextColumn("ETA"),
        TimeRemainingColumn(),
        console=stderr,
    )
    try:
        with progress:
            task = progress.add_task("evaluate", total=total)
            report = run_evaluation(
                model,
                spec,
                replay=replay,
                workers=workers,
                scheduler=scheduler,
                on_trial=lambda _record: progress.advance(task),
            )
    except DeviceUnavailableError as exc:  # the rig failed, other than by refusing a touch
        raise fail(_message(exc), code=1) from None
    except (AppError, CoreError) as exc:
        raise fail(_message(exc)) from None
    except KeyboardInterrupt:
        raise fail("interrupted: nothing written", code=130) from None
    document = report.to_dict()
    if out is not None:
        text = json.dumps(document, indent=1)
        write_atomically(out, lambda p: _write_text(p, text))
    if plot is not None:
        from app.evaluation.plot import plot_report

        write_atomically(plot, lambda p: plot_report(document, p))
    if as_json:
        sys.stdout.write(json.dumps(document) + "\n")
        return
    stdout.print(summary_table(document))
    noise = sampling_noise_line(document)
    if noise:
        stdout.print(escape(noise))
    if document["comparison"]:
        stdout.print(escape(document["comparison"]))
    for note in document["notes"]:
        stdout.print(f"note: {escape(note)}")


def _write_text(path: Path, text: str) -> None:
    path.write_text(text)


def _message(exc: Exception) -> str:
    return str(getattr(exc, "message", None) or exc)
