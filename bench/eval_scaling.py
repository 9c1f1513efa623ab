"""Benchmark: an Experiment 1 evaluation in process, on 1 and on 2 Dask worker processes.

The model is fitted once (data seed 0, 4 × 100 touches, ds = 1, 4 restarts, as ``paper exp1``);
the evaluation is world ``exp1``, policies active and passive, ``--trials`` trials per object
(250: 1,000 per policy), T = 10, seed 0. It runs once in process and once on a ``LocalCluster``
of 1 and of 2 single-threaded worker processes (each run includes starting and closing its
cluster; the start-up alone is timed too). The script checks that the three reports are
identical trial by trial (and as documents, wall time and worker count aside), and measures what
crosses the network: the pickled context sent once per worker, and per task the pickled task
(function reference and trial key) and the pickled result.

One run of each (the evaluation itself is 2,000 trials). Wall seconds, the CPU seconds of this
process and of the cluster's processes (sampled with psutil), and the machine's load are printed:
on a shared machine the CPU seconds per wall second show how much of the cores a run actually
got.

Run: ``.venv/bin/python -m bench.eval_scaling [--trials 250] [--json]``
"""

from __future__ import annotations

import argparse
import json
import os
import pickle
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import numpy as np

from app.evaluation.cluster import batches, local_cluster
from app.evaluation.context import TrialContext, run_trials_task
from app.evaluation.runner import run_evaluation
from app.evaluation.spec import EvaluationSpec
from bench.harness import machine
from core.evaluation import Experiment1World, sample_dataset
from core.gp import FitOptions, fit_manifold


@contextmanager
def child_cpu_seconds(period_s: float = 0.25) -> Iterator[dict[int, float]]:
    """CPU seconds (user + system) of every descendant process, sampled until the block ends.

    The cluster's processes exit when the run closes it, so their last sample is kept.
    """
    import psutil

    last: dict[int, float] = {}
    done = threading.Event()

    def sample() -> None:
        while True:
            for child in psutil.Process().children(recursive=True):
                try:
                    times = child.cpu_times()
                except psutil.Error:
                    continue
                last[child.pid] = times.user + times.system
            if done.wait(period_s):
                return

    thread = threading.Thread(target=sample, daemon=True)
    thread.start()
    try:
        yield last
    finally:
        done.set()
        thread.join()


def comparable(document: dict[str, Any]) -> dict[str, Any]:
    """A report document without wall time and worker count."""
    return {k: v for k, v in document.items() if k not in ("seconds", "workers")}


def main(argv: list[str] | None = None) -> dict[str, Any]:
    """Run the benchmark; print and return the figures."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=250, help="Trials per object and policy.")
    parser.add_argument("--json", action="store_true", help="Print the figures as JSON only.")
    args = parser.parse_args(argv)
    world = Experiment1World()
    data = sample_dataset(world, np.random.default_rng(0), touches_per_object=100)
    model = fit_manifold(data, 1, np.random.default_rng(0), FitOptions(restarts=4))
    spec = EvaluationSpec(world="exp1", trials_per_target=args.trials, steps=10, seed=0)

    runs: dict[str, dict[str, Any]] = {}
    reports = {}
    for name, workers in (("in_process", None), ("workers_1", 1), ("workers_2", 2)):
        cpu = time.process_time()
        started = time.perf_counter()
        with child_cpu_seconds() as children:
            report = run_evaluation(model, spec, workers=workers)
        wall = time.perf_counter() - started
        runs[name] = {
            "wall_s": wall,
            "parent_cpu_s": time.process_time() - cpu,
            "cluster_processes_cpu_s": sum(children.values()),
            "cpu_share_of_wall": (time.process_time() - cpu + sum(children.values())) / wall,
            "workers": report.workers,
            "trials": len(report.records),
            "load_after": os.getloadavg()[0],
        }
        reports[name] = report
    for workers in (1, 2):
        started = time.perf_counter()
        cluster = local_cluster(workers)
        cluster.close()
        runs[f"workers_{workers}"]["cluster_start_close_s"] = time.perf_counter() - started

    base = reports["in_process"]
    identical = {
        name: report.records == base.records
        and comparable(report.to_dict()) == comparable(base.to_dict())
        for name, report in reports.items()
    }
    context = TrialContext(model, spec)
    keys = context.trial_keys()
    tasks = batches(keys, 2)
    task_bytes = [len(pickle.dumps((run_trials_task, batch), protocol=5)) for batch in tasks]
    result_bytes = [len(pickle.dumps(r, protocol=5)) for r in base.records]
    summary = base.to_dict(include_trials=False)
    figures = {
        "benchmark": "eval_scaling",
        "trials_per_object": args.trials,
        "trials": len(base.records),
        "runs": runs,
        "identical_to_in_process": identical,
        "ratio_workers_1_over_workers_2": runs["workers_1"]["wall_s"] / runs["workers_2"]["wall_s"],
        "ratio_in_process_over_workers_2": runs["in_process"]["wall_s"]
        / runs["workers_2"]["wall_s"],
        "bytes": {
            "context_once_per_worker": len(pickle.dumps(context, protocol=5)),
            "trials_per_task_2_workers": len(tasks[0]),
            "task_median": float(np.median(task_bytes)),
            "result_per_trial_median": float(np.median(result_bytes)),
            "result_per_trial_max": int(max(result_bytes)),
        },
        "accuracy_at_T": {p: s["accuracy_by_touch"][-1] for p, s in summary["policies"].items()},
        "comparison": summary["comparison"],
        "machine": machine(),
    }
    if args.json:
        sys.stdout.write(json.dumps(figures) + "\n")
    else:
        for name, run in runs.items():
            print(
                f"{name:>10s}: {run['wall_s']:7.1f} s wall, "
                f"{run['parent_cpu_s'] + run['cluster_processes_cpu_s']:7.1f} s CPU, "
                f"{run['trials']} trials, "
                f"identical to in-process: {identical[name]}"
            )
        ratio = figures["ratio_workers_1_over_workers_2"]
        print(f"wall-time ratio workers 1 / workers 2: {ratio:.2f}")
        print(f"bytes: {json.dumps(figures['bytes'])}")
        print(figures["comparison"])
    return figures


if __name__ == "__main__":
    main()
