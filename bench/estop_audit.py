"""Benchmark: ``POST /rig/estop`` latency with and without the request audit recording it.

Serves the app in-process under uvicorn on 127.0.0.1 (mock rig, temporary database, a token),
then times ``--calls`` sequential e-stops over one keep-alive connection, in ``--rounds``
alternating rounds with the audit recorder running and closed (a closed recorder records
nothing). Prints the median and 95th percentile of each round. The audit writes from its own
thread after the answer is sent, so the e-stop's latency should not depend on it beyond noise.

Run: ``.venv/bin/python -m bench.estop_audit [--calls 300] [--rounds 4]``
"""

from __future__ import annotations

import argparse
import tempfile
import threading
import time
from pathlib import Path

import httpx
import numpy as np

from app.cli.serve import ServedApp, listening_url
from app.config import Settings

TOKEN = "bench-token"


def one_round(audit: bool, calls: int) -> np.ndarray:
    """Latencies (seconds) of ``calls`` e-stops on a fresh server."""
    directory = Path(tempfile.mkdtemp(prefix="activetouch-bench-"))
    settings = Settings(
        _env_file=None,
        port=0,
        viz=False,
        api_token=TOKEN,
        database_url=f"sqlite:///{directory / 'bench.db'}",
        frontend_dir=directory / "none",
    )
    served = ServedApp(settings, log_level="warning")
    thread = threading.Thread(target=served.run, daemon=True)
    thread.start()
    while not served.server.started:
        time.sleep(0.05)
    if not audit:
        served.app.state.audit.close()
    latencies = []
    try:
        base = listening_url(served.server, "127.0.0.1")
        headers = {"Authorization": f"Bearer {TOKEN}"}
        with httpx.Client(base_url=base, headers=headers, timeout=30) as client:
            for _ in range(20):  # warm-up
                client.post("/api/v1/rig/estop")
            for _ in range(calls):
                started = time.perf_counter()
                response = client.post("/api/v1/rig/estop")
                latencies.append(time.perf_counter() - started)
                response.raise_for_status()
    finally:
        served.server.should_exit = True
        thread.join(timeout=30)
    return np.asarray(latencies)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--calls", type=int, default=300)
    parser.add_argument("--rounds", type=int, default=4)
    args = parser.parse_args()
    for round_index in range(args.rounds):
        for audit in (False, True):
            times_ms = one_round(audit, args.calls) * 1000.0
            label = "audit on " if audit else "audit off"
            print(
                f"round {round_index + 1:d} {label}: median {np.median(times_ms):.2f} ms, "
                f"p95 {np.percentile(times_ms, 95):.2f} ms ({args.calls:d} e-stops)"
            )


if __name__ == "__main__":
    main()
