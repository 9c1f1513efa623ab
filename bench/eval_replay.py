"""Benchmark: a replay evaluation on held-out touches of a simulated-rig collection.

1. ``activetouch collect --sim --touches N`` collects N touches of every object of the default
   simulated table (random design, x ~ N(0, I), seed ``--seed``) into a CSV;
2. the first ``--fit`` touches of each object train the model (ds = ``--latent-dim``), the rest
   (touches fit+1..N) are held out and never used for fitting;
3. ``activetouch evaluate --world replay`` runs active and passive on the held-out touches
   (``--trials`` trials per object; T = the held-out pool size): active picks the unused recorded
   touch of largest mutual information, passive a random one.

With T equal to the pool, both policies have seen every held-out touch at touch T and answer the
same there (the object posterior does not depend on the order): the comparison is in the touches
before. Active's choice is deterministic given the belief, so its trials of an object repeat.

Run: ``.venv/bin/python -m bench.eval_replay [--touches 50] [--fit 40] [--trials 20] [--json]``

Measured (one run each; 50 touches per object, fit on touches 1–40 with ds = 2, replay of
touches 41–50, 20 trials per object and policy, T = 10, seed 0):

* default table (7 objects that differ in kind), random design: active and passive 100 % from
  touch 1 (every touch tells these objects apart).
* ``--table lookalike_cups --design shared --policies active,discriminative,passive`` (four PET
  cups, each changed in one property), accuracy % by touch 1..10: active 50 50 50 75 75 75 75 75
  50 75; discriminative 50 50 50 75 50 75 75 75 75 75; passive 48.8 56.2 61.3 62.5 57.5 61.3 61.3
  63.7 61.3 72.5; the water-backed cup is never recognised by any of them (median touches to
  p ≥ 0.95: 7.5, 7, 8).
* the same table with the random design (object by object; measured before the merge of the
  simulator's latest changes): active and passive below chance (active 0 % until
  touch 10, passive 7.5–28.7 %), median touches to p ≥ 0.95 of 3: confidently wrong. The held-out
  touches of each object come last in its block, and the simulator's drift (heater, room
  temperature, pressure baseline) moves them away from the touches the model was fitted on.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from app.documents.model import model_to_document
from app.documents.training_csv import read_training_csv, write_training_csv
from core.gp import FitOptions, fit_manifold
from core.types import TrainingData


def split(data: TrainingData, first: int) -> tuple[TrainingData, TrainingData]:
    """(the first ``first`` touches of each object, the rest), in collection order."""
    fit_rows: list[int] = []
    held_rows: list[int] = []
    for k in range(data.n_objects):
        rows = np.flatnonzero(data.object_index == k)
        fit_rows.extend(int(i) for i in rows[:first])
        held_rows.extend(int(i) for i in rows[first:])

    def subset(rows: list[int]) -> TrainingData:
        index = np.asarray(sorted(rows))
        return TrainingData(
            object_names=data.object_names,
            object_index=data.object_index[index],
            actions=data.actions[index],
            observations=data.observations[index],
        )

    return subset(fit_rows), subset(held_rows)


def main(argv: list[str] | None = None) -> dict[str, Any]:
    """Run the benchmark; print and return the figures."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--touches", type=int, default=50, help="Touches per object collected.")
    parser.add_argument("--fit", type=int, default=40, help="Touches per object used to fit.")
    parser.add_argument("--latent-dim", type=int, default=2, help="ds of the model.")
    parser.add_argument("--trials", type=int, default=20, help="Replay trials per object.")
    parser.add_argument("--seed", type=int, default=0, help="Collection and fit seed.")
    parser.add_argument("--workers", type=int, default=None, help="Dask worker processes.")
    parser.add_argument(
        "--table", default=None, help="Simulated table to collect from (collect --table)."
    )
    parser.add_argument(
        "--object", action="append", default=None, help="Collect only these objects (repeat)."
    )
    parser.add_argument("--action-scale", type=float, default=1.0, help="collect --action-scale.")
    parser.add_argument(
        "--design",
        choices=("random", "shared"),
        default="random",
        help="collect --design: random (object by object) or shared (action by action, so the "
        "held-out touches of every object come last in time).",
    )
    parser.add_argument(
        "--policies", default="active,passive", help="Policies to compare (evaluate --policies)."
    )
    parser.add_argument("--json", action="store_true", help="Print the figures as JSON only.")
    args = parser.parse_args(argv)
    folder = Path(tempfile.mkdtemp(prefix="eval_replay."))
    collection = folder / "collection.csv"
    executable = str(Path(sys.executable).with_name("activetouch"))
    started = time.perf_counter()
    collect = [executable, "collect", "--sim", "--touches", str(args.touches)]
    collect += ["--action-scale", str(args.action_scale), "--design", args.design]
    collect += ["--table", args.table] if args.table else []
    for name in args.object or []:
        collect += ["--object", name]
    subprocess.run(
        [*collect, "--seed", str(args.seed), "--out", str(collection), "--force"],
        check=True,
        capture_output=True,
    )
    collect_s = time.perf_counter() - started
    data = read_training_csv(collection.read_text())
    fit_data, held_out = split(data, args.fit)
    started = time.perf_counter()
    model = fit_manifold(
        fit_data, args.latent_dim, np.random.default_rng(args.seed), FitOptions(restarts=2)
    )
    fit_s = time.perf_counter() - started
    model_path, held_path, report_path = (
        folder / "model.json",
        folder / "held_out.csv",
        folder / "report.json",
    )
    model_path.write_text(json.dumps(model_to_document(model)))
    held_path.write_text(write_training_csv(held_out))
    command = [executable, "evaluate", "--model", str(model_path), "--world", "replay"]
    command += ["--data", str(held_path), "--trials", str(args.trials)]
    command += ["--steps", str(args.touches - args.fit), "--seed", str(args.seed)]
    command += ["--policies", args.policies, "--json", "--out", str(report_path)]
    if args.workers:
        command += ["--workers", str(args.workers)]
    done = subprocess.run(command, capture_output=True, text=True)
    if done.returncode != 0:
        raise SystemExit(f"evaluate failed ({done.returncode}): {done.stderr[-2000:]}")
    report = json.loads(done.stdout)
    figures = {
        "benchmark": "eval_replay",
        "table": args.table or "default",
        "action_scale": args.action_scale,
        "design": args.design,
        "objects": list(data.object_names),
        "touches_per_object": args.touches,
        "fit_touches_per_object": args.fit,
        "held_out_per_object": args.touches - args.fit,
        "latent_dim": args.latent_dim,
        "collect_s": collect_s,
        "fit_s": fit_s,
        "evaluate_s": report["seconds"],
        "trials_per_object": args.trials,
        "steps": report["steps"],
        "notes": report["notes"],
        "comparison": report["comparison"],
        "policies": {
            name: {
                "accuracy_by_touch": s["accuracy_by_touch"],
                "accuracy_interval": s["accuracy_interval"],
                "per_object": {o: v["accuracy"] for o, v in s["per_object"].items()},
                "median_touches_to_confidence": s["median_touches_to_confidence"],
            }
            for name, s in report["policies"].items()
        },
        "files": str(folder),
    }
    if args.json:
        sys.stdout.write(json.dumps(figures) + "\n")
    else:
        print(
            f"collected {args.touches} touches of {len(data.object_names)} objects in "
            f"{collect_s:.1f} s; fitted on the first {args.fit} (ds={args.latent_dim}) in "
            f"{fit_s:.1f} s; replayed the other {args.touches - args.fit}"
        )
        for name, s in figures["policies"].items():
            curve = " ".join(f"{100 * a:.1f}" for a in s["accuracy_by_touch"])
            print(f"{name:>8s} accuracy % by touch: {curve}")
        print(report["comparison"])
    return figures


if __name__ == "__main__":
    main()
