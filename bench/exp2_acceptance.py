"""Experiment 2 acceptance: on a simulated table, does active recognition beat passive on the rig?

Runs the evaluation engine (world ``rig``: every observation is a touch of the simulated rig) for
the given policies with a model fitted on a rig collection of that table, and prints per touch
the accuracy of each policy with its 95 % Wilson interval, per object at T, and the checks:

* after every touch, active ≥ passive within the intervals (active's upper bound ≥ passive's
  lower bound... stated strictly: active's upper bound is not below passive's lower bound);
* at some touch ≤ 5, active's accuracy exceeds passive's by ≥ 15 points;
* per object at T, active is not worse than passive beyond the intervals.

Run: ``python -m bench.exp2_acceptance --model M.json --table NAME [--trials 50] [--steps 10]
[--policies active,passive] [--workers 2] [--seed 0] [--out report.json]``
(``--trials`` is per object and policy: 50 × 4 objects = 200 trials per policy).

Measured (shared 2-core machine, ``--trials 50 --steps 6 --workers 2``, models: ds = 2 fits of
``activetouch collect --sim --table NAME --touches 100 --design random``): ``lookalike_cups``
active 54..64 %, passive 57..63 % (largest gap at a touch ≤ 5: 0.5 points; 193 s);
``textures`` active 45..57 %, discriminative 42..47 %, passive 44..52 % (largest gap 5 points;
251 s). Active is never below passive beyond the intervals, after any touch or per object, and
nowhere 15 points ahead (docs/results.md, "What choosing the touch buys").
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from app.cli.main import load_model
from app.evaluation.runner import run_evaluation
from app.evaluation.spec import EvaluationSpec
from core.evaluation import wilson_interval


def checks(summary: dict[str, Any], reference: str, other: str) -> dict[str, Any]:
    """The acceptance checks of ``reference`` (active) against ``other`` (passive)."""
    a, p = summary[reference], summary[other]
    every_touch = all(
        ai[1] >= pi[0]
        for ai, pi in zip(a["accuracy_interval"], p["accuracy_interval"], strict=True)
    )
    gaps = [
        100 * (x - y) for x, y in zip(a["accuracy_by_touch"], p["accuracy_by_touch"], strict=True)
    ]
    best_early = max(gaps[:5])
    per_object = {}
    for name, mine in a["per_object"].items():
        theirs = p["per_object"][name]
        lo_a, hi_a = wilson_interval(round(mine["accuracy"] * mine["trials"]), mine["trials"])
        lo_p, hi_p = wilson_interval(round(theirs["accuracy"] * theirs["trials"]), theirs["trials"])
        per_object[name] = {
            reference: [mine["accuracy"], lo_a, hi_a],
            other: [theirs["accuracy"], lo_p, hi_p],
            "worse_beyond_intervals": hi_a < lo_p,
        }
    return {
        "not_below_after_every_touch": every_touch,
        "gap_points_by_touch": gaps,
        "largest_gap_at_touch_le_5": best_early,
        "gap_ge_15_at_touch_le_5": best_early >= 15.0,
        "per_object": per_object,
        "never_worse_per_object": not any(v["worse_beyond_intervals"] for v in per_object.values()),
    }


def main(argv: list[str] | None = None) -> int:
    """Run the evaluation, print the figures and the checks."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", type=Path, required=True)
    parser.add_argument("--table", required=True)
    parser.add_argument("--trials", type=int, default=50)
    parser.add_argument("--steps", type=int, default=10)
    parser.add_argument("--policies", default="active,passive")
    parser.add_argument("--workers", type=int, default=None)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=None)
    parser.add_argument(
        "--placement", choices=("trial", "touch"), default="trial", help="Rig trials' placement."
    )
    args = parser.parse_args(argv)
    model = load_model(args.model)
    policies = tuple(p for p in args.policies.split(",") if p)
    spec = EvaluationSpec(
        world="rig",
        trials_per_target=args.trials,
        steps=args.steps,
        policies=policies,
        seed=args.seed,
        table=args.table,
        placement=args.placement,
    )
    done = [0]
    total = args.trials * len(policies) * len(model.object_names)

    def tick(_record: object) -> None:
        done[0] += 1
        if done[0] % 10 == 0 or done[0] == total:
            print(f"{done[0]}/{total} trials", file=sys.stderr, flush=True)

    report = run_evaluation(model, spec, workers=args.workers, on_trial=tick)
    summary = report.summary()
    document: dict[str, Any] = {
        "table": args.table,
        "placement": args.placement,
        "seconds": report.seconds,
        "workers": report.workers,
        "trials_per_policy": args.trials * len(model.object_names),
        "report": report.to_dict(include_trials=False),
    }
    for other in policies:
        if other == "passive":
            continue
        if "passive" in policies:
            document[f"checks_{other}_vs_passive"] = checks(summary, other, "passive")
    print(f"table {args.table}: {report.seconds:.0f} s, {report.workers} workers")
    for policy, figures in summary.items():
        cells = [
            f"{100 * a:.0f} [{100 * lo:.0f},{100 * hi:.0f}]"
            for a, (lo, hi) in zip(
                figures["accuracy_by_touch"], figures["accuracy_interval"], strict=True
            )
        ]
        print(f"{policy:>15}: " + "  ".join(cells))
        objects = ", ".join(
            f"{name} {100 * v['accuracy']:.0f}" for name, v in figures["per_object"].items()
        )
        print(f"{'':>15}  per object at T: {objects}")
    print(report.comparison())
    for key, value in document.items():
        if key.startswith("checks_"):
            print(
                f"{key}: every touch {value['not_below_after_every_touch']}, "
                f"largest gap ≤ touch 5 {value['largest_gap_at_touch_le_5']:.1f} points, "
                f"never worse per object {value['never_worse_per_object']}"
            )
    if args.out is not None:
        args.out.write_text(json.dumps(document, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
