"""Benchmark: ``GET /trials/{id}`` under 20 concurrent clients while a simulated trial runs.

Starts the server as a process (``python -m app.cli.serve``) on 127.0.0.1 with a temporary
database, imports an Experiment 1 model (true latents, fixed hyperparameters: no fit), starts a
simulated trial that keeps touching (one step every ``--step-interval-s``), then lets
``--clients`` threads, each with its own keep-alive connection, read the trial as fast as they
can for ``--seconds``. Prints requests per second, latency percentiles and how many steps the
trial had recorded (the response grows with it). Traffic goes to 127.0.0.1 only and stops by
itself.

Run: ``.venv/bin/python -m bench.api_load [--clients 20] [--seconds 10]``
"""

from __future__ import annotations

import argparse
import os
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import httpx
import numpy as np

from app.documents.model import model_to_document
from core.evaluation import experiment1_at_true_latents

ROOT = Path(__file__).resolve().parent.parent


def experiment1_document() -> dict[str, Any]:
    """An Experiment 1 model document: true θ latents (normalised), fixed hyperparameters."""
    return model_to_document(experiment1_at_true_latents())


def free_port() -> int:
    """A free TCP port on 127.0.0.1."""
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port: int = sock.getsockname()[1]
        return port


def start_server(database: Path, port: int) -> subprocess.Popen[bytes]:
    """The API server as a child process, returned once ``/health`` answers."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("ACTIVETOUCH_")}
    process = subprocess.Popen(
        [sys.executable, "-m", "app.cli.serve", "--port", str(port),
         "--database-url", f"sqlite:///{database}", "--log-level", "warning"],
        cwd=ROOT, env=env,
    )  # fmt: skip
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:
        try:
            if httpx.get(f"http://127.0.0.1:{port}/api/v1/health", timeout=1).is_success:
                return process
        except httpx.TransportError:
            time.sleep(0.2)
    process.kill()
    raise RuntimeError("the server did not start")


def hammer(url: str, stop_at: float, latencies: list[float], errors: list[str]) -> None:
    """Read ``url`` in a loop until ``stop_at`` (monotonic); append latencies in seconds."""
    with httpx.Client(timeout=30) as client:
        while time.monotonic() < stop_at:
            started = time.perf_counter()
            try:
                response = client.get(url)
            except httpx.HTTPError as exc:
                errors.append(repr(exc))
                continue
            latencies.append(time.perf_counter() - started)
            if response.status_code != 200:
                errors.append(f"HTTP {response.status_code}")


def main(argv: list[str] | None = None) -> None:
    """Run the benchmark and print the figures."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    parser.add_argument("--clients", type=int, default=20)
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--step-interval-s", type=float, default=0.05)
    args = parser.parse_args(argv)
    port = free_port()
    base = f"http://127.0.0.1:{port}/api/v1"
    with tempfile.TemporaryDirectory(prefix="activetouch-bench-") as directory:
        process = start_server(Path(directory) / "bench.db", port)
        try:
            model = httpx.post(f"{base}/models/import", json=experiment1_document(), timeout=60)
            model.raise_for_status()
            trial = httpx.post(
                f"{base}/trials",
                json={
                    "model_id": model.json()["id"], "mode": "simulated", "target": "O3",
                    "seed": 0, "max_steps": 1000, "tolerance": 0.0,
                    "simulation": {"world": "experiment1",
                                   "step_interval_s": args.step_interval_s},
                },
                timeout=60,
            )  # fmt: skip
            trial.raise_for_status()
            url = f"{base}/trials/{trial.json()['id']}"
            time.sleep(1.0)  # let the trial record a few steps
            steps_before = httpx.get(url, timeout=30).json()["n_steps"]
            per_client: list[list[float]] = [[] for _ in range(args.clients)]
            errors: list[str] = []
            stop_at = time.monotonic() + args.seconds
            threads = [
                threading.Thread(target=hammer, args=(url, stop_at, per_client[i], errors))
                for i in range(args.clients)
            ]
            started = time.monotonic()
            for thread in threads:
                thread.start()
            for thread in threads:
                thread.join()
            elapsed = time.monotonic() - started
            after = httpx.get(url, timeout=30).json()
            httpx.post(f"{url}/abort", timeout=30)
        finally:
            process.terminate()
            process.wait(timeout=30)
    latencies = np.sort(np.concatenate([np.asarray(c) for c in per_client]))
    count = latencies.size
    print(f"GET /trials/{{id}} with {args.clients} concurrent clients for {elapsed:.1f} s "
          f"during a running simulated trial ({args.step_interval_s} s between steps)")  # fmt: skip
    print(f"  requests: {count}  errors: {len(errors)}  throughput: {count / elapsed:.0f} req/s")
    if count:
        p50, p90, p99 = (float(np.quantile(latencies, q)) * 1000 for q in (0.5, 0.9, 0.99))
        print(f"  latency ms: p50 {p50:.1f}  p90 {p90:.1f}  p99 {p99:.1f}  "
              f"max {latencies[-1] * 1000:.1f}")  # fmt: skip
    print(f"  trial status {after['status']}, steps {steps_before} → {after['n_steps']} "
          f"(the response grows with the steps)")  # fmt: skip


if __name__ == "__main__":
    main()
