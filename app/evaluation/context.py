"""The context that runs an evaluation's trials, in process or on a Dask worker.

:class:`TrialContext` holds what every trial needs — the model, the spec, the replay pools — and
builds per process what is costly and reusable (planners with their candidate statistics, the
world, the rig's action map). It is what is sent to each Dask worker once; a task names only its
trial (policy, target, index). This module imports no web stack, so a worker starts light.

A rig trial whose touch the hardware refuses (:func:`app.evaluation.rig_trial.is_refusal`: a
servo overload, a command a servo refuses, a trajectory refused before it moved) ends as a
:class:`~core.evaluation.records.RefusedTrial`; the evaluation goes on. Any other hardware error
(a lost device, a timeout, an alarm of the turntable) propagates, noted with the trial and touch
it happened in, and ends the evaluation.
"""

from __future__ import annotations

import functools
import threading
from typing import TYPE_CHECKING, Any

from threadpoolctl import threadpool_limits

from app.evaluation.rig_trial import RigTrial, rig_seed
from core.evaluation import (
    ModelTrial,
    ReplayPool,
    TouchSource,
    TrialOutcome,
    World,
    WorldTouches,
    make_world,
    replay_pools,
    run_trial,
    trial_seed,
)
from core.recognition import EVALUATION_POLICIES, ActionBox, Planner, policy_entry
from core.types import ManifoldModel, TrainingData
from hardware.errors import HardwareError

if TYPE_CHECKING:
    from app.evaluation.spec import EvaluationSpec
    from app.rig.actions import TouchActions
    from hardware.sim.materials import Table
    from hardware.sim.noise import NoiseModel

#: Key of one trial: (policy, target, trial index).
TrialKey = tuple[str, str, int]


def rig_tables() -> dict[str, tuple[str, ...]]:
    """The simulated rig's named tables (:data:`hardware.sim.materials.TABLES`): name → objects."""
    from hardware.sim.materials import TABLES

    return {name: table.objects for name, table in TABLES.items()}


def rig_table(table: str | Table | None) -> Table:
    """A spec's simulated rig table: by name (the default table when ``None``), or as itself.

    Raises:
        ConfigurationError: Unknown name.
    """
    from hardware.sim.materials import DEFAULT_TABLE_NAME, get_table

    return get_table(DEFAULT_TABLE_NAME if table is None else table)


def synthetic_world(spec: EvaluationSpec) -> World:
    """The ``exp1`` or ``exp2`` world of a spec (:func:`core.evaluation.worlds.make_world`, as the
    server's simulated trials and the command line make them)."""
    return make_world(spec.world, world_seed=spec.world_seed, noise_std=spec.noise_std)


class TrialContext:
    """Runs trials of one evaluation; picklable (caches are rebuilt in each process).

    Args:
        model: The model.
        spec: The evaluation (already checked).
        replay: Held-out touches of a ``replay`` evaluation.
        box: Where the planners choose actions (the range of the training actions when
            ``None``, as every evaluation has it; a benchmark may narrow it).
        rig_noise: Noise model of the ``rig`` world's simulation (the simulator's default when
            ``None``, as every evaluation has it; a benchmark may quieten it).
    """

    def __init__(
        self,
        model: ManifoldModel,
        spec: EvaluationSpec,
        replay: TrainingData | None = None,
        *,
        box: ActionBox | None = None,
        rig_noise: NoiseModel | None = None,
    ) -> None:
        self.model = model
        self.spec = spec
        self.pools: dict[str, ReplayPool] = {} if replay is None else replay_pools(replay)
        self.steps = spec.steps_used(model, replay)
        self.box = box
        self.rig_noise = rig_noise
        self._reset_caches()

    def _reset_caches(self) -> None:
        self._local = threading.local()

    def __getstate__(self) -> dict[str, Any]:
        state = dict(self.__dict__)
        del state["_local"]
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        self._reset_caches()

    def trial_keys(self) -> list[TrialKey]:
        """Every trial of the evaluation, policy-major, then target, then index."""
        targets = self.spec.target_names(self.model)
        return [
            (policy, target, trial)
            for policy in self.spec.policies
            for target in targets
            for trial in range(self.spec.trials_per_target)
        ]

    def planner(self, policy: str) -> Planner:
        """This thread's planner of a policy (built once; its state is a pure cache)."""
        planners: dict[str, Planner] = getattr(self._local, "planners", None) or {}
        self._local.planners = planners
        if policy not in planners:
            entry = policy_entry(policy, EVALUATION_POLICIES)
            planners[policy] = Planner(self.model, entry.make(), box=self.box)
        return planners[policy]

    def _world(self) -> World:
        world: World | None = getattr(self._local, "world", None)
        if world is None:
            world = synthetic_world(self.spec)
            self._local.world = world
        return world

    def _rig_actions(self) -> TouchActions:
        actions: TouchActions | None = getattr(self._local, "rig_actions", None)
        if actions is None:
            from app.rig.actions import TouchActions

            actions = TouchActions.for_action_dim(
                self.model.hyperparameters.action_dim,
                duration_s=self.model.raw_data.touch_duration_s,
            )
            self._local.rig_actions = actions
        return actions

    def run(self, key: TrialKey) -> TrialOutcome:
        """Run one trial (BLAS on one thread, so results do not depend on the process)."""
        with threadpool_limits(limits=1):
            return self.run_unpinned(key)

    def run_many(self, keys: list[TrialKey]) -> list[TrialOutcome]:
        """:meth:`run` of each key, BLAS pinned once for all of them (it costs ~1 ms)."""
        with threadpool_limits(limits=1):
            return [self.run_unpinned(key) for key in keys]

    def run_unpinned(self, key: TrialKey) -> TrialOutcome:
        """One trial; the caller has pinned BLAS to one thread (see :meth:`run`).

        Raises:
            HardwareError: The rig failed other than by refusing a touch (the error carries a
                note naming the trial).
        """
        try:
            return self._run_trial(key)
        except HardwareError as exc:
            policy, target, trial = key
            exc.add_note(f"in trial {trial} of {policy}/{target}")
            raise

    def open_rig_trial(self, key: TrialKey, seed: int) -> RigTrial:
        """A fresh simulated rig for trial ``key`` (policy, target, index), world seed ``seed``."""
        target = key[1]
        return RigTrial(
            self._rig_actions(),
            rig_table(self.spec.table).slots,
            target,
            seed,
            placement=self.spec.placement,
            noise=self.rig_noise,
            features=self.model.features,
        )

    def _run_trial(self, key: TrialKey) -> TrialOutcome:
        policy, target, trial = key
        seed = trial_seed(self.spec.seed, target, trial)
        run = functools.partial(
            run_trial,
            self.model,
            self.planner(policy),
            policy=policy,
            target=target,
            trial=trial,
            seed=seed,
            settings=self.spec.trial_settings(),
        )
        if self.spec.world == "replay":
            return run(replay=self.pools[target], steps=self.steps)
        touches: TouchSource
        if self.spec.world == "model":
            touches = ModelTrial(self.model, target, self.spec.placement == "trial")
        elif self.spec.world == "rig":
            rig = self.open_rig_trial(key, rig_seed(seed))
            try:
                return run(touches=rig)
            finally:
                rig.close()
        else:
            touches = WorldTouches(self._world(), target)
        return run(touches=touches)


def run_trials_task(context: TrialContext, keys: list[TrialKey]) -> list[TrialOutcome]:
    """The task of a batch of trials (runs on a worker; ``context`` is its scattered copy)."""
    return context.run_many(keys)
