"""Recognising an object by touch: the belief, what a touch will tell, where to touch next
(docs/method.md (M3)–(M5)).

``moments`` (predicting an observation from a Gaussian belief, the mutual information, the
belief update), ``information_gradient``, ``object_information``, ``object_posterior`` (the
posterior over the learned objects), ``latent_uncertainty`` and ``tempering`` (options of the
object likelihood, docs/method.md (L1)–(L3)), ``calibrated`` (everything a fitted model learns
from its training touches after the fit, in one step), ``planning`` (the policies: ``POLICIES``),
``session`` (a recognition session: :class:`RecognitionSession`) and ``dmp`` (actions as offsets
of the DMPs of a teaching trajectory).
"""

from core.recognition.calibrated import Calibrations, calibrate
from core.recognition.dmp import (
    BasisResponses,
    DMPActionSpace,
    action_space,
    basis_responses,
    fit_dmp,
    trajectory_for_action,
)
from core.recognition.latent_uncertainty import check_latent_covariance, with_latent_uncertainty
from core.recognition.moments import (
    action_statistics,
    mutual_information,
    predictive_moments,
    update_belief,
)
from core.recognition.object_mixture import ObjectMixture, mixture_information
from core.recognition.object_posterior import (
    TRIAL_LIKELIHOODS,
    TrialLikelihood,
    object_log_likelihoods,
    object_posterior,
    touch_log_likelihoods,
)
from core.recognition.planning import (
    EVALUATION_POLICIES,
    POLICIES,
    ActionBox,
    ActivePolicy,
    Planner,
    Policy,
    make_policy,
    policy_entry,
)
from core.recognition.session import (
    PLANNING_BELIEFS,
    PlanningBelief,
    RecognitionFinishedError,
    RecognitionSession,
    RecognitionSettings,
    RecognitionStep,
    default_prior,
    objects_belief,
)
from core.recognition.tempering import check_exponent, fit_tempering

__all__ = [
    "EVALUATION_POLICIES",
    "PLANNING_BELIEFS",
    "POLICIES",
    "TRIAL_LIKELIHOODS",
    "ActionBox",
    "ActivePolicy",
    "BasisResponses",
    "Calibrations",
    "DMPActionSpace",
    "ObjectMixture",
    "Planner",
    "PlanningBelief",
    "Policy",
    "RecognitionFinishedError",
    "RecognitionSession",
    "RecognitionSettings",
    "RecognitionStep",
    "TrialLikelihood",
    "action_space",
    "action_statistics",
    "basis_responses",
    "calibrate",
    "check_exponent",
    "check_latent_covariance",
    "default_prior",
    "fit_dmp",
    "fit_tempering",
    "make_policy",
    "mixture_information",
    "mutual_information",
    "object_log_likelihoods",
    "object_posterior",
    "objects_belief",
    "policy_entry",
    "predictive_moments",
    "touch_log_likelihoods",
    "trajectory_for_action",
    "update_belief",
    "with_latent_uncertainty",
]
