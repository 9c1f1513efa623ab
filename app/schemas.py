"""Request and response bodies of the REST API (``/api/v1``), as families per resource.

Field names follow the REST API of docs/usage.md. Arrays are lists of finite floats: NaN/inf in a
JSON body is a 422 naming the field.
"""

from __future__ import annotations

from datetime import datetime
from typing import Annotated, Any, Generic, Literal, TypeVar

from pydantic import (
    AfterValidator,
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Field,
    FiniteFloat,
    StrictBool,
    StringConstraints,
)

from app.documents.json_values import check_json_values
from app.documents.training_csv import MAX_NAME_CHARACTERS
from app.states import ModelStatus, RunStatus

T = TypeVar("T")


def _plain_record(value: dict[str, Any]) -> dict[str, Any]:
    """A free-form record a client sends is stored as JSON and read back: finite numbers,
    valid text under 10 000 characters, nested at most 8 levels."""
    check_json_values(value, "record", max_depth=8, max_text=10_000)
    return value


Name = Annotated[
    str, StringConstraints(strip_whitespace=True, min_length=1, max_length=MAX_NAME_CHARACTERS)
]
#: A free-form JSON object a client records (a touch's trajectory).
Record = Annotated[dict[str, Any], AfterValidator(_plain_record)]
Vector = Annotated[list[FiniteFloat], Field(min_length=1, max_length=64)]
Matrix = Annotated[list[Vector], Field(min_length=1, max_length=64)]
Seed = Annotated[int, Field(ge=0, le=2**32 - 1)]
Id = Annotated[int, Field(ge=1, le=2**63 - 1)]


_Schema = TypeVar("_Schema", bound=BaseModel)


def from_row(schema: type[_Schema], row: object, **given: Any) -> _Schema:
    """The API view ``schema`` of a database row: every field the row's attribute of the same
    name, unless ``given``."""
    return schema.model_validate(
        {name: given[name] if name in given else getattr(row, name) for name in schema.model_fields}
    )


class Page(BaseModel, Generic[T]):
    """A list response: ``{"data": [...], "count": n}`` (``count``: rows matching the filter)."""

    data: list[T]
    count: int


class Health(BaseModel):
    """``GET /health``."""

    status: Literal["ok"]
    version: str
    database: str
    hardware: str
    auth_required: bool


# --- datasets ---------------------------------------------------------------------------------


class SampleIn(BaseModel):
    """One touch: object name, action x (dx,), observation y (dy,), and optionally which
    placement of its object it met and when it was made (every sample of an upload gives one,
    or none does)."""

    model_config = ConfigDict(extra="forbid")

    object: Name
    action: Vector
    observation: Vector
    placement: Annotated[int, Field(ge=0, le=2**31 - 1)] | None = Field(
        default=None,
        description=(
            "Which placement of its object the touch met (0, 1, …): touches of one object with "
            "one number shared a placement, and the fit estimates how much a placement shifts "
            "its touches alike (the model's placement_effect). Null: not recorded."
        ),
    )
    time_s: FiniteFloat | None = Field(
        default=None,
        description=(
            "When the touch was made, in seconds since the collection's first touch (any "
            "origin, one clock for the whole upload): the fit estimates the drift shared by "
            "touches made close together from these times. Null: not recorded."
        ),
    )


class DatasetCreate(BaseModel):
    """JSON upload of a dataset."""

    model_config = ConfigDict(extra="forbid")

    name: Annotated[str, Field(max_length=MAX_NAME_CHARACTERS)] = ""
    samples: Annotated[list[SampleIn], Field(min_length=1, max_length=200_000)]
    touch_duration_s: Annotated[FiniteFloat, Field(gt=0)] | None = Field(
        default=None,
        description=(
            "How long every touch lasted as planned, in seconds: an action means a trajectory "
            "of that duration, so a model of these touches recognises with touches as long. "
            "Null: not recorded (the rig's default duration is then assumed)."
        ),
    )


class DatasetPublic(BaseModel):
    """A dataset's summary (``POST /datasets``, ``GET /datasets/{id}``)."""

    id: int
    name: str
    source: str
    status: str
    objects: list[str]
    n_samples: int
    action_dim: int
    observation_dim: int
    touch_duration_s: float | None = None
    created_at: datetime


# --- models -----------------------------------------------------------------------------------


class ModelCreate(BaseModel):
    """``POST /models``: fit a manifold to a dataset in the background."""

    model_config = ConfigDict(extra="forbid")

    dataset_id: Id
    latent_dim: Annotated[int, Field(ge=1, le=8)] | Literal["auto"] = Field(
        default=2,
        description=(
            "ds, or 'auto': choose it by cross-validated held-out predictive likelihood "
            "(candidates 1..min(5, L-1); the smallest ds within one standard error of the best; "
            "the scores are reported in latent_selection)."
        ),
    )
    noise_model: Literal["auto", "independent", "correlated"] = Field(
        default="auto",
        description=(
            "independent: standardise every feature, independent noise per feature. "
            "correlated: also whiten the noise covariance across features estimated from the "
            "residuals of a first fit, then refit. auto: both, keep the correlated model when "
            "it wins on leave-one-out predictive likelihood (docs/noise-model.md)."
        ),
    )
    optimizer: Literal["lbfgs", "de"] = "lbfgs"
    kernels: Literal["per_feature", "tied"] = Field(
        default="per_feature",
        description=(
            "per_feature: every feature has its own length-scales. tied: the features share "
            "their length-scales (each keeps its signal and noise variance), so one "
            "eigendecomposition per evaluation serves them all: much faster fits from about "
            "5 features on (docs/fitting.md, 'Tied kernels'). Recorded in the model's "
            "diagnostics.kernels."
        ),
    )
    restarts: Annotated[int, Field(ge=0, le=50)] = 2
    seed: Seed | None = None
    max_iterations: Annotated[int, Field(ge=1, le=20_000)] | None = None
    features: Literal["means", "whole"] | None = Field(
        default=None,
        description=(
            "Make y afresh from the dataset's raw touches (an upload of raw touches, "
            "docs/raw-touches.md, or a rig collection): 'whole' reduces every series "
            "(mean, RMS, std, slope, Welch band powers and centroid, electrode pattern), "
            "standardises and projects to feature_dim; 'means' takes each channel's mean. The "
            "fitted pipeline becomes part of the model (its 'features'). Null: y as stored."
        ),
    )
    feature_dim: Annotated[int, Field(ge=1, le=30)] | Literal["auto"] = Field(
        default="auto",
        description=(
            "features 'whole' only: dy, or 'auto': chosen by cross-validated recognition of "
            "held-out training touches (reported in features.explanation)."
        ),
    )
    latent_uncertainty: bool = Field(
        default=True,
        description=(
            "Carry each object's latent covariance (Laplace) into the object likelihood "
            "(docs/method.md (L1)-(L3))."
        ),
    )
    object_placement: bool = Field(
        default=False,
        description=(
            "When the touches record placements: score each object's trials with its own "
            "placement variance, shrunk towards the pooled one. Off by default: measured, it "
            "cost accuracy (docs/calibration.md, 'Each object's placement variance')."
        ),
    )
    placement_pooling: Literal["mean", "median"] = Field(
        default="mean",
        description=(
            "When the touches record placements: the placement variance every trial is scored "
            "with is the mean over all placements, or the median over the objects of each one's "
            "own estimate (measured, not adopted: docs/calibration.md, 'The typical object's "
            "placement variance')."
        ),
    )
    shift_along: Literal["auto", "all"] = Field(
        default="auto",
        description=(
            "When the touches record placements: the action dimensions the input shift is "
            "estimated along. 'auto': the press depth alone when the actions are the rig's with "
            "it (dx = 7), every dimension otherwise; 'all': every dimension (docs/calibration.md, "
            "'The shift along the press depth only')."
        ),
    )
    tempering: bool = Field(
        default=False,
        description=(
            "A last resort: an exponent β ≤ 1 on the object likelihood, fitted by "
            "cross-validation on the training touches (docs/calibration.md, 'Fix 6')."
        ),
    )
    workers: Annotated[int, Field(ge=1, le=256)] | None = Field(
        default=None,
        description=(
            "latent_dim 'auto' only: run the cross-validation folds as Dask tasks on this many "
            "local worker processes (on the server's cluster when it is configured with one, "
            "ACTIVETOUCH_DASK_SCHEDULER; in process when neither)."
        ),
    )


class ModelAccepted(BaseModel):
    """202 answer of ``POST /models``: ``fitting`` when the fit started at once, else ``queued``
    with its place in the queue of fits."""

    id: int
    status: ModelStatus
    queue_position: int | None = None


class ObjectLatent(BaseModel):
    """An object's name and latent point s_l (ds,)."""

    name: str
    latent: list[float]


class FeatureHyperparameters(BaseModel):
    """GP hyperparameters of one feature (length-scales, not squared)."""

    feature: int
    signal_variance: float
    noise_variance: float
    latent_lengthscales: list[float]
    action_lengthscales: list[float]


class ModelPosterior(BaseModel):
    """How a ready model's GP is conditioned (the model document's ``posterior`` field).

    ``dense``: every training touch, one N x N covariance per feature. ``kronecker``: the data
    are a shared design (every object touched with the same actions), the covariance factorises
    exactly. ``sparse``: m = ``n_inducing`` inducing points (the training touches listed in
    ``inducing_touches``) stand in for all N; predictions are an approximation.
    """

    structure: Literal["dense", "kronecker", "sparse"] = Field(
        description="How the GP posterior is conditioned: dense, kronecker or sparse."
    )
    n_inducing: int | None = Field(
        default=None,
        description="Sparse only: m, the number of inducing points (null otherwise).",
    )
    inducing_touches: list[int] | None = Field(
        default=None,
        description=(
            "Sparse only: the training touches used as inducing points, in order (0-based "
            "indices into the dataset's samples in upload order); null otherwise."
        ),
    )


class NoiseModelPublic(BaseModel):
    """The observation noise model a ready model applies (docs/noise-model.md)."""

    kind: Literal["identity", "independent", "correlated"] = Field(
        description=(
            "identity: observations used as recorded (models fitted before noise models "
            "existed); independent: each feature standardised, noise independent per feature; "
            "correlated: standardised and the noise whitened by the estimated correlation."
        )
    )
    correlation: list[list[float]] = Field(
        description="Noise correlation across features that the model whitens (dy x dy)."
    )
    scale: list[float] = Field(description="Per-feature scale the features are divided by.")
    note: str = Field(default="", description="How the noise model was chosen.")


class LatentCandidatePublic(BaseModel):
    """Cross-validated held-out score of one candidate latent dimension."""

    latent_dim: int
    mean: float = Field(description="Mean held-out log-likelihood per touch over folds (nats).")
    standard_error: float
    difference: float = Field(description="Mean paired difference to the best candidate.")
    difference_standard_error: float
    fold_scores: list[float]


class LatentSelectionPublic(BaseModel):
    """How ``latent_dim: "auto"`` chose ds."""

    chosen: int = Field(description="The smallest ds within one standard error of best.")
    best: int = Field(description="The ds with the best mean held-out score.")
    n_folds: int
    candidates: list[LatentCandidatePublic]
    explanation: str


class FeaturesPublic(BaseModel):
    """How a model makes y of a raw touch (the model document's ``features``)."""

    kind: Literal["means", "whole"] = Field(
        description="means: each channel's mean over the touch; whole: per-channel reducers "
        "(mean, RMS, std, slope, Welch band powers and centroid, electrode pattern), "
        "standardised and projected to dy."
    )
    channels: list[str] = Field(description="The raw channels a touch must have.")
    reduced_features: int = Field(description="Numbers per touch before the projection.")
    projection: Literal["pca", "lda"] | None = Field(description="Projection of 'whole'.")
    output_names: list[str] = Field(description="Names of the dy features of y.")
    explanation: str | None = Field(description="How dy was chosen, when it was.")


class LatentUncertaintyPublic(BaseModel):
    """Σ_l, the Laplace uncertainty of each object's latent point that the object likelihood
    integrates over (the model document's ``latent_uncertainty``; docs/method.md (L1))."""

    std: list[list[float]] = Field(
        description=(
            "Per object (in the order of 'objects'), the standard deviation of its latent point "
            "along each latent axis, normalised latent units (the objects' RMS spread is 1)."
        )
    )


class PlacementEffectPublic(BaseModel):
    """σ_b², the variance of the offset the touches of one placement share (the model document's
    ``placement_effect``), estimated at fit time from a dataset that records placements."""

    variance: list[float] = Field(
        description="σ_b² per feature, in the model's space (after its noise model)."
    )
    noise_ratio: list[float] = Field(
        description=(
            "σ_b² / σ_n² per feature: the share of the per-touch noise variance that a trial's "
            "touches of one placement share (0: none, the touches count as independent)."
        )
    )
    in_training_covariance: bool = Field(
        default=False,
        description=(
            "Whether the fit also has σ_b² in its own likelihood (the training touches of one "
            "placement share the offset); false: σ_b² only scores trials."
        ),
    )
    by_object: list[list[float]] | None = Field(
        default=None,
        description=(
            "Each object's own σ_b² per feature (shrunk towards the pooled one; one row per "
            "object, in the model's object order), which scores a trial under that object in "
            "place of ``variance``; null when the fit did not estimate them "
            "(docs/calibration.md, 'Each object's placement variance')."
        ),
    )


class ModelPublic(BaseModel):
    """``GET /models/{id}``."""

    id: int
    status: ModelStatus
    queue_position: int | None = Field(
        default=None,
        description=(
            "While the model is queued: its place in the queue of fits (1: the next to start); "
            "the server fits at most its max_concurrent_fits models at once."
        ),
    )
    reason: str | None
    dataset_id: int
    latent_dim: int
    action_dim: int
    observation_dim: int
    optimizer: str
    restarts: int
    seed: int | None
    objects: list[ObjectLatent]
    log_likelihood: float | None
    hyperparameters: list[FeatureHyperparameters]
    fit_seconds: float | None
    diagnostics: dict[str, Any] | None
    progress: dict[str, Any] | None
    posterior: ModelPosterior | None = Field(
        default=None,
        description=(
            "How the GP was conditioned (structure; for sparse, the inducing points). Null while "
            "fitting, for a failed model, and for a model stored before this was recorded (such "
            "a model is conditioned as the default structure 'auto' chooses)."
        ),
    )
    noise_model: NoiseModelPublic | None = Field(
        default=None,
        description=(
            "The observation noise model applied (null while fitting or failed). Models stored "
            "before noise models existed report kind 'identity'."
        ),
    )
    latent_selection: LatentSelectionPublic | None = Field(
        default=None,
        description="For latent_dim 'auto': every candidate's score and why ds was chosen.",
    )
    features: FeaturesPublic | None = Field(
        default=None,
        description="The feature pipeline that makes y of a raw touch; null: y is given as "
        "recorded (a training CSV, or a rig touch's channel means).",
    )
    latent_uncertainty: LatentUncertaintyPublic | None = Field(
        default=None,
        description=(
            "Each object's latent uncertainty, computed at fit time (the default). Null: the "
            "object likelihood uses the latent points as exact."
        ),
    )
    placement_effect: PlacementEffectPublic | None = Field(
        default=None,
        description=(
            "The placement effect estimated at fit time from the dataset's placements (a "
            "collection records them; docs/calibration.md). Null when the training touches "
            "recorded no placements: a trial's touches are then scored as independent."
        ),
    )
    created_at: datetime
    finished_at: datetime | None


# --- trials -----------------------------------------------------------------------------------


class ActionBounds(BaseModel):
    """Box of allowed actions: ``lower`` (dx,) ≤ x ≤ ``upper`` (dx,)."""

    model_config = ConfigDict(extra="forbid")

    lower: Vector
    upper: Vector


#: Older spellings of the simulated worlds, still accepted (and read from stored trials) as the
#: names of :data:`core.evaluation.worlds.WORLD_NAMES` they stand for.
WORLD_ALIASES: dict[str, str] = {"experiment1": "exp1", "experiment2": "exp2"}


def _world_alias(value: Any) -> Any:
    return WORLD_ALIASES.get(value, value) if isinstance(value, str) else value


class SimulationOptions(BaseModel):
    """How a ``simulated`` trial's world is made.

    ``exp1``: the paper's Experiment 1 (objects O1..O4, dx=1, dy=3); ``exp2``: an
    Experiment-2-like random world drawn from ``world_seed`` (dx=6, dy=5); ``rig``: the simulated
    rig (mock hardware) — the names of ``activetouch`` and of the evaluations. The older
    spellings ``experiment1`` and ``experiment2`` are accepted as aliases of ``exp1`` and
    ``exp2``.
    """

    model_config = ConfigDict(extra="forbid")

    world: Annotated[
        Literal["exp1", "exp2", "rig"],
        BeforeValidator(_world_alias),
        Field(description="exp1, exp2 or rig (aliases: experiment1 → exp1, experiment2 → exp2)."),
    ] = "exp1"
    noise_std: Annotated[float, Field(ge=0.0, le=10.0)] | None = None
    world_seed: Seed = 0
    step_interval_s: Annotated[float, Field(ge=0.0, le=60.0)] = 0.0


class TrialCreate(BaseModel):
    """``POST /trials``."""

    model_config = ConfigDict(extra="forbid")

    model_id: Id
    mode: Literal["scripted", "simulated", "rig"]
    policy: Literal["active", "discriminative", "passive", "fixed"] = "active"
    max_steps: Annotated[int, Field(ge=1, le=1000)] = 20
    tolerance: Annotated[float, Field(ge=0.0, le=1e6)] = 1e-3
    confidence_threshold: Annotated[float, Field(gt=0.0, le=1.0)] | None = None
    prior_mean: Vector | None = None
    prior_cov: Matrix | None = None
    action_bounds: ActionBounds | None = None
    fixed_action: Vector | None = None
    target: Name | None = None
    target_slot: Annotated[int, Field(ge=0, le=1000)] | None = None
    seed: Seed | None = None
    simulation: SimulationOptions | None = None


class Belief(BaseModel):
    """Gaussian belief over the latent point: mean (ds,), cov (ds, ds)."""

    mean: list[float]
    cov: list[list[float]]


class TrialResult(BaseModel):
    """The trial's answer; ``correct`` only when the target is known."""

    object: str
    correct: bool | None = None


class StepPublic(BaseModel):
    """One recorded touch of a trial."""

    step: int
    action: list[float]
    observation: list[float]
    trajectory: dict[str, Any] | None
    mutual_information: float | None
    belief: Belief
    probabilities: dict[str, float]
    nearest_object: str
    answer: str
    stop_reason: str | None
    duration_s: float
    created_at: datetime


class TrialSummary(BaseModel):
    """A trial without its steps (list view)."""

    id: int
    model_id: int
    mode: str
    policy: str
    status: RunStatus
    reason: str | None = Field(
        description="Why it ended: the stop rule of a completed trial (confident: an object "
        "reached confidence_threshold; converged; max_steps), else what stopped or failed it."
    )
    max_steps: int
    tolerance: float
    confidence_threshold: float | None
    prior_mean: list[float]
    prior_cov: list[list[float]]
    action_bounds: ActionBounds | None
    target: str | None
    seed: int | None
    options: dict[str, Any]
    n_steps: int
    result: TrialResult | None
    created_at: datetime
    started_at: datetime | None
    finished_at: datetime | None


class TrialPublic(TrialSummary):
    """``GET /trials/{id}``: the trial with all its steps."""

    steps: list[StepPublic]


class NextAction(BaseModel):
    """``GET /trials/{id}/next-action``: advice for step ``step``."""

    step: int
    action: list[float]
    mutual_information: float | None


class RawChannelIn(BaseModel):
    """One channel of a raw touch (``docs/raw-touches.md``)."""

    model_config = ConfigDict(extra="forbid")

    rate_hz: float | None = Field(default=None, description="Sample rate in Hz (required).")
    samples: list[Any] = Field(description="n numbers, or n vectors of one width.")


class ObservationIn(BaseModel):
    """``POST /trials/{id}/observations``: the action actually performed and what was felt —
    either y itself (``observation``) or the raw touch (``channels``), which the model's own
    feature pipeline turns into y (the channel means for a model without one)."""

    model_config = ConfigDict(extra="forbid")

    action: Vector
    observation: Vector | None = None
    channels: dict[str, RawChannelIn] | None = None
    trajectory: Record | None = None


class ObservationResult(BaseModel):
    """Belief after an observation."""

    step: int
    belief: Belief
    nearest_object: str
    answer: str
    probabilities: dict[str, float]
    done: bool
    stop_reason: str | None = Field(
        default=None,
        description="Why the trial stopped after this touch: confident (an object reached the "
        "confidence threshold), converged or max_steps; null while it goes on.",
    )
    status: RunStatus
    result: TrialResult | None


# --- rig and collections ----------------------------------------------------------------------


class TurntableRequest(BaseModel):
    """``POST /rig/turntable``."""

    model_config = ConfigDict(extra="forbid")

    slot: Annotated[int, Field(ge=0, le=1000)]


class RigPublic(BaseModel):
    """``GET /rig``: connection, state and which run holds the rig."""

    hardware: str
    connected: bool
    state: str
    held_by: str | None
    detail: dict[str, Any]


class CollectionObject(BaseModel):
    """An object to collect: its name and turntable slot."""

    model_config = ConfigDict(extra="forbid")

    name: Name
    slot: Annotated[int, Field(ge=0, le=1000)]


class CollectionCreate(BaseModel):
    """``POST /collections``: touch each object ``samples_per_object`` times on the rig.

    ``action_design``: ``random`` draws a fresh x ~ N(0, action_scale² I) for every touch (the
    paper's design; each object gets its own actions); ``shared`` draws ``samples_per_object``
    actions from the same prior (scrambled Sobol, :func:`core.evaluation.designs.shared_design`) and
    touches every object with each of them (a shared design: fits and plans take the exact Kronecker
    path); ``teaching`` repeats the teaching action x = 0; ``adaptive`` touches the first half
    as ``random`` does, then (``samples_per_object`` ≥ 3) rounds at the actions the planners
    would choose from a model fitted to the touches so far (the same budget,
    :mod:`core.evaluation.adaptive_design`). ``action_design`` left out: ``adaptive``, or ``random``
    with fewer than 3 samples per object (:func:`app.services.collections.default_design`); the
    run's ``params`` record the design used. ``action_scale`` left out: the simulated
    table's own spread on the mock rig (its ``action_std``), 1.0 on a real rig; the run's
    ``params`` record the spread used. ``placements`` (P per object, each touched about
    ``samples_per_object`` / P times in a row; every stored sample records its placement, and a
    fit estimates the placement effect from them): left out, three placements for every four
    touches, half the touches in pairs and half placed anew
    (:func:`app.services.collections.default_placements`); the run's ``params`` record the
    placements used.
    """

    model_config = ConfigDict(extra="forbid")

    name: Annotated[str, Field(max_length=MAX_NAME_CHARACTERS)] = ""
    objects: Annotated[list[CollectionObject], Field(min_length=2, max_length=100)]
    samples_per_object: Annotated[int, Field(ge=2, le=1000)] = 20
    action_design: Literal["random", "shared", "teaching", "adaptive"] | None = None
    action_scale: Annotated[float | None, Field(gt=0.0, le=100.0)] = None
    seed: Seed | None = None
    placements: Annotated[int, Field(ge=1, le=1000)] | None = Field(
        default=None,
        description=(
            "Placements per object P: each object is placed P times and touched about "
            "samples_per_object / P times in a row at each placement, and every sample records "
            "its placement, so that a fit estimates how much one placement shifts a trial's "
            "touches alike (the model's placement_effect). Null: three placements for every four "
            "touches (P = samples_per_object - samples_per_object // 4, at least one pair: half "
            "the touches in pairs, half placed anew); P = samples_per_object places every touch "
            "anew. "
            "At least one per stage of the design (the adaptive design touches in up to 3 "
            "stages, each with placements of its own)."
        ),
    )
    press_depth: bool = Field(
        default=True,
        description=(
            "The press-depth component as the actions' last dimension (dx = 7): it flexes "
            "the finger 0.25° deeper per unit while pressing and is drawn like the other "
            "components, so that a fit learns how a placement's tilt moves the touches. A "
            "model fitted to such a collection is touched with the same actions in rig trials "
            "and evaluations. False: the six DMP components alone (dx = 6)."
        ),
    )
    touch_duration_s: Annotated[float, Field(ge=1.0, le=600.0)] | None = Field(
        default=None,
        description=(
            "How long each touch lasts, in seconds (the DMP's time scaling, as `activetouch "
            "collect --duration`). The dataset records it, and its models touch for as long in "
            "rig trials and evaluations. Null: the teaching trajectory's 14.4 s."
        ),
    )


class RunPublic(BaseModel):
    """A collection run with its progress."""

    id: int
    kind: str
    status: RunStatus
    reason: str | None
    done: int
    total: int
    dataset_id: int | None
    params: dict[str, Any]
    created_at: datetime
    started_at: datetime | None
    finished_at: datetime | None


class ObjectPublic(BaseModel):
    """A registered object: name, turntable slot, notes, known properties."""

    id: int
    name: str
    slot: int | None
    notes: str
    properties: dict[str, Any]
    created_at: datetime


# --- evaluations ------------------------------------------------------------------------------

EvaluationWorld = Literal["exp1", "exp2", "rig", "model", "replay"]


class EvaluationCreate(BaseModel):
    """``POST /evaluations``: many recognition trials of one model, summarised per policy.

    The parameters of ``activetouch evaluate``; ``replay`` names a dataset of recorded
    held-out touches (``dataset_id``). Trials run in the server; on a Dask cluster when the
    server is configured with one (``ACTIVETOUCH_DASK_SCHEDULER``), else on ``workers``
    local processes (in-process when not given).
    """

    model_config = ConfigDict(extra="forbid")

    model_id: Id
    world: EvaluationWorld = Field(description="exp1, exp2, rig, model or replay.")
    dataset_id: Id | None = Field(
        default=None, description="replay only: the dataset of held-out touches to replay."
    )
    targets: Annotated[list[Name], Field(min_length=1, max_length=1000)] | None = Field(
        default=None, description="Objects to recognise (all of the model's when not given)."
    )
    policies: Annotated[list[Name], Field(min_length=1, max_length=10)] = Field(
        default_factory=lambda: ["active", "passive"]
    )
    trials_per_target: Annotated[int, Field(ge=1, le=100_000)] = 10
    steps: Annotated[int, Field(ge=1, le=1000)] = 10
    confidence: Annotated[float, Field(gt=0.0, le=1.0)] = 0.95
    seed: Seed = 0
    table: Name | None = Field(
        default=None,
        description="rig only: the simulated rig table — a built-in one by name, or the name of "
        "the server's table file (ACTIVETOUCH_SIM_TABLE_FILE); the server's table when omitted.",
    )
    placement: Literal["trial", "touch"] = Field(
        default="trial",
        description="rig and model: place the object once per trial, or anew before every "
        "touch (the table turns away and back, as in a collection; the model world draws its "
        "placement effect likewise).",
    )
    trial_likelihood: Literal["joint", "independent"] = Field(
        default="joint",
        description="How the object posterior scores a trial's touches: one Gaussian with the "
        "GP's full covariance (joint) or a product over touches (independent).",
    )
    plan_under: Literal["objects", "gaussian"] = Field(
        default="objects",
        description="The belief the active policy plans under: the mixture over the learned "
        "objects that the object posterior implies (objects) or the paper's Gaussian belief "
        "(gaussian).",
    )
    stop_at_confidence: StrictBool = Field(
        default=False,
        description="Also stop a trial once its answer's probability reaches `confidence` (the "
        "answer is carried forward to T; the trial records the stop). true or false.",
    )
    workers: Annotated[int, Field(ge=1, le=256)] | None = None


class ReliabilityBinPublic(BaseModel):
    """One bin of stated probability [lower, upper) (the last includes 1) of a reliability table."""

    lower: float
    upper: float
    count: int = Field(description="Answers given with a probability in the bin.")
    mean_confidence: float | None = Field(description="Their mean probability (null if none).")
    accuracy: float | None = Field(description="The share of them that were right (null if none).")


class SureAndWrongPublic(BaseModel):
    """Answers given with probability ≥ the evaluation's confidence, and the wrong ones."""

    threshold: float
    sure: int
    wrong: int
    share_wrong: float | None = Field(description="wrong / sure; null when none was sure.")


class EceIfCalibrated(BaseModel):
    """The ECE the same stated probabilities would show by sampling alone, were they
    calibrated (each answer right with exactly its probability, independently): an observed
    ECE is evidence of miscalibration only above ``p95``."""

    mean: float = Field(description="Mean over the Monte Carlo draws.")
    p95: float = Field(description="95th percentile over the draws.")


class CalibrationAtTouch(BaseModel):
    """Calibration of a set of answers, without the reliability table (the measures are null
    for an empty set)."""

    answers: int = Field(description="Answers scored.")
    accuracy: float | None
    ece: float | None = Field(description="Expected calibration error over 10 equal bins.")
    brier: float | None = Field(description="Multi-class Brier score of the object posterior.")
    log_loss: float | None = Field(description="Mean −log p(true object), nats.")
    sure_and_wrong: SureAndWrongPublic
    ece_if_calibrated: EceIfCalibrated | None = Field(
        default=None,
        description="The ECE expected from sampling alone if the stated probabilities were "
        "calibrated (null for no answers, and in reports written before it was added).",
    )


class CalibrationPublic(CalibrationAtTouch):
    """Calibration of a set of answers with its reliability table (stated vs observed)."""

    reliability: list[ReliabilityBinPublic]


class PolicyCalibration(BaseModel):
    """How far one policy's stated probabilities can be trusted (completed trials only).

    Every answer is scored with the object posterior behind it; a trial that stopped early
    keeps its last answer up to T, as in ``accuracy_by_touch``.
    """

    all_touches: CalibrationPublic = Field(description="Over every (trial, touch 1..T).")
    final: CalibrationPublic = Field(description="At touch T.")
    by_touch: list[CalibrationAtTouch] = Field(description="At touch 1..T.")


class EvaluationPolicySummary(BaseModel):
    """One policy's summary: accuracy by touch with 95 % intervals, per object, confusion,
    touches to confidence, calibration (null in summaries of format ``/1``), trials, refused."""

    model_config = ConfigDict(extra="allow")

    accuracy_by_touch: list[float]
    accuracy_interval: list[list[float]]
    effective_trials: list[float] | None = Field(
        default=None,
        description="Per touch, the trials counted once per distinct evidence (Kish's effective "
        "sample size, what the interval uses): fewer than trials where trials share recorded "
        "touches (replay); null in reports written before it.",
    )
    trials: int
    calibration: PolicyCalibration | None = None


class EvaluationSummary(BaseModel):
    """The ``activetouch-evaluation/2`` document without its trials (see ``EvaluationPublic``);
    a stored ``/1`` one has no calibration."""

    model_config = ConfigDict(extra="allow")

    format: str
    policies: dict[str, EvaluationPolicySummary]


class EvaluationPublic(BaseModel):
    """``GET /evaluations/{id}``: the request, state, progress and summary.

    ``summary`` is the ``activetouch-evaluation/2`` document without its trials: the final
    report's once the job has ended with one; while it runs (or after it failed) the summary
    of the trials finished so far, marked ``"partial": true``; null before the first trial.
    Its ``refused_trials`` and ``refused_by_policy`` count the trials the rig refused a touch
    of (a servo overload, ...); each policy's accuracy and calibration are over its completed
    ``trials`` only.
    """

    id: int
    model_id: int
    dataset_id: int | None
    spec: dict[str, Any]
    status: RunStatus
    reason: str | None
    done: int
    total: int
    workers: int | None
    seconds: float | None
    summary: EvaluationSummary | None
    created_at: datetime
    updated_at: datetime
    started_at: datetime | None
    finished_at: datetime | None


class TrialRefusal(BaseModel):
    """Why a trial was refused: the rig refused one of its touches (e.g. a servo overload)."""

    touch: int = Field(description="The refused touch, 1-based (touches before it were made).")
    action: list[float] = Field(description="The action refused.")
    error: str = Field(description="The device error, e.g. ServoHardwareError.")
    reason: str = Field(description="The device's message.")


class EvaluationTrialSummary(BaseModel):
    """A finished trial of an evaluation, without its touches (list view).

    A refused trial (``refused``) ended when the rig refused one of its touches; ``correct`` is
    false, ``touches`` counts those made before the refusal and ``stop_reason`` is
    ``"refused"``; the evaluation's accuracy leaves it out (its summary counts it apart).
    """

    number: int
    policy: str
    target: str
    trial: int
    correct: bool
    touches: int
    answer: str | None
    stop_reason: str | None
    refused: bool = False
    refusal: TrialRefusal | None = None


class EvaluationTrialPublic(EvaluationTrialSummary):
    """``GET /evaluations/{id}/trials/{n}``: one finished trial with its touches.

    ``record`` is the engine's ``TrialRecord`` as JSON (answers, probabilities, actions and
    mutual information after each touch, seed); ``objects`` the model's object order of its
    probabilities. For a refused trial it is the engine's ``RefusedTrial``: those per-touch
    fields cover only the touches made before the refusal (none when the first was refused),
    ``refused`` (as ``refusal``) the refused touch, and there is no answer.
    """

    evaluation_id: int
    model_id: int
    objects: list[str]
    record: dict[str, Any]


class HealthLocked(BaseModel):
    """``GET /health`` off loopback without the token: that auth is required, nothing more."""

    auth_required: Literal[True] = True


class SignIn(BaseModel):
    """The dashboard's sign-in: the server's API token (kept by no one but the server)."""

    model_config = ConfigDict(extra="forbid")

    token: Annotated[str, Field(min_length=1, max_length=1000)]


class SessionStatus(BaseModel):
    """How this request is authenticated, and what the server asks for."""

    authenticated: bool
    method: Literal["token", "session"] | None
    auth_required: bool = Field(description="A token is configured: changes need it.")
    reads_need_auth: bool = Field(
        description="Off loopback: every request (reads, events, the 3D view) needs it."
    )
    expires_at: datetime | None = None


class RequestAuditPublic(BaseModel):
    """A recorded mutating request."""

    id: int
    time: datetime
    client: str | None = Field(description="Client address as the server saw it.")
    method: str
    path: str
    route: str | None = Field(description="The matched route template, if any.")
    status_code: int
    authenticated: bool
    auth_method: Literal["token", "session"] | None
    duration_ms: float
