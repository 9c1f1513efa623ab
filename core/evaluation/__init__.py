"""Running and scoring recognition trials (docs/method.md, "Evaluation protocols").

``trial_engine`` (the one trial loop over a touch source: a world, model samples, a replay),
``worlds`` (the synthetic worlds by name), ``designs`` and ``adaptive_design`` (where a collection
touches), ``records`` (the one outcome type, per-trial seeds), ``summary``, ``calibration`` and
``metrics`` (scoring), ``reference_model`` (Experiment 1's model without the fit).
"""

from core.evaluation.adaptive_design import planner_round, round_sizes
from core.evaluation.calibration import calibration
from core.evaluation.designs import CollectionDesign, collect, random_design, shared_design
from core.evaluation.metrics import abs_correlation, procrustes_r2
from core.evaluation.records import (
    REFUSED,
    RefusedTrial,
    TrialOutcome,
    TrialRecord,
    outcome_from_dict,
    seed_sequence,
    trial_seed,
)
from core.evaluation.reference_model import experiment1_at_true_latents
from core.evaluation.summary import comparison_sentence, summarise, wilson_interval
from core.evaluation.trial_engine import (
    ModelSamples,
    ModelTrial,
    PlannedTouches,
    ReplayPool,
    Touch,
    TouchSource,
    TrialSettings,
    WorldTouches,
    iter_trial,
    replay_pools,
    run_trial,
)
from core.evaluation.worlds import (
    EXPERIMENT1_THETAS,
    WORLD_NAMES,
    Experiment1World,
    World,
    WorldName,
    make_world,
    sample_dataset,
    sample_experiment1,
)

__all__ = [
    "EXPERIMENT1_THETAS",
    "REFUSED",
    "WORLD_NAMES",
    "CollectionDesign",
    "Experiment1World",
    "ModelSamples",
    "ModelTrial",
    "PlannedTouches",
    "RefusedTrial",
    "ReplayPool",
    "Touch",
    "TouchSource",
    "TrialOutcome",
    "TrialRecord",
    "TrialSettings",
    "World",
    "WorldName",
    "WorldTouches",
    "abs_correlation",
    "calibration",
    "collect",
    "comparison_sentence",
    "experiment1_at_true_latents",
    "iter_trial",
    "make_world",
    "outcome_from_dict",
    "planner_round",
    "procrustes_r2",
    "random_design",
    "replay_pools",
    "round_sizes",
    "run_trial",
    "sample_dataset",
    "sample_experiment1",
    "seed_sequence",
    "shared_design",
    "summarise",
    "trial_seed",
    "wilson_interval",
]
