"""Run an optimiser in a helper thread and stream its progress as a generator.

:func:`stream_optimiser` turns a blocking ``scipy.optimize`` call that accepts a callback into a
generator of (iteration, value) events whose return value is the optimiser's result, so a fit
can report progress and be stopped by closing the generator (:mod:`core.gp.fit_run`);
:func:`run_to_end` exhausts such a generator when the progress is not wanted.
"""

from __future__ import annotations

import queue
import threading
from collections.abc import Callable, Generator
from typing import Any, TypeVar

import scipy.optimize

_Result = TypeVar("_Result")


def run_to_end(generator: Generator[Any, None, _Result]) -> _Result:
    """Exhaust ``generator`` (its progress unused) and return what it returned."""
    while True:
        try:
            next(generator)
        except StopIteration as stop:
            result: _Result = stop.value
            return result


def stream_optimiser(
    run: Callable[[Callable[[Any], None]], _Result], every: int
) -> Generator[tuple[int, float], None, _Result]:
    """Run an optimiser in a helper thread and yield (iteration, value) every ``every``
    iterations; the generator's return value is the optimiser's result.

    The two threads strictly take turns (the optimiser waits while the consumer handles an
    event), so results are deterministic. Closing the generator stops the optimiser: its
    callback raises ``StopIteration``, which scipy treats as a request to halt.
    """
    to_consumer: queue.Queue[tuple[str, Any]] = queue.Queue(maxsize=1)
    to_worker: queue.Queue[bool] = queue.Queue(maxsize=1)
    count = 0

    def callback(intermediate_result: scipy.optimize.OptimizeResult) -> None:
        nonlocal count
        count += 1
        if count % every == 0:
            to_consumer.put(("progress", (count, float(intermediate_result.fun))))
            if not to_worker.get():
                raise StopIteration

    def work() -> None:
        try:
            to_consumer.put(("done", run(callback)))
        except BaseException as exc:  # handed to the consumer thread
            to_consumer.put(("error", exc))

    thread = threading.Thread(target=work, name="manifold-optimiser", daemon=True)
    thread.start()
    finished = False
    try:
        while True:
            kind, payload = to_consumer.get()
            if kind == "progress":
                yield payload
                to_worker.put(True)
            elif kind == "done":
                finished = True
                return payload  # type: ignore[no-any-return]
            else:
                finished = True
                raise payload
    finally:
        if not finished:
            # The consumer stopped early: release the optimiser with a stop request and wait.
            to_worker.put(False)
            while True:
                kind, _ = to_consumer.get()
                if kind != "progress":
                    break
                to_worker.put(False)
        thread.join()
