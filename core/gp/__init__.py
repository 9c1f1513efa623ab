"""The GP object manifold and its fit (docs/method.md (M1), (M2)).

The model: kernels (``kernels``), the structured linear algebra (``linalg``, ``kronecker``,
``kronecker_blocks``, ``sparse``), the hyperparameter layout (``parameters``), the marginal
likelihood (``likelihood``; with tied kernels ``tied_likelihood``) and the posterior it
conditions (``posterior``). Its fit: options and
progress (``fit_options``), the optimisation (``fit_run``, ``hyperparameter_fit``,
``optimiser_stream``), starting latents (``initialisation``), the entry points (``manifold``), the
noise model (``noise_model``), the placement effect (``placement_effect``; each object's own:
``object_placement``), the drift effect
(``drift_effect``) and a placement's shift of the action (``input_shift``).

Callers outside ``core`` use the names below; tests and benchmarks may reach the modules.
"""

from core.gp.drift_effect import check_drift_variance, estimate_drift_variance, with_drift_effect
from core.gp.fit_options import FitOptions, FitProgress
from core.gp.fit_run import (
    StartMap,
    StartPlan,
    StartResult,
    StartTask,
    fit_structure,
    run_first_stage,
)
from core.gp.input_shift import (
    check_shift_creep,
    check_shift_variance,
    estimate_shift_variance,
    with_input_shift,
)
from core.gp.manifold import (
    FitCancelledError,
    fit_hyperparameters,
    fit_manifold,
    iter_fit,
    refit_warm,
)
from core.gp.noise_model import (
    NoiseModelChoice,
    attach_transform,
    choose_noise_model,
    transform_data,
)
from core.gp.object_placement import (
    ObjectPlacementEstimate,
    check_object_placement_variance,
    estimate_object_placement_variance,
    with_object_placement,
)
from core.gp.placement_effect import (
    check_placement_variance,
    estimate_placement_variance,
    with_placement_effect,
)
from core.gp.posterior import (
    Structure,
    condition,
    gram_matrix,
    make_likelihood,
    predict,
    predict_model_space,
)
from core.gp.sparse import condition_sparse
from core.gp.tied_likelihood import KERNELS, Kernels

__all__ = [
    "KERNELS",
    "FitCancelledError",
    "FitOptions",
    "FitProgress",
    "Kernels",
    "NoiseModelChoice",
    "ObjectPlacementEstimate",
    "StartMap",
    "StartPlan",
    "StartResult",
    "StartTask",
    "Structure",
    "attach_transform",
    "check_drift_variance",
    "check_object_placement_variance",
    "check_placement_variance",
    "check_shift_creep",
    "check_shift_variance",
    "choose_noise_model",
    "condition",
    "condition_sparse",
    "estimate_drift_variance",
    "estimate_object_placement_variance",
    "estimate_placement_variance",
    "estimate_shift_variance",
    "fit_hyperparameters",
    "fit_manifold",
    "fit_structure",
    "gram_matrix",
    "iter_fit",
    "make_likelihood",
    "predict",
    "predict_model_space",
    "refit_warm",
    "run_first_stage",
    "transform_data",
    "with_drift_effect",
    "with_input_shift",
    "with_object_placement",
    "with_placement_effect",
]
