"""The settings of a manifold fit (:class:`FitOptions`) and its progress events
(:class:`FitProgress`); the fit itself is :mod:`core.gp.manifold` / :mod:`core.gp.fit_run`."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from core.errors import InvalidInputError
from core.gp.posterior import STRUCTURES, Structure
from core.gp.sparse import DEFAULT_INDUCING_POINTS
from core.gp.tied_likelihood import KERNELS, Kernels, refuse_structured
from core.types import ManifoldModel
from core.validation import FloatArray

Optimizer = Literal["lbfgs", "de"]
OPTIMIZERS: tuple[str, ...] = ("lbfgs", "de")


@dataclass(frozen=True)
class FitOptions:
    """Settings of :func:`iter_fit` / :func:`fit_manifold`.

    Attributes:
        optimizer: ``"lbfgs"`` (data-driven starts + random restarts, L-BFGS-B) or ``"de"``
            (the same, plus one differential-evolution start polished with L-BFGS-B).
        restarts: Random restarts on top of the data-driven starts (≥ 0).
        max_iterations: L-BFGS-B iteration limit of each joint optimisation (≥ 1).
        hyperparameter_iterations: Iteration limit of the data-driven starts' first stage,
            hyperparameters with S frozen (≥ 0; 0 skips the stage).
        ftol: L-BFGS-B relative reduction tolerance (> 0).
        gtol: L-BFGS-B projected-gradient tolerance (> 0).
        screen_touches_per_object: Touches per object in the screening subsample (0 = no
            screening; otherwise ≥ 2). Where the subsample would not make an evaluation at
            least :data:`core.gp.fit_run.SCREEN_MIN_SAVING` times cheaper, screening runs on all
            the data (see :mod:`core.gp.fit_run`).
        screen_iterations: L-BFGS-B iteration limit of each start on the screening subsample
            (≥ 1); starts still crawling then are not promising.
        polish_starts: How many of the best screened starts (ranked by their likelihood on
            all the data) are optimised on all the data at least (≥ 1; more when an
            unpolished start looks better than every polished one, see the module docstring).
        latent_bound: Latents are boxed in [-latent_bound, latent_bound] during the fit
            (starts have unit spread; > 0).
        initial_latent_lengthscale: Initial latent length-scale in units of the latent spread
            (> 0).
        de_population: Population size multiplier of differential evolution (scipy's
            ``popsize``, ≥ 1).
        de_generations: Generations of differential evolution (≥ 1).
        progress_every: Yield a :class:`FitProgress` every this many optimiser iterations (≥ 1).
        structure: How the likelihood is evaluated (:func:`core.gp.posterior.resolve_structure`):
            ``"auto"`` (default) uses the exact Kronecker path when every object was touched
            with the same actions, the dense path otherwise, and the sparse variational path
            above :data:`core.gp.posterior.AUTO_SPARSE_ABOVE` touches; ``"dense"``,
            ``"kronecker"`` or ``"sparse"`` force one. The model is conditioned the same way.
            A Kronecker fit screens on a subsample of the design actions, the same for every
            object, so the screening data stay a shared design.
        n_inducing: Inducing points of the sparse path (≥ 1).
        hyperparameter_latent_lengthscales: Extra starting latent length-scales (in units of
            the latent spread, > 0) of every hyperparameter stage with S frozen, tried per
            feature beside the current ones (:mod:`core.gp.hyperparameter_fit`).
        stall_nats: Stop an L-BFGS-B run once -log p improved by less than this over
            ``stall_iterations`` iterations (≥ 0; 0 = never).
        stall_iterations: The window of the stall test (≥ 1).
        stall_relative: Also stop once the improvement over the window is below
            ``stall_relative · stall_iterations · |log p|`` (≥ 0; 0 = never) — the windowed
            analogue of ``ftol``. On large problems the latents then stop creeping along a
            flat ridge (measured at L=100 × M=100: −log p 0.14 % from where 3000 more
            iterations would take it).
        joint_lbfgs_memory: Correction pairs (scipy's ``maxcor``, ≥ 1) of the joint L-BFGS-B
            runs on all the data (the screening and hyperparameter stages keep scipy's 10).
            The joint problem has L·ds + dy·(2 + ds + dx) unknowns (140 at L=20, ds=5, dy=5)
            and ends in a long curved valley of latent length-scales. On
            ``bench/fit_n800.py``'s data (two seeds, ds = 2 and 5) 30 pairs instead of 10
            reached the same optima (within 0.6 nats) in 203-346 instead of 269-519
            evaluations. In the screening stage more pairs cost more evaluations (889
            instead of 738 at ds=2). The polish after a subsample screening uses
            ``polish_lbfgs_memory`` instead.
        screen_max_touches: Cap on the screening subsample's total size (0 = no cap): it takes
            at most ``max(2, screen_max_touches // L)`` touches per object, fewer than
            ``screen_touches_per_object`` when there are many objects. A dense evaluation
            costs ~N³, so 25 touches from each of 20 objects (N = 500) screen at a third of
            the cost of all N = 800 touches, not at the ~1/64 of a small subsample.
        joint_stall_nats: The stall test of the joint L-BFGS-B runs on all the data (the
            final optimisation of every polished start; of every start when nothing is
            screened), in place of ``stall_nats`` there (≥ 0; 0 = never). Those runs end
            the fit, so they stop once the remaining gain looks below about one nat, not
            a hundredth: on ``bench/fit_n800.py``'s data their last 19-45 % of evaluations
            gained under one nat (see :mod:`core.gp.fit_run`). The screening and
            hyperparameter stages keep ``stall_nats``: they only choose and prepare starts,
            and their paths are left as they were. On Experiment 1 (``bench/fit_speed.py``,
            ten seeds, joint runs of ~30 iterations) the same log-likelihoods, with 0-3
            more evaluations (the window is 30 iterations, not 20).
        joint_stall_iterations: The window of ``joint_stall_nats`` (≥ 1).
        polish_lbfgs_memory: Correction pairs of the joint runs on all the data that polish
            starts screened on a subsample (≥ 1); they start from fresh hyperparameters.
            On ``bench/fit_n800.py``'s data, with ``joint_stall_nats`` 0.5, 100 pairs
            instead of 30 took 121-215 joint evaluations instead of 120-284 (60: 144-239;
            200: 122-214) and ended 0.2-0.9 nats higher, within 0.2 nats of the 30-pair,
            hundredth-of-a-nat fits; on Experiment 1 nothing changed. Not used where
            screening runs on all the data (a shared design with many objects: there the
            polish continues from the screened parameters, and 100 pairs in every run on all
            the data moved a L=100 × M=60 Kronecker fit's end point by −55 and +582 nats on
            two seeds) nor without screening: ``joint_lbfgs_memory`` there. Pairs cost
            L-BFGS-B's own arithmetic ~O(pairs² · unknowns) per iteration: 100 add ~0.3 ms
            at 140 unknowns, ~1.2 ms at 2,000.
        restart_reach_iterations: The random restarts' screening runs give up once they
            cannot reach the best data-driven start's screened value at their pace over this
            many iterations (:func:`core.gp.hyperparameter_fit.minimize_free`'s ``reach``; ≥ 0,
            0 = never). The data-driven starts (and ``initial_latents``) are screened first,
            so which random starts give up does not depend on where the starts run; a start
            that gave up still competes with its full-data value. Only while screening, and
            only against a data-driven start that is not degenerate (see
            :mod:`core.gp.fit_run`).
        threads: Python threads one likelihood evaluation on all the data (or the screening
            subsample) runs its features on (≥ 1; dense structure only): each feature's
            factorisation and inverse are independent LAPACK calls that release the GIL
            (:mod:`core.gp.likelihood`). The fit's result does not depend on it. Set it to
            the cores the process may use when it has them to itself, 1 in a Dask worker
            (the ``activetouch`` commands and the server do).
        kernels: ``"per_feature"`` (default): every feature has its own length-scales
            (docs/method.md (M1)). ``"tied"``: the features share ℓ^s and ℓ^x and keep their own
            σ_f² and σ_n², so one eigendecomposition per evaluation serves every feature
            (:mod:`core.gp.tied_likelihood`, docs/fitting.md "Tied kernels"): a different,
            smaller model, not an approximation, much cheaper per evaluation from dy ≈ 5 on.
            Every stage of the fit (starts, screening, restarts, polish, warm refits) then uses
            it; the fitted hyperparameters are per feature, the shared length-scales repeated.
            Dense only: with structure ``"kronecker"`` or ``"sparse"`` it is refused, and a
            placement effect is not put into a tied fit's likelihood
            (:func:`core.gp.placement_effect.with_placement_effect` keeps it for scoring).
        initial_latents: Extra starting latents, each of shape (L, ds) for the data and ds of
            the fit (checked when the fit starts; here: 2-D and finite). Each is normalised
            (centred, unit RMS spread) and treated like the data-driven starts: the
            hyperparameters are fitted with it frozen first, then it is screened and, if it
            ranks best, polished (:mod:`core.gp.fit_run`). Used e.g. to start ds = k from the
            ds = k - 1 optimum (:mod:`core.selection.latent_selection`). Stored as read-only float
            copies; excluded from ``==`` and ``hash`` (arrays have neither).
    """

    optimizer: Optimizer = "lbfgs"
    restarts: int = 4
    max_iterations: int = 3000
    hyperparameter_iterations: int = 200
    ftol: float = 1e-12
    gtol: float = 1e-6
    screen_touches_per_object: int = 25
    screen_iterations: int = 100
    polish_starts: int = 1
    latent_bound: float = 5.0
    initial_latent_lengthscale: float = 10.0
    de_population: int = 8
    de_generations: int = 40
    progress_every: int = 10
    structure: Structure = "auto"
    n_inducing: int = DEFAULT_INDUCING_POINTS
    hyperparameter_latent_lengthscales: tuple[float, ...] = (1.0,)
    stall_nats: float = 1e-2
    stall_iterations: int = 20
    stall_relative: float = 1e-6
    joint_lbfgs_memory: int = 30
    screen_max_touches: int = 0
    joint_stall_nats: float = 0.5
    joint_stall_iterations: int = 30
    polish_lbfgs_memory: int = 100
    restart_reach_iterations: int = 10
    threads: int = 1
    kernels: Kernels = "per_feature"
    initial_latents: tuple[FloatArray, ...] = field(default=(), compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "initial_latents", _checked_latents(self.initial_latents))
        if self.optimizer not in OPTIMIZERS:
            raise InvalidInputError(
                f"optimizer: expected one of {', '.join(OPTIMIZERS)}, received {self.optimizer!r}."
            )
        minimums = {
            "restarts": 0,
            "max_iterations": 1,
            "hyperparameter_iterations": 0,
            "screen_touches_per_object": 0,
            "screen_iterations": 1,
            "polish_starts": 1,
            "de_population": 1,
            "de_generations": 1,
            "progress_every": 1,
            "n_inducing": 1,
            "stall_iterations": 1,
            "joint_lbfgs_memory": 1,
            "screen_max_touches": 0,
            "joint_stall_iterations": 1,
            "polish_lbfgs_memory": 1,
            "restart_reach_iterations": 0,
            "threads": 1,
        }
        for name, minimum in minimums.items():
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | np.integer):
                raise InvalidInputError(f"{name}: expected an integer, received {value!r}.")
            if value < minimum:
                raise InvalidInputError(f"{name}: must be ≥ {minimum}, received {value}.")
        if self.structure not in STRUCTURES:
            raise InvalidInputError(
                f"structure: expected one of {', '.join(STRUCTURES)}, received {self.structure!r}."
            )
        if self.kernels not in KERNELS:
            raise InvalidInputError(
                f"kernels: expected one of {', '.join(KERNELS)}, received {self.kernels!r}."
            )
        if self.kernels == "tied":
            refuse_structured(self.structure)
        for name in ("stall_nats", "stall_relative", "joint_stall_nats"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | float | np.floating):
                raise InvalidInputError(f"{name}: expected a number, received {value!r}.")
            if not np.isfinite(value) or value < 0:
                raise InvalidInputError(f"{name}: must be a finite number ≥ 0, received {value}.")
        lengths = self.hyperparameter_latent_lengthscales
        if not isinstance(lengths, tuple) or not all(
            not isinstance(v, bool)
            and isinstance(v, int | float | np.floating)
            and np.isfinite(v)
            and v > 0
            for v in lengths
        ):
            raise InvalidInputError(
                "hyperparameter_latent_lengthscales: expected a tuple of finite numbers > 0, "
                f"received {lengths!r}."
            )
        if self.screen_touches_per_object == 1:
            raise InvalidInputError(
                "screen_touches_per_object: must be 0 (no screening) or ≥ 2, received 1."
            )
        for name in ("ftol", "gtol", "latent_bound", "initial_latent_lengthscale"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | float | np.floating):
                raise InvalidInputError(f"{name}: expected a number, received {value!r}.")
            if not np.isfinite(value) or value <= 0:
                raise InvalidInputError(f"{name}: must be a finite number > 0, received {value}.")


def _checked_latents(starts: object) -> tuple[FloatArray, ...]:
    """``initial_latents`` as read-only float copies; each must be a finite 2-D array."""
    if not isinstance(starts, tuple | list):
        raise InvalidInputError(
            "initial_latents: expected a tuple of (L, ds) arrays, received "
            f"{type(starts).__name__}."
        )
    checked = []
    for i, start in enumerate(starts):
        try:
            array = np.array(start, dtype=np.float64)
        except (TypeError, ValueError) as error:
            raise InvalidInputError(
                f"initial_latents[{i}]: expected an (L, ds) array of numbers, received "
                f"{type(start).__name__} ({error})."
            ) from None
        if array.ndim != 2 or array.shape[0] < 1 or array.shape[1] < 1:
            raise InvalidInputError(
                f"initial_latents[{i}]: expected shape (L, ds) with L, ds ≥ 1, received shape "
                f"{array.shape}."
            )
        if not np.all(np.isfinite(array)):
            raise InvalidInputError(
                f"initial_latents[{i}]: expected finite values, received "
                f"{int(np.sum(~np.isfinite(array)))} non-finite of {array.size}."
            )
        array.setflags(write=False)
        checked.append(array)
    return tuple(checked)


@dataclass(frozen=True)
class FitProgress:
    """One progress event of :func:`iter_fit`.

    Attributes:
        start: Index of the start being optimised (0 = data-driven; the DE start comes last).
        n_starts: Number of starts.
        iteration: Optimiser iterations of this start so far (generations for DE).
        log_likelihood: Current log-likelihood of this start, on the data the stage works
            on: the screening subsample in ``"screen"`` and ``"de"`` (and
            ``"hyperparameters"`` when screening), all the data in ``"joint"``.
        best_log_likelihood: Best full-data log-likelihood so far (-inf before any).
        phase: The stage: ``"hyperparameters"`` (data-driven starts, S frozen), ``"screen"``
            (joint, on the subsample), ``"de"``, ``"joint"`` (all the data); the same with
            ``" done"`` appended for the event that ends a stage; ``"done"`` for the final
            event.
        model: The fitted model, on the final event only.
        fraction: The share of the fit done, in [0, 1], from the stages that have ended
            (each weighted by its usual share of the evaluations; 1 on the final event). An
            estimate to show the time remaining from, not a measurement.
    """

    start: int
    n_starts: int
    iteration: int
    log_likelihood: float
    best_log_likelihood: float
    phase: str = "joint"
    model: ManifoldModel | None = None
    fraction: float = 0.0
