"""Measurement helpers for the benchmarks: pinned BLAS threads, medians of repeats, the GEMM
rate of this machine, peak memory of a child process, and the machine's load.

Timings are wall-clock medians (``time.perf_counter``) with the CPU time beside them: on a shared
machine the CPU time shows how much of the wall time the process actually ran.
"""

from __future__ import annotations

import json
import os
import platform
import resource
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from threadpoolctl import threadpool_info, threadpool_limits

from core.validation import FloatArray


@dataclass(frozen=True)
class Timing:
    """Wall and CPU seconds of repeated calls.

    Attributes:
        median_s: Median wall time of one call.
        p10_s: 10th percentile.
        p90_s: 90th percentile.
        cpu_median_s: Median CPU time (user + system, this process) of one call.
        repeats: Number of timed calls.
    """

    median_s: float
    p10_s: float
    p90_s: float
    cpu_median_s: float
    repeats: int

    def to_dict(self) -> dict[str, float | int]:
        return asdict(self)


def measure(
    function: Callable[[], object],
    repeats: int = 5,
    warmup: int = 1,
    budget_s: float | None = None,
) -> Timing:
    """Time ``function()``: ``warmup`` untimed calls, then ``repeats`` timed ones (fewer if
    ``budget_s`` of wall time runs out after at least one)."""
    for _ in range(warmup):
        function()
    wall: list[float] = []
    cpu: list[float] = []
    started = time.perf_counter()
    for _ in range(max(repeats, 1)):
        w0, c0 = time.perf_counter(), time.process_time()
        function()
        wall.append(time.perf_counter() - w0)
        cpu.append(time.process_time() - c0)
        if budget_s is not None and time.perf_counter() - started > budget_s:
            break
    values = np.array(wall)
    return Timing(
        median_s=float(np.median(values)),
        p10_s=float(np.percentile(values, 10)),
        p90_s=float(np.percentile(values, 90)),
        cpu_median_s=float(np.median(cpu)),
        repeats=len(wall),
    )


@contextmanager
def blas_threads(threads: int) -> Iterator[None]:
    """Limit the BLAS/OpenMP thread pools to ``threads`` inside the block."""
    with threadpool_limits(limits=threads):
        yield


def gemm_product(size: int = 1024) -> tuple[Callable[[], object], float]:
    """A size × size double-precision product to time, and its flop count."""
    rng = np.random.default_rng(0)
    a = rng.standard_normal((size, size))
    b = rng.standard_normal((size, size))
    return (lambda: a @ b), 2.0 * size**3


def gemm_rate(size: int = 1024, repeats: int = 5) -> float:
    """Measured double-precision GEMM rate (flop/s) of a size × size product, median of repeats,
    under the current thread limit."""
    product, flops = gemm_product(size)
    timing = measure(product, repeats=repeats, warmup=1)
    return flops / timing.median_s


def paired_times(
    first: Callable[[], object], second: Callable[[], object], repeats: int, warmup: int = 1
) -> tuple[FloatArray, FloatArray]:
    """Wall seconds of ``first()`` and ``second()`` called alternately ``repeats`` times each.

    A ratio of the two taken pair by pair (then its median) shrugs off the slow drifts of a
    shared machine that would skew a ratio of two medians measured minutes apart.
    """
    for _ in range(warmup):
        first()
        second()
    times = np.empty((2, max(repeats, 1)))
    for k in range(times.shape[1]):
        for row, function in enumerate((first, second)):
            started = time.perf_counter()
            function()
            times[row, k] = time.perf_counter() - started
    return times[0], times[1]


def machine() -> dict[str, Any]:
    """CPU count, load averages, BLAS library and Python version."""
    load = os.getloadavg() if hasattr(os, "getloadavg") else (float("nan"),) * 3
    blas = [
        f"{info.get('internal_api')} {info.get('version')} ({info.get('architecture')})"
        for info in threadpool_info()
        if info.get("user_api") == "blas"
    ]
    return {
        "cpus": os.cpu_count(),
        "load_average_1_5_15": [round(v, 2) for v in load],
        "blas": sorted(set(blas)),
        "python": platform.python_version(),
        "numpy": np.__version__,
        "platform": platform.platform(),
    }


def peak_rss_mb() -> float:
    """High-water resident set size of this process so far, MB.

    Linux: ``VmHWM`` of ``/proc/self/status`` (reset by ``exec``, so a child started by
    :func:`run_child` reports its own peak; ``ru_maxrss`` would carry the parent's over).
    Elsewhere: ``ru_maxrss``.
    """
    try:
        with open("/proc/self/status", encoding="ascii") as status:
            for line in status:
                if line.startswith("VmHWM:"):
                    return float(line.split()[1]) / 1024.0
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def run_child(module: str, arguments: dict[str, Any], timeout_s: float) -> dict[str, Any]:
    """Run ``python -m module '<json>'`` with one BLAS thread (unless ``arguments['threads']``)
    and return the JSON object it prints last on stdout.

    A fresh process gives a clean peak-memory figure (``ru_maxrss``) per measurement.

    Raises:
        RuntimeError: The child failed or timed out (the message carries its stderr tail).
    """
    threads = str(arguments.get("threads", 1))
    env = dict(os.environ)
    for variable in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        env[variable] = threads
    try:
        done = subprocess.run(
            [sys.executable, "-m", module, json.dumps(arguments)],
            capture_output=True,
            text=True,
            timeout=timeout_s,
            env=env,
            check=False,
        )
    except subprocess.TimeoutExpired as exc:
        raise RuntimeError(f"{module} {arguments} timed out after {timeout_s:.0f} s") from exc
    if done.returncode != 0:
        tail = "\n".join(done.stderr.strip().splitlines()[-5:])
        raise RuntimeError(f"{module} {arguments} failed ({done.returncode}): {tail}")
    lines = [line for line in done.stdout.strip().splitlines() if line.startswith("{")]
    if not lines:
        raise RuntimeError(f"{module} {arguments} printed no JSON result")
    result: dict[str, Any] = json.loads(lines[-1])
    return result


def ratio(numerator: float | None, denominator: float | None) -> float | None:
    """numerator / denominator, or ``None`` when either is missing or the denominator is 0."""
    if numerator is None or denominator is None or denominator == 0:
        return None
    return float(numerator / denominator)
