"""Benchmark: time to a model — wall time of ``fit --latent-dim auto``, serial and on workers.

A random design (every touch its own action) from
:func:`core.evaluation.worlds.random_experiment2_world` (true ds = 3, dx = 1) sampled at
``--objects`` × ``--touches`` (default 20 × 40, N = 800), for each ``--dy``. The run is what
``activetouch fit --latent-dim auto`` does: cross-validation of ds with warm folds
(:func:`core.selection.latent_selection.select_latent_dim` with ``refit``: every candidate fitted
on all the touches with the independent noise model, :class:`app.services.fit_tasks.FoldFit`,
then each fold refitted from it), then the final model at the chosen ds with the noise model
``auto`` from the candidate's fit (only the correlated refit runs): in process, or on a
``LocalCluster`` of ``--workers`` single-threaded processes
(:class:`app.services.fit_tasks.FitEngine`: the candidates' fits and the folds as tasks, the
starts of every fit as tasks of their own; the cluster's start-up is included). ``--cold`` runs
the selection as before warm folds: every fold's candidates fitted nested from scratch, then a
complete final fit.

Printed per dy and worker count: the wall seconds of the selection, of the final fit and of the
calibration that follows every fit (here the latent uncertainty's Laplace step), the ds
chosen, the final log-likelihood, and whether the cluster chose the same ds with the same fold
scores as the serial run; serially also the likelihood evaluations in units of one evaluation
with gradient on all N touches (``bench.fit_n800.full_equivalents``: deterministic, the fair
figure on a shared machine) of the fits on all the touches, the folds and the final fit, and
every candidate's mean held-out score. ``--fixed-ds K`` times one fit at ds = K instead (no
selection).

BLAS runs on one thread in this process, as ``activetouch fit`` runs it, and in the workers.
The machine is shared: the load average before and after each run is printed; quote it.

Run: ``.venv/bin/python -m bench.time_to_model [--dy 5 20] [--workers 0 2] [--objects 20]
[--touches 40] [--max-dim 5] [--folds 5] [--restarts 4] [--seed 0] [--fixed-ds K]
[--threads T] [--cold] [--kernels per_feature|tied]``
(``--workers 0``: serial).
"""

from __future__ import annotations

import argparse
import contextlib
import os
import time

import numpy as np
from threadpoolctl import threadpool_limits

from app.config import available_cores
from app.services.fit_tasks import FitEngine, FoldFit
from bench.fit_n800 import _COUNTS, full_equivalents, instrument
from core.evaluation.worlds import random_experiment2_world, sample_dataset
from core.gp import FitOptions, iter_fit
from core.recognition import calibrate
from core.selection import LatentSelection, select_latent_dim, serial_map, serial_warm_map
from core.types import ManifoldModel, TrainingData

TRUE_DIM = 3


def make_data(objects: int, touches: int, dy: int, seed: int) -> TrainingData:
    """The benchmark's training touches: a random design, dx = 1, true ds = 3."""
    rng = np.random.default_rng(seed)
    world = random_experiment2_world(
        rng, n_objects=objects, latent_dim=TRUE_DIM, action_dim=1, observation_dim=dy
    )
    return sample_dataset(world, rng, touches_per_object=touches)


def _equivalents(data: TrainingData) -> float:
    """The evaluations counted so far in this process, in full-data equivalents; resets."""
    total = sum(full_equivalents(_COUNTS, data.n_touches, data.observation_dim).values())
    _COUNTS.clear()
    return total


def time_to_model(
    data: TrainingData,
    options: FitOptions,
    workers: int,
    max_dim: int,
    folds: int,
    seed: int,
    fixed_ds: int | None = None,
    cold: bool = False,
) -> tuple[LatentSelection | None, float, float, float, float, int, dict[str, float]]:
    """(selection, selection seconds, final-fit seconds, calibration seconds, final
    log-likelihood, ds, evaluation equivalents by stage — counted in this process only, so
    serially) of one run (no selection at ``fixed_ds``). The calibration is the step that
    follows every fit (:func:`core.recognition.calibrate`: here, without placements or times,
    the latent uncertainty)."""
    rng = np.random.default_rng(seed)
    counts: dict[str, float] = {}
    _COUNTS.clear()
    started = time.perf_counter()
    with contextlib.ExitStack() as stack:
        engine = stack.enter_context(FitEngine(workers, None)) if workers > 0 else None
        selection = None
        if fixed_ds is None:
            fit = FoldFit(options, "independent")

            def rung_done(ds: int, log_likelihood: float) -> None:
                counts[f"ds={ds} on all"] = _equivalents(data)

            selection = select_latent_dim(
                data,
                fit,
                rng,
                tuple(range(1, min(max_dim, data.n_objects - 1) + 1)),
                n_folds=folds,
                map=serial_map if engine is None else engine.fold_map,
                refit=None if cold else fit.refit,
                warm_map=serial_warm_map if engine is None else engine.warm_map,
                rung_callback=rung_done,
            )
            counts["folds"] = _equivalents(data)
        ds = selection.chosen if selection is not None else int(fixed_ds or 1)
        selected = time.perf_counter()
        done_before = None if selection is None else selection.chosen_model
        model: ManifoldModel | None = None
        for event in iter_fit(
            data,
            ds,
            rng,
            options,
            "auto",
            None if engine is None else engine.start_map,
            fitted=done_before,
        ):
            model = event.model if event.model is not None else model
        assert model is not None
        counts["final"] = _equivalents(data)
        fitted = time.perf_counter()
        calibrate(model, options, rng)
    return (
        selection,
        selected - started,
        fitted - selected,
        time.perf_counter() - fitted,
        float(model.log_likelihood),
        ds,
        counts,
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dy", type=int, nargs="+", default=[5, 20])
    parser.add_argument("--workers", type=int, nargs="+", default=[0, 2])
    parser.add_argument("--objects", type=int, default=20)
    parser.add_argument("--touches", type=int, default=40)
    parser.add_argument("--max-dim", type=int, default=5)
    parser.add_argument("--folds", type=int, default=5)
    parser.add_argument("--restarts", type=int, default=FitOptions().restarts)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--fixed-ds", type=int, default=None, help="one fit at this ds")
    parser.add_argument(
        "--threads",
        type=int,
        default=available_cores(),
        help="feature threads of this process's evaluations (default, as the CLI: the cores "
        "it may use; 1 in the workers)",
    )
    parser.add_argument(
        "--cold", action="store_true", help="the selection without warm folds (as before them)"
    )
    parser.add_argument(
        "--kernels",
        choices=("per_feature", "tied"),
        default=FitOptions().kernels,
        help="length-scales per feature, or shared by the features (docs/fitting.md 'Tied "
        "kernels')",
    )
    args = parser.parse_args()
    instrument()
    options = FitOptions(restarts=args.restarts, threads=args.threads, kernels=args.kernels)
    # BLAS on one thread in this process, as `activetouch fit` runs it: otherwise the serial
    # run's NumPy calls (the tied kernels' eigh, every GEMM) take both cores and "serial" is not.
    with threadpool_limits(limits=1):
        run(args, options)


def run(args: argparse.Namespace, options: FitOptions) -> None:
    """Every figure of the module docstring, for ``args``' cases."""
    print(
        f"{args.objects} objects x {args.touches} touches, dx = 1, true ds = {TRUE_DIM}, "
        f"candidates 1..{args.max_dim}, {args.folds} folds, restarts {args.restarts}, "
        f"{os.cpu_count()} cores, {args.threads} feature thread(s), data seed {args.seed}, "
        f"{'cold' if args.cold else 'warm'} folds, kernels {args.kernels}"
    )
    print(
        " dy workers  select_s  final_s  calib_s  total_s  chosen  log-lik    same"
        "  load before/after"
    )
    for dy in args.dy:
        data = make_data(args.objects, args.touches, dy, args.seed)
        serial: LatentSelection | None = None
        for workers in args.workers:
            before = os.getloadavg()[0]
            selection, select_s, final_s, calib_s, log_likelihood, ds, counts = time_to_model(
                data,
                options,
                workers,
                args.max_dim,
                args.folds,
                args.seed,
                args.fixed_ds,
                args.cold,
            )
            after = os.getloadavg()[0]
            if workers == 0:
                serial = selection
            same = "-" if serial is None or workers == 0 else str(selection == serial)
            print(
                f"{dy:3d} {workers:7d} {select_s:9.1f} {final_s:8.1f} {calib_s:8.1f} "
                f"{select_s + final_s + calib_s:8.1f} {ds:7d} {log_likelihood:9.2f} "
                f"{same:>5s}  {before:.1f}/{after:.1f}",
                flush=True,
            )
            if workers == 0:
                print(
                    "    evaluation equivalents (N = "
                    f"{data.n_touches}): "
                    + ", ".join(f"{k} {v:.0f}" for k, v in counts.items())
                    + f"; total {sum(counts.values()):.0f}"
                )
            if selection is not None:
                print(
                    "    held-out nats/touch: "
                    + ", ".join(
                        f"ds={c.latent_dim} {c.mean:.4f}±{c.standard_error:.4f}"
                        for c in selection.candidates
                    )
                    + f"; {selection.explanation}",
                    flush=True,
                )


if __name__ == "__main__":
    main()
