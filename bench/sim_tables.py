"""Benchmark: on a simulated table, which actions separate the objects, and does choosing them pay?

Two parts, both on the in-process simulated rig (the real drivers, the DMP actions dx = 6, the
five tactile channels):

1. **Sensitivity** (``--part sensitivity``): for every pair of objects of the table, the
   noise-free mean responses at the teaching action x = 0 and at ±``reach`` along each action
   dimension (the DMP action: x_0..x_2 the three dominant FFJ3 flexion weights, x_3..x_5 the
   FFJ4 abduction ones), and their separation d(x) = √(Δ(x)ᵀ Σ⁻¹ Δ(x)) in units of the
   touch-to-touch noise (Σ: the covariance of repeated noisy touches with x = 0, pooled over the
   objects). d(x) ≈ 1 means one touch at x tells the pair apart about as well as one standard
   deviation; the per-dimension slope (d(+r e_j) − d(−r e_j)) / 2r says which dimension
   separates them.
2. **Recognition** (``--part trials``): a training set as ``activetouch collect --sim --table
   NAME --touches N --design random`` makes it (x ~ N(0, scale² I) afresh per touch), a ds = 2
   fit, then recognition trials for the active, discriminative and passive policies, and the
   accuracy after each touch, overall and per object. The trials are an evaluation's
   (:func:`policy_records`, on :class:`app.evaluation.context.TrialContext`): every observation
   is a real touch of a fresh simulated rig per trial (as ``activetouch evaluate --world rig``),
   or with ``--source gp`` a draw from the learned GP.

Run: ``.venv/bin/python -m bench.sim_tables --table lookalike_cups [--part both]
[--touches 100] [--action-scale 1] [--trials 10] [--steps 10] [--seed 0] [--json]``
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import sys
import time
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from threadpoolctl import threadpool_limits

from app.evaluation.context import TrialContext
from app.evaluation.spec import PLACEMENTS, EvaluationSpec, Placement
from app.rig.actions import TouchActions
from core.evaluation import TrialOutcome, TrialRecord, random_design, summarise
from core.gp import FitOptions, fit_manifold
from core.recognition import EVALUATION_POLICIES, ActionBox
from core.types import ManifoldModel, TrainingData
from core.validation import FloatArray
from hardware.rig import RigConfig
from hardware.sim.materials import get_table
from hardware.sim.noise import NO_DRIFT, NoiseModel
from hardware.sim.rig import in_process_rig

QUIET = NoiseModel(
    channel_std=(0.0,) * 5,
    contact_std=(0.0,) * 5,
    drift=NO_DRIFT,
    placement_std_deg=0.0,
    slip_std_deg=0.0,
    object_temperature_std_c=0.0,
)
"""No noise at all: the mean responses (up to the heat history of earlier touches)."""

CONFIDENCE = 0.95
"""The confidence level handed to :func:`core.evaluation.summary.summarise` (its accuracies do
not depend on it)."""


def touch_all(
    objects: tuple[str, ...],
    actions: TouchActions,
    xs: FloatArray,
    noise: NoiseModel | None,
    seed: int,
) -> FloatArray:
    """Every object touched with every action (action-major). Shape (L, len(xs), dy).

    One warm-up round with x = 0 comes first (discarded): the sensor skin starts at its core
    temperature, and the first touches would otherwise carry that transient.
    """
    sim = in_process_rig(objects, seed=seed, noise=noise, rig_config=RigConfig())
    out = np.empty((len(objects), len(xs), 5))
    try:
        with sim.rig.acquire("bench.sim_tables") as lease:
            lease.connect()
            for slot in range(len(objects)):
                actions.touch(lease, np.zeros(actions.action_dim), slot=slot)
            for i, x in enumerate(xs):
                for slot in range(len(objects)):
                    out[slot, i] = actions.touch(lease, x, slot=slot).observation
    finally:
        sim.close()
    return out


@dataclass(frozen=True)
class PairSensitivity:
    """How well one touch separates two objects, at x = 0 and along each action dimension."""

    pair: tuple[str, str]
    at_teaching: float
    minus: tuple[float, ...]
    plus: tuple[float, ...]
    reach: float

    @property
    def slopes(self) -> tuple[float, ...]:
        """(d(+r e_j) − d(−r e_j)) / 2r per dimension."""
        return tuple((p - m) / (2 * self.reach) for m, p in zip(self.minus, self.plus, strict=True))

    @property
    def best(self) -> float:
        """The largest separation over the probed actions."""
        return max(self.at_teaching, *self.minus, *self.plus)


def sensitivity(
    table: str, actions: TouchActions, reach: float, repeats: int, seed: int
) -> tuple[list[PairSensitivity], FloatArray]:
    """Separation of every pair of the table's objects (see the module docstring).

    Returns:
        One record per pair, and the touch noise covariance Σ (5, 5).
    """
    objects = get_table(table).objects
    dx = actions.action_dim
    probes = [np.zeros(dx)]
    for j in range(dx):
        probes += [-reach * np.eye(dx)[j], reach * np.eye(dx)[j]]
    clean = touch_all(objects, actions, np.array(probes), QUIET, seed)
    noisy = touch_all(objects, actions, np.zeros((repeats, dx)), None, seed + 1)
    residual = (noisy - noisy.mean(axis=1, keepdims=True)).reshape(-1, 5)
    cov = residual.T @ residual / (residual.shape[0] - len(objects))
    precision = np.linalg.inv(cov)
    records = []
    for a, b in itertools.combinations(range(len(objects)), 2):
        delta = clean[a] - clean[b]  # (probes, dy)
        d = np.sqrt(np.einsum("pi,ij,pj->p", delta, precision, delta))
        records.append(
            PairSensitivity(
                (objects[a], objects[b]),
                float(d[0]),
                tuple(float(v) for v in d[1::2]),
                tuple(float(v) for v in d[2::2]),
                reach,
            )
        )
    return records, cov


def collect_training(
    table: str,
    actions: TouchActions,
    touches: int,
    scale: float,
    seed: int,
    noise: NoiseModel | None = None,
    interleave: bool = False,
) -> TrainingData:
    """A random-design training set on the simulated rig (object by object, as ``collect``;
    with ``interleave``, round-robin over the objects, so slow drift is spread evenly)."""
    objects = get_table(table).objects
    dx = actions.action_dim
    design = random_design(
        len(objects), touches, np.zeros(dx), scale**2 * np.eye(dx), np.random.default_rng(seed)
    )
    sim = in_process_rig(objects, seed=seed, rig_config=RigConfig(), noise=noise)
    observations = np.empty((design.actions.shape[0], 5))
    order = np.arange(design.actions.shape[0])
    if interleave:
        order = order.reshape(len(objects), touches).T.reshape(-1)
    try:
        with sim.rig.acquire("bench.sim_tables") as lease:
            lease.connect()
            for k in order:
                obj, x = design.object_index[k], design.actions[k]
                observations[k] = actions.touch(lease, x, slot=int(obj)).observation
    finally:
        sim.close()
    return TrainingData(objects, design.object_index, design.actions, observations)


def policy_records(
    model: ManifoldModel,
    policy: str,
    n_trials: int,
    steps: int,
    seed: int,
    *,
    source: str,
    table: str,
    box: ActionBox | None = None,
    noise: NoiseModel | None = None,
    placement: Placement = "trial",
) -> list[TrialOutcome]:
    """``n_trials`` trials of every model object, run by the evaluation engine.

    An evaluation of world ``rig`` (every observation a touch of a fresh simulated rig seeded
    from the trial, as ``activetouch evaluate --world rig``; ``placement`` ``"touch"`` places the
    object anew before every touch, ``"trial"`` once per trial) or, with ``source="gp"``, of world
    ``model`` (draws from the learned GP, the paper's protocol), T = ``steps``, no early stop,
    seed ``seed``. ``box`` narrows where the planner acts, ``noise`` the simulated rig's noise
    model; both are the evaluation's defaults when ``None``.
    """
    spec = EvaluationSpec(
        world="model" if source == "gp" else "rig",
        trials_per_target=n_trials,
        steps=steps,
        policies=(policy,),
        seed=seed,
        table=table if source != "gp" else None,
        tolerance=0.0,
        placement=placement,
    )
    context = TrialContext(model, spec, box=box, rig_noise=noise)
    return context.run_many(context.trial_keys())


def trials(
    table: str,
    data: TrainingData,
    n_trials: int,
    steps: int,
    seed: int,
    log: Any,
    noise: NoiseModel | None = None,
    box_std: float = 0.0,
    source: str = "rig",
    placement: Placement = "trial",
) -> dict[str, Any]:
    """Fit ds = 2, then trials per policy (observations from the rig or the learned GP);
    accuracy by touch, overall and per object."""
    start = time.perf_counter()
    model = fit_manifold(data, 2, np.random.default_rng(seed), FitOptions())
    fit_s = time.perf_counter() - start
    log(f"fit: {fit_s:.1f} s, log-likelihood {model.log_likelihood:.1f}")
    results: dict[str, Any] = {"fit_s": fit_s, "log_likelihood": model.log_likelihood}
    box = None
    if box_std > 0:
        centre, spread = data.actions.mean(axis=0), data.actions.std(axis=0)
        box = ActionBox(centre - box_std * spread, centre + box_std * spread)
    for name in EVALUATION_POLICIES:
        begin = time.perf_counter()
        outcomes = policy_records(
            model,
            name,
            n_trials,
            steps,
            seed + 100,
            source=source,
            table=table,
            box=box,
            noise=noise,
            placement=placement,
        )
        # A trial whose touch the rig refused has no answer; it is counted apart.
        records = [r for r in outcomes if isinstance(r, TrialRecord)]
        summary = summarise(records, model.object_names, steps, CONFIDENCE)[name]
        by_touch = np.asarray(summary["accuracy_by_touch"])
        object_by_touch = {
            n: summarise(
                [r for r in records if r.target == n], model.object_names, steps, CONFIDENCE
            )[name]["accuracy_by_touch"]
            for n in model.object_names
        }
        results[name] = {
            "accuracy_by_touch": by_touch.tolist(),
            "final_accuracy_per_object": {
                n: summary["per_object"][n]["accuracy"] for n in model.object_names
            },
            "accuracy_by_touch_per_object": object_by_touch,
            "trials": len(records),
            "refused": len(outcomes) - len(records),
            "wall_s": time.perf_counter() - begin,
        }
        log(
            f"{name:>14}: accuracy by touch "
            + " ".join(f"{v:.2f}" for v in by_touch)
            + f"  ({time.perf_counter() - begin:.0f} s"
            + (f", {len(outcomes) - len(records)} refused" if len(outcomes) > len(records) else "")
            + ")"
        )
        for obj, values in object_by_touch.items():
            log(f"{'':>14}  {obj:>16}: " + " ".join(f"{v:.2f}" for v in values))
    return results


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--table", default="lookalike_cups")
    parser.add_argument("--part", choices=("sensitivity", "trials", "both"), default="both")
    parser.add_argument("--touches", type=int, default=100, help="Training touches per object.")
    parser.add_argument("--action-scale", type=float, default=1.0, help="Design std per dim.")
    parser.add_argument("--trials", type=int, default=10, help="Trials per object and policy.")
    parser.add_argument("--steps", type=int, default=10, help="T, touches per trial.")
    parser.add_argument("--repeats", type=int, default=12, help="Noisy touches for Σ.")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--no-drift", action="store_true", help="Switch the slow drift off.")
    parser.add_argument(
        "--placement",
        choices=PLACEMENTS,
        default="trial",
        help="In rig trials, place the object once per trial or anew before every touch "
        "(as activetouch evaluate --placement).",
    )
    parser.add_argument(
        "--reseat-each-touch",
        dest="placement",
        action="store_const",
        const="touch",
        help="The old spelling of --placement touch.",
    )
    parser.add_argument(
        "--no-session-effects",
        action="store_true",
        help="No drift and no placement/slip/object-temperature spread: only the per-touch "
        "noise (frame noise and contact offsets) remains.",
    )
    parser.add_argument(
        "--box-std",
        type=float,
        default=0.0,
        help="Plan within mean ± this many std of the training actions (0: their full range).",
    )
    parser.add_argument("--data", help="Training set cache (.npz): loaded if present, else saved.")
    parser.add_argument(
        "--source",
        choices=("rig", "gp"),
        default="rig",
        help="Trial observations: touches of the simulated rig, or draws from the learned GP.",
    )
    parser.add_argument(
        "--interleave", action="store_true", help="Collect round-robin over the objects."
    )
    parser.add_argument("--json", action="store_true", help="Print one JSON document.")
    args = parser.parse_args(argv)

    def log(message: str) -> None:
        print(message, file=sys.stderr if args.json else sys.stdout, flush=True)

    get_table(args.table)
    actions = TouchActions.from_teaching()
    report: dict[str, Any] = {"table": args.table, "settings": vars(args)}
    # The probes reach the edge of where a random design of this scale puts actions (±2.5σ).
    reach = 2.5 * args.action_scale
    with threadpool_limits(1):
        if args.part in ("sensitivity", "both"):
            records, cov = sensitivity(args.table, actions, reach, args.repeats, args.seed)
            log(f"table {args.table}: separation d (noise std units) of each pair, one touch")
            log(f"touch noise std: {' '.join(f'{v:.3g}' for v in np.sqrt(np.diag(cov)))}")
            header = " ".join(f"  -x{j}   +x{j}" for j in range(actions.action_dim))
            log(f"{'pair':>34}  x=0   {header}")
            for r in records:
                cells = " ".join(f"{m:5.1f} {p:5.1f}" for m, p in zip(r.minus, r.plus, strict=True))
                log(f"{' / '.join(r.pair):>34} {r.at_teaching:5.1f}  {cells}")
            report["noise_cov"] = cov.tolist()
            report["sensitivity"] = [
                {**r.__dict__, "slopes": r.slopes, "pair": list(r.pair)} for r in records
            ]
        if args.part in ("trials", "both"):
            start = time.perf_counter()
            noise = replace(NoiseModel(), drift=NO_DRIFT) if args.no_drift else None
            if args.no_session_effects:
                noise = replace(
                    NoiseModel(),
                    drift=NO_DRIFT,
                    placement_std_deg=0.0,
                    slip_std_deg=0.0,
                    object_temperature_std_c=0.0,
                )
            if args.data and os.path.exists(args.data):
                cached = np.load(args.data)
                data = TrainingData(
                    get_table(args.table).objects,
                    cached["object_index"],
                    cached["actions"],
                    cached["observations"],
                )
            else:
                data = collect_training(
                    args.table,
                    actions,
                    args.touches,
                    args.action_scale,
                    args.seed,
                    noise,
                    args.interleave,
                )
                if args.data:
                    np.savez(
                        args.data,
                        object_index=data.object_index,
                        actions=data.actions,
                        observations=data.observations,
                    )
            log(f"collected {data.n_touches:d} touches in {time.perf_counter() - start:.0f} s")
            report["trials"] = trials(
                args.table,
                data,
                args.trials,
                args.steps,
                args.seed,
                log,
                noise,
                args.box_std,
                args.source,
                args.placement,
            )
    if args.json:
        sys.stdout.write(json.dumps(report) + "\n")


if __name__ == "__main__":
    main()
