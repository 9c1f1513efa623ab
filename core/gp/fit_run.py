"""How a manifold fit runs: starts, screening, differential evolution, choice, normalisation.

The engine behind :func:`core.gp.manifold.iter_fit` (:class:`FitRun`), for the objective of
docs/method.md (M2). The measurements behind each choice below are in docs/fitting.md.

1. **Starts.** The first starts are data-driven (:func:`core.gp.initialisation.data_driven_starts`:
   the PCA of the object profiles, and their Isomap from 8 objects on); the caller's
   ``FitOptions.initial_latents`` (normalised) join them; R more draw S ~ N(0, I)
   (``FitOptions.restarts``). Every start has unit latent spread, the data-relative initial
   hyperparameters of :func:`core.gp.parameters.initial_hyperparameters` and latent length-scales
   about 10× the spread. Data-driven starts first fit the hyperparameters with S frozen (one
   small problem per feature, :mod:`core.gp.hyperparameter_fit`), then everything jointly; random
   starts go straight to the joint fit, because hyperparameters fitted to frozen random latents
   adapt to a meaningless arrangement and slow the joint fit down.
2. **Screening.** When some object has more touches than ``screen_touches_per_object``, every
   start is first optimised (at most ``screen_iterations``) on one random subsample of that many
   touches per object, which makes an evaluation about (N/n)³ cheaper. The ``polish_starts``
   best screened starts — ranked by their likelihood on *all* the data at the screened
   parameters, since the subsample's own likelihood can rank a poor start first — are then
   optimised on all the data from their screened latents with fresh hyperparameters
   (hyperparameters fitted to a subsample transfer badly, see :meth:`FitRun._transfer`): the
   hyperparameters alone first, then jointly, because a joint fit from fresh hyperparameters can
   throw every latent length-scale onto its lower bound (K^s = I, a flat corner L-BFGS-B never
   leaves). The data-driven starts are screened first; a random restart then gives up once
   it cannot come within :data:`REACH_MARGIN_NATS` of the best of them that is not degenerate
   at its current pace (``FitOptions.restart_reach_iterations``). When the subsample would
   make an evaluation less than :data:`SCREEN_MIN_SAVING` times cheaper
   (:func:`evaluation_cost`: many objects on a shared design, where the L × L latent
   factorisations dominate), screening runs on all the data instead.
3. **Differential evolution** (``optimizer="de"``): one more start, a
   :func:`scipy.optimize.differential_evolution` search over the same bounded vector on the
   screening data (value only), seeded with the best start so far, refined with L-BFGS-B and
   polished on all the data.
4. **Choice.** The best full-data likelihood among the polished starts wins, unless it is
   *degenerate* and a non-degenerate polished start exists. The next screened start is polished
   too while every polished start is degenerate, or while its full-data likelihood at its
   screened parameters beats the best polished one (so no unpolished start looks better than
   the winner). Degenerate: some latent length-scale sits on its lower bound (objects
   uncorrelated in a feature), or every feature's length-scale of some latent dimension sits on
   its upper bound (an unused dimension). ``FitDiagnostics.starts_log_likelihood`` holds every
   start's full-data log-likelihood.
5. **Normalisation.** Latents are centred and scaled to RMS distance 1 from their centre, and the
   latent length-scales divided by the same factor, which leaves the likelihood unchanged; the
   model is built with :func:`core.gp.posterior.condition`.

Every L-BFGS-B run also stops once it stalls (``FitOptions.stall_nats`` / ``stall_relative``):
gains of hundredths of a nat per iteration along a flat ridge would otherwise cost most of the
iterations. The joint runs on all the data, which end the fit, use the looser
``joint_stall_nats`` / ``joint_stall_iterations``; the screening and hyperparameter stages keep
the tighter rule, so the starts and their choice do not depend on it.

**Starts elsewhere.** The first stage of every start (1.: its hyperparameters with S frozen, then
its joint run on the screening data) depends only on the start's vector and on the problem, so
the starts are independent: :func:`first_stage` is one start's work, a pure function of a
:class:`StartPlan` (shared by every start) and a :class:`StartTask`, and a ``start_map``
(:data:`StartMap`) may run them elsewhere, e.g. as Dask tasks (the app's
``app.services.fit_tasks``); the fit is then the serial one, only the progress events within a
start are not streamed. Without a map the starts run one after another in this process, with
progress every ``progress_every`` iterations.

The likelihood is exactly invariant to scaling one latent dimension of S together with every
feature's ℓ^s of that dimension (and to shifting S); its gradient is orthogonal to those
directions (tests/core/test_likelihood.py), so the fit leaves the symmetry alone and normalises
at the end (5.).

**Tied kernels** (``FitOptions.kernels = "tied"``): every problem's likelihood (all the data,
the screening subsample) is :class:`core.gp.tied_likelihood.TiedLikelihood` on a tied layout,
and the hyperparameter stage with S frozen is one problem over every hyperparameter
(:func:`core.gp.hyperparameter_fit.iter_fit_jointly`: the shared length-scales couple the
features); the stages are otherwise the same (docs/fitting.md, "Tied kernels").

Bounds (log space, relative to the data): see :func:`core.gp.parameters.parameter_bounds`.
"""

from __future__ import annotations

import copy
import dataclasses
from collections.abc import Callable, Generator, Iterable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.optimize

from core.errors import ConvergenceError, InvalidInputError, NotPositiveDefiniteError
from core.gp.fit_options import FitOptions, FitProgress
from core.gp.hyperparameter_fit import (
    DEFAULT_LBFGS_MEMORY,
    FAILED_VALUE,
    SeparableProgress,
    SeparableResult,
    iter_fit_jointly,
    iter_fit_separately,
    minimize_free,
)
from core.gp.initialisation import data_driven_starts, normalise_spread, random_latents
from core.gp.kronecker import find_shared_design
from core.gp.likelihood import ManifoldLikelihood, check_threads, feature_data
from core.gp.optimiser_stream import run_to_end, stream_optimiser
from core.gp.parameters import ParameterLayout, initial_hyperparameters, parameter_bounds
from core.gp.posterior import (
    AUTO_SPARSE_ABOVE,
    Likelihood,
    Structure,
    condition,
    make_likelihood,
    resolve_structure,
)
from core.gp.sparse import DEFAULT_INDUCING_POINTS
from core.gp.tied_likelihood import Kernels, tied_structure
from core.types import (
    FitDiagnostics,
    Hyperparameters,
    ManifoldModel,
    PosteriorStructure,
    TrainingData,
)
from core.validation import FloatArray, as_float_array

#: Distance (log units) from a bound that counts as sitting on it.
AT_BOUND = 1e-4

#: A random restart gives up only when its pace cannot bring it within this margin of the best
#: data-driven start's screened -log p (the larger of the two), because L-BFGS-B's pace is
#: uneven (``FitOptions.restart_reach_iterations``; the measurement is in docs/fitting.md).
REACH_MARGIN_NATS = 1.0
REACH_MARGIN_RELATIVE = 1e-3

#: Shares of a fit's work in ``FitProgress.fraction`` (an estimate for a time-remaining
#: display, from the evaluation counts in docs/fitting.md): the starts' first stages on a
#: screening subsample (the rest is the polish of the best), or on all the data; the
#: hyperparameter stage of a polish (the rest is the joint run).
FIRST_STAGES_SHARE = 0.25
FIRST_STAGES_SHARE_ALL_DATA = 0.6
POLISH_HYPERPARAMETER_SHARE = 0.2
MAX_FRACTION_BEFORE_DONE = 0.99

#: Screening runs on a subsample only when that makes an evaluation at least this many times
#: cheaper (:func:`evaluation_cost`); otherwise it runs on all the data.
SCREEN_MIN_SAVING = 2.0


def normalise_latents(
    latents: FloatArray, hyperparameters: Hyperparameters
) -> tuple[FloatArray, Hyperparameters]:
    """Centre S, scale it to RMS distance 1 from its centre, and rescale ℓ^s to match.

    s' = (s - centre) / c and ℓ^s' = ℓ^s / c leave every kernel value, hence the likelihood,
    unchanged (the model is identifiable only up to such maps, docs/method.md M2).

    Args:
        latents: Shape (L, ds).
        hyperparameters: Hyperparameters with ds latent dimensions.

    Returns:
        The normalised latents (L, ds) and hyperparameters.
    """
    latents = as_float_array(latents, "latents", (None, hyperparameters.latent_dim))
    normalised, _, scale = normalise_spread(latents)
    h = hyperparameters
    return normalised, Hyperparameters(
        signal_variance=h.signal_variance,
        noise_variance=h.noise_variance,
        latent_lengthscales=h.latent_lengthscales / scale,
        action_lengthscales=h.action_lengthscales,
    )


@dataclass
class Start:
    """Book-keeping of one start."""

    index: int
    kind: str  # "data" (data-driven), "random", "de"
    vector: FloatArray
    iterations: int = 0
    screen_value: float = np.inf  # -log p on the screening data
    full_value: float = np.inf  # -log p on all the data
    polished: bool = False
    converged: bool = False
    message: str = ""


@dataclass
class FitProblem:
    """A likelihood with its bounds (all the data, or the screening subsample)."""

    likelihood: Likelihood
    lower: FloatArray
    upper: FloatArray
    structure: Structure = "auto"
    n_inducing: int = DEFAULT_INDUCING_POINTS
    _features: list[Likelihood] | None = None

    @property
    def tied(self) -> bool:
        """Whether the likelihood's features share their length-scales (tied kernels)."""
        return self.likelihood.layout.tied

    def feature_likelihoods(self) -> list[Likelihood]:
        """One likelihood per feature (dy = 1 each), built on first use."""
        if self._features is None:
            data = self.likelihood.data
            latent_dim = self.likelihood.layout.latent_dim
            whole = self.likelihood
            self._features = [
                whole.for_feature(a)
                if isinstance(whole, ManifoldLikelihood)
                else make_likelihood(
                    feature_data(data, a), latent_dim, self.structure, self.n_inducing
                )
                for a in range(data.observation_dim)
            ]
        return self._features

    def with_threads(self, threads: int) -> FitProblem:
        """This problem with its evaluations on ``threads`` threads (a dense likelihood's
        features, :mod:`core.gp.likelihood`): a shallow copy sharing the data."""
        likelihood = self.likelihood
        if isinstance(likelihood, ManifoldLikelihood) and likelihood.threads != threads:
            likelihood = copy.copy(likelihood)
            likelihood.threads = check_threads(threads)
        return dataclasses.replace(self, likelihood=likelihood, _features=None)

    @property
    def max_jitter(self) -> float:
        """The largest jitter any of this problem's likelihoods needed (per-feature ones too)."""
        return max([self.likelihood.max_jitter] + [f.max_jitter for f in self._features or []])

    def fit_separately(
        self, vector: FloatArray, layout: ParameterLayout, options: FitOptions, max_iterations: int
    ) -> Generator[SeparableProgress, None, SeparableResult]:
        """The hyperparameters of ``vector`` fitted feature by feature, S fixed
        (:func:`core.gp.hyperparameter_fit.iter_fit_separately` with ``options``' settings); all
        at once with tied kernels, whose shared length-scales couple the features
        (:func:`core.gp.hyperparameter_fit.iter_fit_jointly`)."""
        fit: Callable[..., Generator[SeparableProgress, None, SeparableResult]] = (
            iter_fit_jointly if self.tied else iter_fit_separately
        )
        objective: object = self.likelihood if self.tied else self.feature_likelihoods()
        return fit(
            objective,
            layout,
            vector,
            self.lower,
            self.upper,
            max_iterations,
            options.ftol,
            options.gtol,
            options.hyperparameter_latent_lengthscales,
            options.stall_nats,
            options.stall_iterations,
            options.stall_relative,
            **({} if self.tied else {"threads": self._threads()}),
        )

    def _threads(self) -> int:
        """The threads of this problem's evaluations (1 but for a dense likelihood's)."""
        likelihood = self.likelihood
        return likelihood.threads if isinstance(likelihood, ManifoldLikelihood) else 1


@dataclass(frozen=True)
class RunSettings:
    """How one L-BFGS-B run of a stage stops and remembers (see :meth:`FitRun._settings`)."""

    stall_nats: float
    stall_iterations: int
    memory: int
    reach: float = -np.inf
    reach_iterations: int = 0


@dataclass(frozen=True)
class StageOutcome:
    """Where one stage left a start.

    Attributes:
        vector: The packed vector. Shape (P,).
        iterations: L-BFGS-B iterations of the stage.
        converged: Whether the stage converged.
        message: The optimiser's message.
        value: -log p at ``vector`` on the stage's problem.
    """

    vector: FloatArray
    iterations: int
    converged: bool
    message: str
    value: float


def optimise_stage(
    problem: FitProblem,
    vector: FloatArray,
    free: np.ndarray[Any, np.dtype[np.bool_]],
    max_iterations: int,
    options: FitOptions,
    settings: RunSettings,
) -> Generator[tuple[int, float], None, StageOutcome]:
    """L-BFGS-B on the ``free`` entries of ``vector`` (shape (P,)); yields (iteration, -log p)
    every ``options.progress_every`` iterations and returns the :class:`StageOutcome`."""
    base = vector.copy()

    def run(callback: Callable[[Any], None]) -> scipy.optimize.OptimizeResult:
        return minimize_free(
            problem.likelihood,
            base,
            free,
            problem.lower,
            problem.upper,
            max_iterations,
            options.ftol,
            options.gtol,
            callback,
            settings.stall_nats,
            settings.stall_iterations,
            options.stall_relative,
            settings.memory,
            settings.reach,
            settings.reach_iterations,
        )

    stream = stream_optimiser(run, options.progress_every)
    try:
        while True:
            yield next(stream)
    except StopIteration as stop:
        result: scipy.optimize.OptimizeResult = stop.value
    finally:
        stream.close()
    out = base.copy()
    out[free] = result.x
    return StageOutcome(
        out, int(result.nit), bool(result.success), str(result.message), float(result.fun)
    )


def hyperparameter_stage(
    problem: FitProblem, vector: FloatArray, layout: ParameterLayout, options: FitOptions
) -> Generator[tuple[int, float], None, StageOutcome]:
    """The hyperparameters of ``vector`` (shape (P,)) with S frozen, one feature at a time
    (:func:`core.gp.hyperparameter_fit.iter_fit_separately`); yields (iterations, -log p) after
    every feature and returns the :class:`StageOutcome`."""
    stream = problem.fit_separately(vector, layout, options, options.hyperparameter_iterations)
    try:
        while True:
            step = next(stream)
            yield step.iterations, step.value
    except StopIteration as stop:
        result: SeparableResult = stop.value
    return StageOutcome(
        result.vector, result.iterations, result.converged, result.message, result.value
    )


@dataclass(frozen=True)
class StartPlan:
    """What the first stage of every start shares (sent to a worker once).

    Attributes:
        problem: The working problem (the screening subsample, or all the data).
        layout: The packed vector's layout.
        options: The fit's settings.
        max_iterations: Iteration limit of the joint run.
        phase: ``"screen"`` or ``"joint"`` (no screening: the run ends the fit).
        settings: Stall rule and memory of the joint run.
    """

    problem: FitProblem
    layout: ParameterLayout
    options: FitOptions
    max_iterations: int
    phase: str
    settings: RunSettings

    def on_one_thread(self) -> StartPlan:
        """The plan with its evaluations on one thread (``FitOptions.threads`` = 1), for a
        process that shares its cores with others, e.g. a Dask worker."""
        return dataclasses.replace(
            self,
            problem=self.problem.with_threads(1),
            options=dataclasses.replace(self.options, threads=1),
        )


@dataclass(frozen=True)
class StartTask:
    """One start: its index, kind (``"data"``, ``"random"``) and starting vector (P,)."""

    index: int
    kind: str
    vector: FloatArray


@dataclass(frozen=True)
class StartResult:
    """Where the first stage left one start.

    Attributes:
        index: The start's index.
        outcome: The joint run's outcome (``iterations`` counts the hyperparameter stage's
            too).
        max_jitter: The largest jitter the problem's likelihoods had needed when the start
            ended (they may have run other starts before it).
    """

    index: int
    outcome: StageOutcome
    max_jitter: float


#: Runs ``first_stage`` of every task, to the end, yielding the results in any order
#: (:func:`serial_start_map` one after another; the app supplies one running them as Dask
#: tasks). The fit's result does not depend on the map.
StartMap = Callable[[StartPlan, Sequence[StartTask]], Iterable[StartResult]]


@dataclass(frozen=True)
class WarmStart:
    """One start near an optimum already found (e.g. a refit of the same objects after an
    observation transform): the fit then has this start only, no screening and no random
    restarts (see :class:`FitRun`).

    Attributes:
        latents: Shape (L, ds); normalised when the fit starts.
        hyperparameters: Hyperparameters of the fit's data, with ds latent dimensions.
        placement_variance: σ_b,a², held fixed: the fit's likelihood and its posterior then
            let touches sharing a placement share an offset
            (:class:`core.gp.likelihood.ManifoldLikelihood`; dense path). The noise variances
            of ``hyperparameters`` and of the result are each touch's whole noise variance
            σ_b,a² + σ_w,a² (the convention of :class:`core.types.ManifoldModel`); the run
            fits σ_w,a². ``None``: independent noise. Shape (dy,).
    """

    latents: FloatArray
    hyperparameters: Hyperparameters
    placement_variance: FloatArray | None = None


def first_stage(
    plan: StartPlan, task: StartTask
) -> Generator[tuple[str, int, float], None, StartResult]:
    """One start's first stage: for a data-driven start the hyperparameters with S frozen,
    then the joint run on the working problem. Yields (phase, iterations so far, -log p); a
    phase ending in ``" done"`` ends a sub-stage. A pure function of its arguments."""
    options, vector, iterations = plan.options, task.vector.copy(), 0
    if task.kind == "data" and options.hyperparameter_iterations > 0:
        stream = hyperparameter_stage(plan.problem, vector, plan.layout, options)
        try:
            while True:
                done, value = next(stream)
                yield "hyperparameters", done, value
        except StopIteration as stop:
            separate: StageOutcome = stop.value
        vector, iterations = separate.vector, separate.iterations
        yield "hyperparameters done", iterations, separate.value
    everything = np.ones(plan.layout.size, dtype=bool)
    joint = optimise_stage(
        plan.problem, vector, everything, plan.max_iterations, options, plan.settings
    )
    try:
        while True:
            done, value = next(joint)
            yield plan.phase, iterations + done, value
    except StopIteration as stop:
        outcome: StageOutcome = stop.value
    outcome = dataclasses.replace(outcome, iterations=iterations + outcome.iterations)
    return StartResult(task.index, outcome, plan.problem.max_jitter)


def run_first_stage(plan: StartPlan, task: StartTask) -> StartResult:
    """:func:`first_stage` to the end, without progress (what a :data:`StartMap` runs)."""
    return run_to_end(first_stage(plan, task))


def serial_start_map(plan: StartPlan, tasks: Sequence[StartTask]) -> Iterator[StartResult]:
    """The starts one after another, in this process."""
    for task in tasks:
        yield run_first_stage(plan, task)


class FitRun:
    """State of one fit; :meth:`events` is the generator behind :func:`core.gp.manifold.iter_fit`.

    Args:
        data: Training touches.
        latent_dim: ds ≥ 1.
        rng: Random generator (starts, screening subsample, DE).
        options: Fit settings.
        start_map: Runs the starts' first stage (:data:`StartMap`); ``None``: one after
            another in this process, with streamed progress.
        warm_start: Fit from this one start only (:meth:`_warm_events`): the joint run on
            all the data; ``options``' starts, screening and differential evolution are not
            used.
    """

    def __init__(
        self,
        data: TrainingData,
        latent_dim: int,
        rng: np.random.Generator,
        options: FitOptions,
        start_map: StartMap | None = None,
        warm_start: WarmStart | None = None,
    ) -> None:
        if not isinstance(data, TrainingData):
            raise InvalidInputError(f"data: expected TrainingData, received {type(data).__name__}.")
        if isinstance(latent_dim, bool) or not isinstance(latent_dim, int | np.integer):
            raise InvalidInputError(f"latent_dim: expected an integer, received {latent_dim!r}.")
        if latent_dim < 1:
            raise InvalidInputError(f"latent_dim: must be ≥ 1, received {latent_dim}.")
        if not isinstance(rng, np.random.Generator):
            raise InvalidInputError(
                f"rng: expected numpy.random.Generator, received {type(rng).__name__}."
            )
        if not isinstance(options, FitOptions):
            raise InvalidInputError(
                f"options: expected FitOptions, received {type(options).__name__}."
            )
        for i, given in enumerate(options.initial_latents):
            if given.shape != (data.n_objects, int(latent_dim)):
                raise InvalidInputError(
                    f"options.initial_latents[{i}]: expected shape (L, ds) = "
                    f"({data.n_objects}, {int(latent_dim)}), received {given.shape}."
                )
        if warm_start is not None:
            _check_warm_start(warm_start, data, int(latent_dim))
        self.data = data
        self.latent_dim = int(latent_dim)
        self.rng = rng
        self.warm_start = warm_start
        self.options = options
        self.placement_variance = None if warm_start is None else warm_start.placement_variance
        self.structure = fit_structure(data, options.structure, options.kernels)
        if self.placement_variance is not None and options.kernels == "tied":
            raise InvalidInputError(
                "warm_start.placement_variance: tied kernels have no placement effect in their "
                "likelihood (σ_b² Z Zᵀ would break the eigenbasis the features share); fit "
                "with kernels 'per_feature' to put it there."
            )
        if warm_start is not None and self.placement_variance is not None:
            # The shared offsets break a shared design's product form; sparse is not offered.
            if self.structure == "sparse" or options.structure == "kronecker":
                raise InvalidInputError(
                    f"warm_start.placement_variance: a placement effect in the fit needs the "
                    f"dense likelihood, not {self.structure!r}."
                )
            self.structure = "dense"
            self.warm_start = warm_start = _within_placement(warm_start, self.placement_variance)
        full = make_likelihood(
            data,
            self.latent_dim,
            self.structure,
            options.n_inducing,
            options.threads,
            placement_variance=self.placement_variance,
            kernels=options.kernels,
        )
        self.layout: ParameterLayout = full.layout
        lower, upper = parameter_bounds(data, self.layout, options.latent_bound)
        self.full = FitProblem(full, lower, upper, self.structure, options.n_inducing)
        self.screen: FitProblem | None = None
        counts = data.touches_per_object()
        k = options.screen_touches_per_object
        if k and options.screen_max_touches:
            k = min(k, max(2, options.screen_max_touches // data.n_objects))
        if k and np.any(counts > k) and warm_start is None:
            subset = self._subsample(k)
            # The screening subsample of a shared design is a shared design (see _subsample).
            screen_structure = "kronecker" if self.structure == "kronecker" else options.structure
            saving = evaluation_cost(data, self.structure, options.n_inducing) / evaluation_cost(
                subset, self.structure, options.n_inducing
            )
            if saving < SCREEN_MIN_SAVING:
                # The subsample would cost nearly as much per evaluation (many objects on a
                # shared design: the L × L latent factorisations dominate) and only blur the
                # starts: screen on all the data instead, with the same iteration limit.
                self.screen = self.full
            else:
                screen_likelihood = make_likelihood(
                    subset,
                    self.latent_dim,
                    screen_structure,
                    options.n_inducing,
                    options.threads,
                    kernels=options.kernels,
                )
                # Bounds stay those of all the data, so screened vectors are valid full vectors.
                self.screen = FitProblem(
                    screen_likelihood, lower, upper, screen_structure, options.n_inducing
                )
        self.starts: list[Start] = []
        self.best_full = np.inf
        self.start_map = start_map
        #: The largest jitter the starts run by ``start_map`` needed (elsewhere).
        self.remote_jitter = 0.0
        #: The share of the fit done (``FitProgress.fraction``), and what the stage running
        #: now adds to it when it ends.
        self.fraction = 0.0
        self._share = 0.0

    # -- set-up ------------------------------------------------------------------------------

    def _subsample(self, per_object: int) -> TrainingData:
        data = self.data
        keep: list[np.ndarray[Any, np.dtype[np.intp]]] = []
        design = find_shared_design(data) if self.structure == "kronecker" else None
        if design is not None:
            # The same design actions for every object, so the subsample is a shared design.
            chosen = self.rng.choice(design.size, size=per_object, replace=False)
            rows = np.flatnonzero(np.isin(design.grid_index % design.size, chosen))
            return TrainingData(
                object_names=data.object_names,
                object_index=data.object_index[rows],
                actions=data.actions[rows],
                observations=data.observations[rows],
            )
        for obj in range(data.n_objects):
            idx = np.flatnonzero(data.object_index == obj)
            if idx.size > per_object:
                idx = np.sort(self.rng.choice(idx, size=per_object, replace=False))
            keep.append(idx)
        rows = np.concatenate(keep)
        return TrainingData(
            object_names=data.object_names,
            object_index=data.object_index[rows],
            actions=data.actions[rows],
            observations=data.observations[rows],
        )

    def _initial_vector(self, latents: FloatArray) -> FloatArray:
        hyper = initial_hyperparameters(
            self.data, self.latent_dim, self.options.initial_latent_lengthscale
        )
        return np.clip(self.layout.pack(latents, hyper), self.full.lower, self.full.upper)

    # -- the generator -----------------------------------------------------------------------

    def events(self) -> Generator[FitProgress, None, None]:
        """Run the fit, yielding progress; the last event carries the model."""
        if self.warm_start is not None:
            yield from self._warm_events(self.warm_start)
            return
        options = self.options
        layout = self.layout
        n_objects = self.data.n_objects
        for latents in data_driven_starts(self.data, layout.latent_dim, self.rng):
            self.starts.append(Start(len(self.starts), "data", self._initial_vector(latents)))
        for given in options.initial_latents:  # the caller's starts, treated as data-driven
            latents, _, _ = normalise_spread(given)
            self.starts.append(Start(len(self.starts), "data", self._initial_vector(latents)))
        for _ in range(options.restarts):
            latents = random_latents(n_objects, layout.latent_dim, self.rng)
            self.starts.append(Start(len(self.starts), "random", self._initial_vector(latents)))
        n_starts = len(self.starts) + (1 if options.optimizer == "de" else 0)
        working = self.screen if self.screen is not None else self.full
        everything = np.ones(layout.size, dtype=bool)
        phase = "screen" if self.screen is not None else "joint"
        # Shares of the fit in FitProgress.fraction (module docstring, "Progress").
        first_share = (
            1.0
            if self.screen is None
            else FIRST_STAGES_SHARE_ALL_DATA
            if self.screen is self.full
            else FIRST_STAGES_SHARE
        )
        n_polish = options.polish_starts + (1 if options.optimizer == "de" else 0)
        self._share = first_share / n_starts

        # 1. Every L-BFGS start on the working data (screening subsample or all the data).
        limit = options.screen_iterations if self.screen is not None else options.max_iterations
        settings = self._settings(working, phase)
        data_starts = [s for s in self.starts if s.kind == "data"]
        yield from self._first_stages(data_starts, working, limit, phase, n_starts, settings)
        # The random restarts give up once they cannot reach the best healthy data-driven
        # start (FitOptions.restart_reach_iterations): known before any of them runs, so
        # the outcome does not depend on where they run.
        healthy = [
            s.screen_value
            for s in data_starts
            if np.isfinite(s.screen_value) and not self._is_degenerate(s.vector)
        ]
        if self.screen is not None and healthy and options.restart_reach_iterations > 0:
            best = min(healthy)
            margin = max(REACH_MARGIN_NATS, REACH_MARGIN_RELATIVE * abs(best))
            settings = dataclasses.replace(
                settings, reach=best + margin, reach_iterations=options.restart_reach_iterations
            )
        others = [s for s in self.starts if s.kind != "data"]
        yield from self._first_stages(others, working, limit, phase, n_starts, settings)

        # 2. Differential evolution on the working data, seeded with the best start so far.
        if options.optimizer == "de":
            seed_vector = self._best_working(working).vector.copy()
            de_start = Start(len(self.starts), "de", seed_vector)
            self.starts.append(de_start)
            yield from self._differential_evolution(de_start, working, n_starts)
            self._share = 0.0
            yield from self._optimise(de_start, working, everything, limit, phase, n_starts)

        # 3. Polish the best screened starts on all the data (and the DE start), from their
        #    screened latents with fresh hyperparameters; if the best polished start is
        #    degenerate, polish the next ones until one is not (or none is left).
        if self.screen is not None:
            polish_share = (1.0 - first_share) / n_polish
            for start in self.starts:
                start.full_value = self._full_value(start.vector)
            ranked = sorted(self.starts, key=lambda s: (s.full_value, s.screen_value))
            queue_ = ranked[: options.polish_starts]
            queue_ += [s for s in self.starts if s.kind == "de" and s not in queue_]
            rest = [s for s in ranked if s not in queue_]
            while queue_:
                start = queue_.pop(0)
                self._share = polish_share
                if self.screen is not self.full:
                    start.vector = self._transfer(start.vector)
                    if options.hyperparameter_iterations > 0:
                        self._share = polish_share * POLISH_HYPERPARAMETER_SHARE
                        yield from self._optimise_separately(start, self.full, n_starts)
                        self._share = polish_share * (1.0 - POLISH_HYPERPARAMETER_SHARE)
                yield from self._optimise(
                    start, self.full, everything, options.max_iterations, "joint", n_starts
                )
                start.polished = True
                if not queue_ and rest and self._needs_more_polish(rest[0]):
                    queue_.append(rest.pop(0))
        else:
            for start in self.starts:
                start.polished = True
        yield self._done(n_starts)

    def _warm_events(self, warm: WarmStart) -> Generator[FitProgress, None, None]:
        """The fit from one warm start: everything jointly on all the data, stopping as the
        runs that end a fit do (``joint_stall_nats``). The hyperparameters are not fitted
        with S frozen first, unlike a fresh start's: they start near where they end (on
        ``bench/fit_n800.py``'s data that stage doubled the refit's cost for 0.04 nats;
        docs/fitting.md)."""
        normalised, hyper = normalise_latents(np.asarray(warm.latents), warm.hyperparameters)
        vector = self.layout.pack(normalised, hyper)
        start = Start(0, "warm", np.clip(vector, self.full.lower, self.full.upper))
        self.starts.append(start)
        self._share = 1.0
        everything = np.ones(self.layout.size, dtype=bool)
        limit = self.options.max_iterations
        yield from self._optimise(start, self.full, everything, limit, "joint", 1)
        start.polished = True
        yield self._done(1)

    def _done(self, n_starts: int) -> FitProgress:
        """The final event, with the winner's model."""
        model = self._final_model()
        return FitProgress(
            start=model.diagnostics.best_start if model.diagnostics else 0,
            n_starts=n_starts,
            iteration=model.diagnostics.iterations if model.diagnostics else 0,
            log_likelihood=model.log_likelihood,
            best_log_likelihood=model.log_likelihood,
            phase="done",
            model=model,
            fraction=1.0,
        )

    # -- pieces ------------------------------------------------------------------------------

    def _needs_more_polish(self, candidate: Start) -> bool:
        """Polish ``candidate`` (the best unpolished start) too when every polished start is
        degenerate, or when its full-data value, at its screened parameters, already beats
        the best polished start (the screening ranked them wrongly)."""
        polished = [s for s in self.starts if s.polished and np.isfinite(s.full_value)]
        if all(self._is_degenerate(s.vector) for s in polished):
            return True
        return candidate.full_value < min(s.full_value for s in polished)

    def _transfer(self, vector: FloatArray) -> FloatArray:
        """The full-data starting point of a screened start: its screened latents
        (normalised) with fresh initial hyperparameters. Hyperparameters fitted to a subsample
        transfer badly (measured on Experiment 1: a feature left at ℓ^s ≈ 48, where the full
        fit stays on a plateau 65 nats below the optimum, and 2-20x more iterations)."""
        latents, _ = self.layout.unpack(vector)
        normalised, _, _ = normalise_spread(latents)
        return self._initial_vector(normalised)

    def _best_working(self, working: FitProblem) -> Start:
        key = (lambda s: s.screen_value) if working is self.screen else (lambda s: s.full_value)
        return min(self.starts, key=key)

    def _full_value(self, vector: FloatArray) -> float:
        try:
            return self.full.likelihood.value(vector)
        except NotPositiveDefiniteError:
            return np.inf

    def _record(self, start: Start, problem: FitProblem, value: float) -> None:
        if problem is self.full:
            start.full_value = value
            self.best_full = min(self.best_full, value)
        if problem is self.screen:
            start.screen_value = value

    def _progress(
        self, start: Start, n_starts: int, iteration: int, value: float, phase: str
    ) -> FitProgress:
        """A progress event of ``start`` at -log p = ``value``."""
        return FitProgress(
            start=start.index,
            n_starts=n_starts,
            iteration=iteration,
            log_likelihood=-value,
            best_log_likelihood=-self.best_full,
            phase=phase,
            fraction=self.fraction,
        )

    def _finished(
        self, start: Start, problem: FitProblem, value: float, phase: str, n_starts: int
    ) -> FitProgress:
        """Record the value ``start`` ended a stage with, count the stage's share of the fit
        done; the event that ends the stage."""
        self._record(start, problem, value)
        # More polishes than planned add nothing: the fraction stays below 1 until the end.
        self.fraction = min(self.fraction + self._share, MAX_FRACTION_BEFORE_DONE)
        return self._progress(start, n_starts, start.iterations, value, f"{phase} done")

    def _settings(self, problem: FitProblem, phase: str) -> RunSettings:
        """Stall rule and memory of a joint run of ``phase`` on ``problem``: the runs that
        end the fit stop within about a nat (``FitOptions.joint_stall_nats``)."""
        options = self.options
        final = problem is self.full and phase == "joint"
        memory = DEFAULT_LBFGS_MEMORY
        if problem is self.full:
            polish = final and self.screen is not None and self.screen is not self.full
            memory = options.polish_lbfgs_memory if polish else options.joint_lbfgs_memory
        return RunSettings(
            options.joint_stall_nats if final else options.stall_nats,
            options.joint_stall_iterations if final else options.stall_iterations,
            memory,
        )

    def _apply(self, start: Start, outcome: StageOutcome, initial_iterations: int) -> None:
        start.vector = outcome.vector
        start.iterations = initial_iterations + outcome.iterations
        start.converged = outcome.converged
        start.message = outcome.message

    def _first_stages(
        self,
        starts: list[Start],
        working: FitProblem,
        max_iterations: int,
        phase: str,
        n_starts: int,
        settings: RunSettings,
    ) -> Generator[FitProgress, None, None]:
        """The first stage of ``starts`` (:func:`first_stage`), in this process with
        streamed progress, or by ``start_map`` with one event per start."""
        if not starts:
            return
        plan = StartPlan(working, self.layout, self.options, max_iterations, phase, settings)
        tasks = [StartTask(s.index, s.kind, s.vector) for s in starts]
        if self.start_map is None:
            for start, task in zip(starts, tasks, strict=True):
                stream = first_stage(plan, task)
                try:
                    while True:
                        stage, iteration, value = next(stream)
                        if stage.endswith(" done"):
                            self._record(start, working, value)
                        yield self._progress(start, n_starts, iteration, value, stage)
                except StopIteration as stop:
                    result: StartResult = stop.value
                self._apply(start, result.outcome, 0)
                yield self._finished(start, working, result.outcome.value, phase, n_starts)
            return
        for result in self.start_map(plan, tasks):
            start = self.starts[result.index]
            self.remote_jitter = max(self.remote_jitter, result.max_jitter)
            self._apply(start, result.outcome, 0)
            yield self._finished(start, working, result.outcome.value, phase, n_starts)

    def _optimise(
        self,
        start: Start,
        problem: FitProblem,
        free: np.ndarray[Any, np.dtype[np.bool_]],
        max_iterations: int,
        phase: str,
        n_starts: int,
    ) -> Generator[FitProgress, None, None]:
        """L-BFGS-B on the ``free`` entries of ``start.vector``, streaming progress."""
        initial_iterations = start.iterations
        stream = optimise_stage(
            problem,
            start.vector,
            free,
            max_iterations,
            self.options,
            self._settings(problem, phase),
        )
        try:
            while True:
                iteration, value = next(stream)
                yield self._progress(start, n_starts, initial_iterations + iteration, value, phase)
        except StopIteration as stop:
            outcome: StageOutcome = stop.value
        self._apply(start, outcome, initial_iterations)
        yield self._finished(start, problem, outcome.value, phase, n_starts)

    def _optimise_separately(
        self, start: Start, problem: FitProblem, n_starts: int
    ) -> Generator[FitProgress, None, None]:
        """The hyperparameters with S frozen, one feature at a time
        (:func:`hyperparameter_stage`)."""
        initial_iterations = start.iterations
        stream = hyperparameter_stage(problem, start.vector, self.layout, self.options)
        try:
            while True:
                iterations, value = next(stream)
                yield self._progress(
                    start, n_starts, initial_iterations + iterations, value, "hyperparameters"
                )
        except StopIteration as stop:
            outcome: StageOutcome = stop.value
        self._apply(start, outcome, initial_iterations)
        yield self._finished(start, problem, outcome.value, "hyperparameters", n_starts)

    def _differential_evolution(
        self, start: Start, problem: FitProblem, n_starts: int
    ) -> Generator[FitProgress, None, None]:
        """Differential evolution over the whole bounded vector, seeded with ``start``."""
        options = self.options
        likelihood = problem.likelihood
        seed = np.random.default_rng(self.rng.integers(2**63))

        def objective(vector: FloatArray) -> float:
            try:
                return likelihood.value(vector)
            except NotPositiveDefiniteError:
                return FAILED_VALUE

        def run(callback: Callable[[Any], None]) -> scipy.optimize.OptimizeResult:
            return scipy.optimize.differential_evolution(
                objective,
                bounds=scipy.optimize.Bounds(problem.lower, problem.upper),
                x0=start.vector,
                popsize=options.de_population,
                maxiter=options.de_generations,
                polish=False,
                init="latinhypercube",
                rng=seed,
                callback=callback,
                updating="immediate",
            )

        stream = stream_optimiser(run, 1)
        try:
            while True:
                generation, value = next(stream)
                yield self._progress(start, n_starts, generation, value, "de")
        except StopIteration as stop:
            result: scipy.optimize.OptimizeResult = stop.value
        finally:
            stream.close()
        start.vector = np.asarray(result.x, dtype=np.float64).copy()
        start.iterations = int(result.nit)
        start.message = str(result.message)
        yield self._finished(start, problem, float(result.fun), "de", n_starts)

    def _is_degenerate(self, vector: FloatArray) -> bool:
        layout = self.layout
        sl = layout.log_latent_lengthscales
        log_ls = vector[sl].reshape(layout.lengthscale_rows, layout.latent_dim)
        low = self.full.lower[sl].reshape(log_ls.shape)
        high = self.full.upper[sl].reshape(log_ls.shape)
        at_low = log_ls <= low + AT_BOUND
        at_high = log_ls >= high - AT_BOUND
        return bool(np.any(at_low) or np.any(np.all(at_high, axis=0)))

    def _final_model(self) -> ManifoldModel:
        candidates = [s for s in self.starts if s.polished and np.isfinite(s.full_value)]
        if not candidates:
            raise ConvergenceError(
                "every start of the manifold fit failed (the Gram matrices stayed singular): "
                "check for duplicate touches with conflicting observations."
            )
        candidates.sort(key=lambda s: s.full_value)
        winner = candidates[0]
        if self._is_degenerate(winner.vector):
            healthy = [s for s in candidates if not self._is_degenerate(s.vector)]
            if healthy:
                winner = healthy[0]
        everything = np.ones(self.layout.size, dtype=bool)
        on_bounds = at_bounds(
            winner.vector, self.full.lower, self.full.upper, self.layout, everything
        )
        diagnostics = FitDiagnostics(
            starts_log_likelihood=tuple(-s.full_value for s in self.starts),
            best_start=winner.index,
            iterations=winner.iterations,
            converged=winner.converged,
            message=winner.message,
            jitter_used=max(
                self.full.max_jitter,
                self.screen.max_jitter if self.screen is not None else 0.0,
                self.remote_jitter,
            ),
            hyperparameters_at_bounds=on_bounds,
            kernels=self.options.kernels,
        )
        latents, hyper = self.layout.unpack(winner.vector)
        latents, hyper = normalise_latents(latents, hyper)
        return self._condition(latents, hyper, diagnostics)

    def _condition(
        self, latents: FloatArray, hyper: Hyperparameters, diagnostics: FitDiagnostics | None
    ) -> ManifoldModel:
        """The posterior at fitted parameters; with a placement variance, the fitted σ_w² made
        each touch's whole noise variance σ_w² + σ_b² again (:class:`WarmStart`)."""
        if self.placement_variance is not None:
            hyper = dataclasses.replace(
                hyper, noise_variance=hyper.noise_variance + self.placement_variance
            )
        return condition(
            self.data,
            latents,
            hyper,
            diagnostics,
            structure=self.structure,
            n_inducing=self.options.n_inducing,
            placement_variance=self.placement_variance,
        )

    def best_model_so_far(self) -> ManifoldModel | None:
        """The best parameters reached so far, conditioned on all the data (or ``None``)."""
        done = [s for s in self.starts if np.isfinite(s.full_value)]
        if not done:
            done = [s for s in self.starts if np.isfinite(s.screen_value)]
            for s in done:
                s.full_value = self._full_value(s.vector)
            done = [s for s in done if np.isfinite(s.full_value)]
        if not done:
            return None
        best = min(done, key=lambda s: s.full_value)
        latents, hyper = normalise_latents(*self.layout.unpack(best.vector))
        return self._condition(latents, hyper, None)


def _within_placement(warm: WarmStart, placement_variance: FloatArray) -> WarmStart:
    """The warm start with each touch's whole noise variance split: σ_w² = σ_n² − σ_b², the
    noise variance the run fits (kept above 1 % of σ_n²).

    Raises:
        InvalidInputError: σ_b² of another length than dy, or negative.
    """
    h = warm.hyperparameters
    variance = as_float_array(placement_variance, "placement_variance", (h.observation_dim,))
    if np.any(variance < 0.0):
        raise InvalidInputError(
            f"warm_start.placement_variance: every σ_b,a² must be ≥ 0, received "
            f"{variance.tolist()}."
        )
    within = np.maximum(h.noise_variance - variance, 0.01 * h.noise_variance)
    return dataclasses.replace(warm, hyperparameters=dataclasses.replace(h, noise_variance=within))


def _check_warm_start(warm: WarmStart, data: TrainingData, latent_dim: int) -> None:
    """Reject a warm start whose shapes do not fit the data and ds."""
    if not isinstance(warm, WarmStart):
        raise InvalidInputError(f"warm_start: expected WarmStart, received {type(warm).__name__}.")
    latents = as_float_array(warm.latents, "warm_start.latents", (data.n_objects, latent_dim))
    if not np.all(np.isfinite(latents)):
        raise InvalidInputError("warm_start.latents: expected finite values.")
    h = warm.hyperparameters
    expected = (data.observation_dim, latent_dim, data.action_dim)
    received = (h.observation_dim, h.latent_dim, h.action_lengthscales.shape[1])
    if received != expected:
        raise InvalidInputError(
            f"warm_start.hyperparameters: expected (dy, ds, dx) = {expected}, received {received}."
        )


def fit_structure(data: TrainingData, structure: Structure, kernels: Kernels) -> PosteriorStructure:
    """The structure a fit evaluates its likelihood with: that of
    :func:`core.gp.posterior.resolve_structure`, or dense for tied kernels
    (:func:`core.gp.tied_likelihood.tied_structure`).

    Raises:
        InvalidInputError: As those do.
    """
    if kernels == "tied":
        tied_structure(data, structure, AUTO_SPARSE_ABOVE)
        return "dense"
    chosen, _ = resolve_structure(data, structure)
    return chosen


def evaluation_cost(data: TrainingData, structure: Structure, n_inducing: int) -> float:
    """Leading flop count of one likelihood evaluation per feature, up to a constant.

    Dense: N³ (Cholesky and inverse of K). Kronecker (L objects × M shared actions): L³ + M³ for
    the two factorisations plus L·M·(L + M) for the rotations. Sparse (m inducing touches):
    N·m². Only ratios between data sets of one structure are meaningful.
    """
    n = float(data.n_touches)
    if structure == "kronecker":
        n_objects = float(data.n_objects)
        n_actions = n / n_objects
        return n_objects**3 + n_actions**3 + n_objects * n_actions * (n_objects + n_actions)
    if structure == "sparse":
        return n * min(float(n_inducing), n) ** 2
    return n**3


def at_bounds(
    vector: FloatArray,
    lower: FloatArray,
    upper: FloatArray,
    layout: ParameterLayout,
    free: np.ndarray[Any, np.dtype[np.bool_]],
) -> tuple[str, ...]:
    """Names of the ``free`` entries of ``vector`` within :data:`AT_BOUND` of a bound, each
    with ``(lower)`` or ``(upper)``."""
    names = layout.names()
    hits = []
    for i in np.flatnonzero(free):
        if vector[i] <= lower[i] + AT_BOUND:
            hits.append(f"{names[i]} (lower)")
        elif vector[i] >= upper[i] - AT_BOUND:
            hits.append(f"{names[i]} (upper)")
    return tuple(hits)
