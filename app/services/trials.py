"""Trials: scripted (the caller owns the robot), simulated and rig (the server drives).

A server-driven trial runs the trial engine (:func:`core.evaluation.trial_engine.iter_trial`) over
its touch source; a scripted trial drives the engine's step-wise core, the
:class:`~core.recognition.session.RecognitionSession`, one posted observation at a time.
Every touch is committed as a :class:`app.db.tables.TrialStep` the moment it happens, under the
trial's run lock, so control requests (pause, resume, stop, abort) never interleave with a step.
"""

from __future__ import annotations

import functools
import logging
import threading
import time
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from sqlalchemy.orm import Session

from app import crud, states
from app.config import Settings
from app.db import Database
from app.db.tables import Trial, TrialStep
from app.errors import AppError, BadInputError, ConflictError
from app.schemas import (
    Belief,
    NextAction,
    ObservationIn,
    ObservationResult,
    SimulationOptions,
    TrialCreate,
    TrialPublic,
)
from app.services.events import EventBus
from app.services.jobs import INTERRUPTED, Job, JobCancelled, JobRunner
from app.services.models import ReadyModels
from app.services.rig import RigService
from app.services.trial_views import require, step_public, to_public, trial_result
from app.services.worlds import TouchSource, WorldFactory
from core.errors import CoreError, InvalidInputError
from core.evaluation import PlannedTouches, iter_trial
from core.features.pipeline import means_pipeline
from core.features.raw import raw_touch
from core.recognition import (
    ActionBox,
    Planner,
    Policy,
    RecognitionSession,
    RecognitionSettings,
    RecognitionStep,
    default_prior,
    make_policy,
)
from core.types import GaussianBelief, ManifoldModel
from hardware.errors import HardwareError

logger = logging.getLogger(__name__)

#: Scripted trials whose recognition session is kept in memory.
MAX_LIVE_SCRIPTED = 256


# --- building a recognition session from a trial ---------------------------------------------


def _policy(trial: Trial) -> Policy:
    fixed = trial.options.get("fixed_action") if trial.policy == "fixed" else None
    return make_policy(trial.policy, None if fixed is None else np.asarray(fixed, dtype=float))


@dataclass
class _Live:
    """An in-memory recognition session of a trial and its random stream."""

    model: ManifoldModel
    session: RecognitionSession
    rng: np.random.Generator


class TrialService:
    """Creates, drives and controls trials.

    Args:
        settings: App settings (limits).
        database: Where trials live.
        events: Where steps and states are announced.
        models: Loads fitted models.
        jobs: Runs the simulated and rig trials.
        worlds: Makes the touch sources of simulated and rig trials.
        rig: This server's rig (slots of its simulated objects).
    """

    def __init__(
        self,
        settings: Settings,
        database: Database,
        events: EventBus,
        models: ReadyModels,
        jobs: JobRunner,
        worlds: WorldFactory,
        rig: RigService,
    ) -> None:
        self._settings = settings
        self._database = database
        self._events = events
        self._models = models
        self._jobs = jobs
        self._worlds = worlds
        self._rig = rig
        self._planners: OrderedDict[tuple[Any, ...], tuple[ManifoldModel, Planner]] = OrderedDict()
        self._planner_lock = threading.Lock()
        # Live sessions of scripted trials (a session evicted here is rebuilt by replay).
        self._scripted: OrderedDict[int, _Live] = OrderedDict()

    # --- creation -----------------------------------------------------------------------------

    def _planner(self, model_id: int, model: ManifoldModel, trial: Trial) -> Planner:
        box_key = (
            None
            if trial.action_lower is None or trial.action_upper is None
            else (tuple(trial.action_lower.tolist()), tuple(trial.action_upper.tolist()))
        )
        fixed = trial.options.get("fixed_action")
        key = (model_id, trial.policy, tuple(fixed) if fixed else None, box_key)
        with self._planner_lock:
            cached = self._planners.get(key)
            if cached is not None and cached[0] is model:
                self._planners.move_to_end(key)
                return cached[1]
        box = None
        if trial.action_lower is not None and trial.action_upper is not None:
            box = ActionBox(lower=trial.action_lower, upper=trial.action_upper)
        planner = Planner(model, _policy(trial), box=box)
        with self._planner_lock:
            self._planners[key] = (model, planner)
            while len(self._planners) > 16:
                self._planners.popitem(last=False)
        return planner

    def _recognition(self, model: ManifoldModel, trial: Trial) -> RecognitionSession:
        return RecognitionSession(
            model,
            self._planner(trial.model_id, model, trial),
            GaussianBelief(mean=trial.prior_mean, cov=trial.prior_cov),
            RecognitionSettings(
                max_steps=trial.max_steps,
                tolerance=trial.tolerance,
                confidence_threshold=trial.confidence_threshold,
            ),
        )

    def create(self, session: Session, body: TrialCreate) -> TrialPublic:
        """Check a trial request, store it and (simulated/rig) start driving it.

        Raises:
            NotFoundError: No such model.
            ConflictError: The model is not ready, or the rig is held by another run.
            BadInputError: A setting does not fit the model (the field is named).
        """
        model = self._models.load(session, body.model_id)
        fields = self._check_request(model, body)
        simulation: SimulationOptions | None = None
        if body.mode == "simulated":
            simulation = body.simulation or SimulationOptions()
            if simulation.step_interval_s > self._settings.max_simulated_step_interval_s:
                raise BadInputError(
                    f"simulation.step_interval_s: at most "
                    f"{self._settings.max_simulated_step_interval_s} s on this server.",
                    field="simulation.step_interval_s",
                )
        options: dict[str, Any] = {}
        if body.fixed_action is not None:
            options["fixed_action"] = list(body.fixed_action)
        if simulation is not None:
            options["simulation"] = simulation.model_dump()
        target_slot = body.target_slot
        if body.mode == "rig" and target_slot is None and body.target is not None:
            known = crud.get_object_by_name(session, body.target)
            target_slot = known.slot if known is not None else self._rig.slot_of(body.target)
        if target_slot is not None:
            options["target_slot"] = target_slot
        if body.mode != "scripted":
            # Validates the world/rig and the target before anything is stored.
            self._worlds.check(body.mode, simulation, model, body.target, target_slot)
        if body.mode == "rig" and (holder := self._rig.holder) is not None:
            raise ConflictError(f"The rig is in use by {holder}.", held_by=holder)
        trial = crud.create_trial(
            session,
            model_id=body.model_id,
            mode=body.mode,
            policy=body.policy,
            status="queued",
            max_steps=body.max_steps,
            tolerance=body.tolerance,
            confidence_threshold=body.confidence_threshold,
            target=body.target,
            seed=body.seed,
            options=options,
            **fields,
        )
        # Builds the planner now: a bad box or action fails the request, not the run.
        try:
            self._recognition(model, trial)
        except InvalidInputError as exc:
            session.rollback()
            raise BadInputError(str(exc), field="action_bounds") from exc
        if body.mode == "scripted":
            crud.set_trial_status(session, trial, "running")
            session.commit()
            self._announce_status(trial)
        else:
            trial_id = trial.id
            self._jobs.commit_and_start(
                session,
                "trial",
                trial_id,
                lambda job: self._drive(job, trial_id),
                announce=lambda: self._announce_status(trial),
                fail=lambda reason: self._fail(trial_id, reason),
                take_rig=self._rig.take if body.mode == "rig" else None,
            )
        session.refresh(trial)
        return to_public(session, trial)

    @staticmethod
    def _check_request(model: ManifoldModel, body: TrialCreate) -> dict[str, Any]:
        ds = model.latent_dim
        dx = model.hyperparameters.action_dim
        prior = default_prior(model)
        mean = np.asarray(body.prior_mean if body.prior_mean is not None else prior.mean)
        if mean.shape != (ds,):
            raise BadInputError(
                f"prior_mean: expected {ds} values (the model's latent_dim), received "
                f"{mean.shape[0]}.",
                field="prior_mean",
            )
        if body.prior_cov is not None:
            rows = [len(r) for r in body.prior_cov]
            if len(rows) != ds or any(n != ds for n in rows):
                raise BadInputError(
                    f"prior_cov: expected a {ds}×{ds} matrix, received rows of lengths {rows}.",
                    field="prior_cov",
                )
        cov = np.asarray(body.prior_cov if body.prior_cov is not None else prior.cov)
        try:
            GaussianBelief(mean=mean, cov=cov)
        except InvalidInputError as exc:
            raise BadInputError(str(exc), field="prior_cov") from exc
        fields: dict[str, Any] = {"prior_mean": mean, "prior_cov": cov}
        if body.action_bounds is not None:
            lower, upper = body.action_bounds.lower, body.action_bounds.upper
            for name, values in (("lower", lower), ("upper", upper)):
                if len(values) != dx:
                    raise BadInputError(
                        f"action_bounds.{name}: expected {dx} values (the model's action_dim), "
                        f"received {len(values)}.",
                        field=f"action_bounds.{name}",
                    )
            try:
                box = ActionBox(lower=np.asarray(lower), upper=np.asarray(upper))
            except InvalidInputError as exc:
                raise BadInputError(str(exc), field="action_bounds") from exc
            fields["action_lower"] = box.lower
            fields["action_upper"] = box.upper
        if body.policy == "fixed":
            if body.fixed_action is None or len(body.fixed_action) != dx:
                got = "none" if body.fixed_action is None else str(len(body.fixed_action))
                raise BadInputError(
                    f"fixed_action: the fixed policy needs an action of {dx} values, "
                    f"received {got}.",
                    field="fixed_action",
                )
        elif body.fixed_action is not None:
            raise BadInputError(
                f"fixed_action: only used with policy 'fixed', not {body.policy!r}.",
                field="fixed_action",
            )
        return fields

    # --- scripted trials ----------------------------------------------------------------------

    def _live(self, session: Session, trial: Trial) -> _Live:
        """The scripted trial's session, rebuilt by replaying its recorded steps if needed."""
        live = self._scripted.get(trial.id)
        model = self._models.load(session, trial.model_id)
        if live is not None and live.model is model:
            return live
        recognition = self._recognition(model, trial)
        for step in crud.trial_steps(session, trial.id):
            recognition.observe(step.action, step.observation)
        live = _Live(model=model, session=recognition, rng=np.random.default_rng(trial.seed))
        self._scripted[trial.id] = live
        while len(self._scripted) > MAX_LIVE_SCRIPTED:
            self._scripted.popitem(last=False)
        return live

    def _require_scripted_running(self, trial: Trial) -> None:
        if trial.mode != "scripted":
            raise ConflictError(
                f"Trial {trial.id} is a {trial.mode} trial: the server drives it.",
                current_state=trial.status,
            )
        if trial.status != "running":
            raise ConflictError(
                f"Trial {trial.id} is {trial.status}; it takes actions only while running.",
                current_state=trial.status,
            )

    def next_action(self, session: Session, trial_id: int) -> NextAction:
        """The planner's advice for the next touch of a scripted trial."""
        with self._jobs.run_lock("trial", trial_id):
            trial = require(session, trial_id)
            self._require_scripted_running(trial)
            live = self._live(session, trial)
            planned = live.session.suggest(live.rng)
            return NextAction(
                step=trial.n_steps + 1,
                action=planned.action.tolist(),
                mutual_information=planned.mutual_information,
            )

    def observe(self, session: Session, trial_id: int, body: ObservationIn) -> ObservationResult:
        """Record a touch the caller performed and update the beliefs."""
        with self._jobs.run_lock("trial", trial_id):
            trial = require(session, trial_id)
            self._require_scripted_running(trial)
            live = self._live(session, trial)
            h = live.model.hyperparameters
            observation = observation_of(body, live.model)
            for name, values, expected in (
                ("action", body.action, h.action_dim),
                ("observation", observation, h.observation_dim),
            ):
                if len(values) != expected:
                    raise BadInputError(
                        f"{name}: expected {expected} values for this model, received "
                        f"{len(values)}.",
                        field=name,
                    )
            started = time.perf_counter()
            step = live.session.observe(np.asarray(body.action), np.asarray(observation))
            row = self._store_step(
                session, trial, live.model, step, body.trajectory, time.perf_counter() - started
            )
            session.commit()
            if trial.status not in states.ACTIVE:
                self._scripted.pop(trial.id, None)
        names = list(live.model.object_names)
        self._announce_step(trial, row, names)
        return ObservationResult(
            step=row.step,
            belief=Belief(mean=row.belief_mean.tolist(), cov=row.belief_cov.tolist()),
            nearest_object=row.nearest_object,
            answer=row.answer,
            probabilities=dict(zip(names, row.probabilities.tolist(), strict=True)),
            done=step.done,
            stop_reason=step.stop_reason,
            status=trial.status,
            result=trial_result(trial),
        )

    # --- recording ----------------------------------------------------------------------------

    @staticmethod
    def _store_step(
        session: Session,
        trial: Trial,
        model: ManifoldModel,
        step: RecognitionStep,
        trajectory: dict[str, Any] | None,
        duration_s: float,
    ) -> TrialStep:
        names = model.object_names
        if step.step != trial.n_steps + 1:
            raise ConflictError(
                f"Trial {trial.id}: step {step.step} does not follow the {trial.n_steps} "
                "recorded steps.",
                current_state=trial.status,
            )
        row = crud.add_trial_step(
            session,
            trial,
            action=step.action,
            observation=step.observation,
            trajectory=trajectory,
            mutual_information=step.mutual_information,
            belief_mean=step.belief.mean,
            belief_cov=step.belief.cov,
            probabilities=step.probabilities,
            nearest_object=names[step.nearest_object],
            answer=names[step.answer],
            stop_reason=step.stop_reason,
            duration_s=duration_s,
        )
        if step.done and trial.status in ("running", "paused"):
            crud.set_trial_status(session, trial, "completed", reason=step.stop_reason)
            TrialService._set_result(trial, names[step.answer])
        return row

    @staticmethod
    def _set_result(trial: Trial, answer: str) -> None:
        trial.result_object = answer
        trial.result_correct = None if trial.target is None else answer == trial.target

    def _announce_status(self, trial: Trial) -> None:
        self._events.publish(
            "trial.status",
            {
                "trial_id": trial.id,
                "status": trial.status,
                "reason": trial.reason,
                "n_steps": trial.n_steps,
                "result": None if (r := trial_result(trial)) is None else r.model_dump(),
            },
        )

    def _announce_step(self, trial: Trial, row: TrialStep, names: list[str]) -> None:
        self._events.publish(
            "trial.step",
            {"trial_id": trial.id, **step_public(row, names).model_dump(mode="json")},
        )
        if trial.status not in states.ACTIVE:
            self._announce_status(trial)

    # --- control ------------------------------------------------------------------------------

    def control(self, session: Session, trial_id: int, action: states.Action) -> TrialPublic:
        """Pause, resume, stop or abort a trial (409 with the current state if not allowed)."""
        with self._jobs.run_lock("trial", trial_id):
            trial = require(session, trial_id)
            target = states.check_action(f"trial {trial_id}", trial.status, action)
            crud.set_trial_status(session, trial, target, reason=f"{action} requested")
            if target == "stopped":
                steps = crud.trial_steps(session, trial_id)
                if steps:
                    self._set_result(trial, steps[-1].answer)
            session.commit()
            handle = self._jobs.handle("trial", trial_id)
            if handle is not None:
                handle.control(action)
            if target in states.FINISHED:
                self._scripted.pop(trial_id, None)
        if action == "abort" and trial.mode == "rig":
            self._worlds.halt()
        self._announce_status(trial)
        return to_public(session, trial)

    # --- simulated and rig trials -------------------------------------------------------------

    def _drive(self, handle: Job, trial_id: int) -> None:
        """Worker: plan, touch, record, until done, stopped or failed.

        The write that ends the trial (its last step, or the failure) is made only after the
        touch source is closed and the rig given back, so a trial seen as ended never still
        holds the rig.
        """
        source: TouchSource | None = None
        end: Callable[[], None] | None = None
        try:
            with self._database.session() as session:
                trial = require(session, trial_id)
                model = self._models.load(session, trial.model_id)
                recognition = self._recognition(model, trial)
                simulation = trial.options.get("simulation")
                options = SimulationOptions(**simulation) if simulation else None
                source = self._worlds.open(
                    trial.mode,
                    options,
                    model,
                    trial.target,
                    trial.options.get("target_slot"),
                    owner=f"trial {trial_id}",
                    lease=handle.lease,
                )
                interval_s = options.step_interval_s if options is not None else 0.0
                # One stream for the planner and the world's noise.
                rng = np.random.default_rng(trial.seed)
                steps = iter_trial(recognition, PlannedTouches(source), rng, rng)
                with self._jobs.run_lock("trial", trial_id):
                    session.refresh(trial)
                    if trial.status != "queued":
                        return
                    crud.set_trial_status(session, trial, "running")
                    session.commit()
                self._announce_status(trial)
            while True:
                handle.checkpoint()
                started = time.perf_counter()
                step, touch = next(steps)  # plan, touch, update
                record = functools.partial(
                    self._record_worker_step,
                    trial_id,
                    model,
                    step,
                    touch.trajectory,
                    time.perf_counter() - started,
                )
                if step.done:
                    end = record
                    return
                record()
                handle.sleep(interval_s)
        except JobCancelled as cancelled:
            if cancelled.kind == "shutdown":
                end = functools.partial(self._fail, trial_id, INTERRUPTED)
            else:  # normally already set by the request; an e-stop only tells the handle
                end = functools.partial(
                    self._fail, trial_id, f"{cancelled.kind} by the operator", cancelled.kind
                )
        except HardwareError as exc:
            requested = handle.stop_requested
            if requested in ("stopped", "aborted"):  # the stop interrupted the touch
                end = functools.partial(
                    self._fail, trial_id, f"{requested} by the operator ({exc})", requested
                )
            else:
                end = functools.partial(self._fail, trial_id, f"{type(exc).__name__}: {exc}")
        except (CoreError, AppError, ValueError, ArithmeticError) as exc:
            end = functools.partial(self._fail, trial_id, f"{type(exc).__name__}: {exc}")
        except Exception as exc:
            logger.exception("trial %d crashed", trial_id)
            end = functools.partial(
                self._fail, trial_id, f"internal error: {type(exc).__name__}: {exc}"
            )
        finally:
            if source is not None:
                source.close()
            if handle.lease is not None:
                handle.lease.release()
            if end is not None:
                self._end(trial_id, end)

    def _end(self, trial_id: int, end: Callable[[], None]) -> None:
        """Make the write that ends a trial; if that fails, fail the trial instead of leaving it
        running."""
        try:
            end()
        except (CoreError, AppError, ValueError, ArithmeticError) as exc:
            self._fail(trial_id, f"{type(exc).__name__}: {exc}")
        except Exception as exc:
            logger.exception("trial %d: its last step could not be recorded", trial_id)
            self._fail(trial_id, f"internal error: {type(exc).__name__}: {exc}")

    def _record_worker_step(
        self,
        trial_id: int,
        model: ManifoldModel,
        step: RecognitionStep,
        trajectory: dict[str, Any] | None,
        duration_s: float,
    ) -> None:
        with self._jobs.run_lock("trial", trial_id), self._database.session() as session:
            trial = require(session, trial_id)
            row = self._store_step(session, trial, model, step, trajectory, duration_s)
            session.commit()
        self._announce_step(trial, row, list(model.object_names))

    def _fail(self, trial_id: int, reason: str, status: str = "failed") -> None:
        """End a trial that is still active (a stop request may have ended it already)."""
        with self._jobs.run_lock("trial", trial_id), self._database.session() as session:
            trial = crud.get_trial(session, trial_id)
            if trial is None or trial.status not in states.ACTIVE:
                return
            crud.set_trial_status(session, trial, status, reason=reason)
            if status == "stopped":
                steps = crud.trial_steps(session, trial_id)
                if steps:
                    self._set_result(trial, steps[-1].answer)
            session.commit()
        self._announce_status(trial)


def observation_of(body: ObservationIn, model: ManifoldModel) -> list[float]:
    """y of a posted observation: as given, or the raw touch through the model's pipeline.

    Raises:
        BadInputError: Neither or both of ``observation`` and ``channels``, or a raw touch the
            pipeline refuses (the message names the channel).
    """
    if (body.observation is None) == (body.channels is None):
        raise BadInputError(
            "give either 'observation' (y) or 'channels' (the raw touch), not both or neither.",
            field="observation",
        )
    if body.observation is not None:
        return list(body.observation)
    assert body.channels is not None
    try:
        touch = raw_touch({name: (c.rate_hz, c.samples) for name, c in body.channels.items()})
        pipeline = model.features or means_pipeline(touch)
        return [float(v) for v in pipeline.transform(touch)]
    except InvalidInputError as exc:
        raise BadInputError(f"channels: {exc}", field="channels") from None
