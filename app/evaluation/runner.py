"""Run an evaluation: every trial of a spec, in process or as tasks on Dask distributed.

Each trial draws from its own ``SeedSequence`` (:func:`core.evaluation.records.trial_seed`), so the
records do not depend on where or in which order trials run: a cluster run equals a local one,
trial by trial.

A trial whose touch the rig refuses is kept as a :class:`~core.evaluation.records.RefusedTrial`
and the evaluation goes on; a hardware error that is not such a refusal ends the evaluation with
:class:`~app.errors.DeviceUnavailableError` naming the trial and touch.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence

from app.errors import BadInputError, DeviceUnavailableError
from app.evaluation.context import TrialContext
from app.evaluation.report import EvaluationReport
from app.evaluation.spec import EvaluationSpec
from core.evaluation import RefusedTrial, TrialOutcome, TrialRecord
from core.types import ManifoldModel, TrainingData
from hardware.errors import HardwareError


def run_evaluation(
    model: ManifoldModel,
    spec: EvaluationSpec,
    *,
    replay: TrainingData | None = None,
    workers: int | None = None,
    scheduler: str | None = None,
    on_trial: Callable[[TrialOutcome], None] | None = None,
    should_stop: Callable[[], bool] | None = None,
    done: Sequence[TrialOutcome] = (),
) -> EvaluationReport:
    """Run every trial of ``spec`` not already in ``done``.

    Args:
        model: The model recognising.
        spec: The evaluation.
        replay: Held-out touches (the ``replay`` world).
        workers: Start a ``LocalCluster`` of this many single-threaded worker processes.
        scheduler: Address of an existing Dask scheduler (``tcp://host:8786``).
        on_trial: Called in the caller's thread as each trial finishes (any order), refused
            ones included.
        should_stop: Polled between trials; when true no new trial starts, finished ones are
            kept and the report is marked stopped.
        done: Trials already finished, refused ones included (a resumed run does not redo
            them).

    Raises:
        BadInputError: The spec does not fit the model or the data (naming the field), both or
            bad ``workers``/``scheduler``, or a scheduler that cannot be reached.
        DeviceUnavailableError: The rig failed other than by refusing one touch (the message
            names the trial, the touch and the device's error).
    """
    spec.check(model, replay)
    if workers is not None and scheduler is not None:
        raise BadInputError(
            "workers and scheduler: give one (a local cluster or an existing one), not both.",
            field="workers",
        )
    if workers is not None and (isinstance(workers, bool) or workers < 1):
        raise BadInputError(f"workers: must be ≥ 1, received {workers}.", field="workers")
    context = TrialContext(model, spec, replay)
    finished = {r.key: r for r in done}
    keys = [k for k in context.trial_keys() if k not in finished]
    records = list(finished.values())

    def collect(record: TrialOutcome) -> None:
        records.append(record)
        if on_trial is not None:
            on_trial(record)

    stop = should_stop if should_stop is not None else (lambda: False)
    started = time.perf_counter()
    try:
        if workers is None and scheduler is None:
            stopped = _run_serial(context, keys, collect, stop)
            used = 1
        else:
            from app.evaluation.cluster import run_on_cluster

            stopped, used = run_on_cluster(context, keys, collect, stop, workers, scheduler)
    except HardwareError as exc:
        raise rig_failure(exc, len(records)) from exc
    return EvaluationReport(
        spec=spec,
        records=tuple(r for r in records if isinstance(r, TrialRecord)),
        refused=tuple(r for r in records if isinstance(r, RefusedTrial)),
        seconds=time.perf_counter() - started,
        workers=used,
        stopped=stopped,
        object_names=model.object_names,
        steps=context.steps,
    )


def rig_failure(error: HardwareError, finished: int) -> DeviceUnavailableError:
    """The error that ends an evaluation when the rig fails other than by refusing a touch."""
    where = " ".join(reversed(getattr(error, "__notes__", None) or []))
    return DeviceUnavailableError(
        f"the rig failed{' ' + where if where else ''}: {type(error).__name__}: {error}. "
        f"This is not the refusal of one touch, so the evaluation stopped "
        f"({finished} trial(s) had finished).",
        device_error=type(error).__name__,
    )


def _run_serial(
    context: TrialContext,
    keys: list[tuple[str, str, int]],
    collect: Callable[[TrialOutcome], None],
    stop: Callable[[], bool],
) -> bool:
    from threadpoolctl import threadpool_limits

    # BLAS on one thread for the whole loop (pinning costs ~1 ms; a trial ~30 ms).
    with threadpool_limits(limits=1):
        for key in keys:
            if stop():
                return True
            collect(context.run_unpinned(key))
    return False
