"""Collections: a dataset gathered on the rig as a run with progress.

:func:`iter_collection` is the collection loop (a generator over the touches of a
:class:`core.evaluation.designs.CollectionDesign`) and :func:`iter_stages` runs it over a
collection's stages (the adaptive design's initial half and rounds), each with its own
placements (:func:`collection_stages`); the server's runs here and ``activetouch collect`` both
drive the rig through them, and check their object lists with :func:`check_objects`.

Each touch is stored as a sample (with its raw tactile series, its placement and its time:
seconds since the collection's first touch) the moment it is recorded; the dataset is
``collecting`` during the run, then ``ready`` (or ``failed`` if too little was gathered to learn
from). Each ``collection.progress`` event carries the touch's features, its placement, its time
and a thinned copy of its raw tactile series (``trace``: at most 200 frames) for the live plot.
"""

from __future__ import annotations

import dataclasses
import logging
from collections import Counter
from collections.abc import Callable, Iterator, Mapping, Sequence
from functools import partial
from typing import Literal

import numpy as np
from sqlalchemy.orm import Session

from app import crud, states
from app.db import Database
from app.db.tables import Run
from app.errors import AppError, BadInputError, ConflictError
from app.rig.actions import TouchActions
from app.rig.collection import CollectedTouch, iter_collect, since_first_touch
from app.schemas import CollectionCreate, Page, RunPublic, from_row
from app.services import objects
from app.services.events import EventBus
from app.services.jobs import INTERRUPTED, Job, JobCancelled, JobRunner
from app.services.rig import RigService, raw_series, trace_preview
from core.errors import CoreError
from core.evaluation import (
    CollectionDesign,
    planner_round,
    random_design,
    round_sizes,
    shared_design,
)
from core.gp import fit_manifold
from core.types import TrainingData
from hardware.errors import HardwareError
from hardware.rig import RigLease

logger = logging.getLogger(__name__)
KIND: Literal["collection"] = "collection"

#: Rounds of planner-chosen touches of the adaptive design, after its initial random half.
ADAPTIVE_ROUNDS = 2

#: Fewest touches per object the adaptive design can spend: 2 random ones, then a round of 1.
ADAPTIVE_MIN_TOUCHES = 3


def default_design(touches: int) -> tuple[Literal["adaptive", "random"], str | None]:
    """The design of a collection that names none: ``adaptive`` wherever it can run.

    Why adaptive: with the random design the planners' touches land where the GP extrapolates
    and the model is confidently wrong on the rig; the adaptive design spends half the same
    budget where the planners go (docs/calibration.md, "Adaptive training design"). It cannot
    run with fewer than :data:`ADAPTIVE_MIN_TOUCHES` touches per object; there the default is
    ``random``.

    Args:
        touches: Touches per object.

    Returns:
        The design, and ``None`` or the sentence saying why ``random`` replaced ``adaptive``.
    """
    if touches < ADAPTIVE_MIN_TOUCHES:
        return "random", (
            f"the default design is adaptive, but it needs {ADAPTIVE_MIN_TOUCHES} touches per "
            f"object or more (received {touches}), so the random design is used"
        )
    return "adaptive", None


def stage_sizes(design: str, touches: int) -> list[int]:
    """Touches per object of each stage of a collection: the adaptive design's initial random
    half and its rounds (:data:`ADAPTIVE_ROUNDS`), or the one stage of any other design.

    Raises:
        InvalidInputError: Too few touches for the adaptive design's initial half and a round.
    """
    if design != "adaptive":
        return [touches]
    initial = max(2, touches // 2)
    return [initial, *round_sizes(touches, initial, min(ADAPTIVE_ROUNDS, touches - initial))]


def default_placements(sizes: list[int]) -> int:
    """Placements per object of a collection that names none: three for every four touches.

    A recognition trial places its object once and touches it several times, and the touches of
    one placement share an offset (its pose and contact point; docs/calibration.md, "Fix 1"). The
    fit can only measure that offset from touches that share a placement, and a model without it
    counts a trial's shared offset once per touch: on the look-alike cups, whose placement moves
    the pressure by as much as one cup differs from the next, a model from fresh placements was
    sure and wrong in 15-17 % of its sure answers. Touches placed anew, on the other hand, show
    the GP more placements: on the textures a fresh placement per touch was 7-10 points more
    accurate than pairs. P = N - ⌊N/4⌋ (at least one pair) puts half the touches in pairs, which
    measure the offset, and places the other half anew; over the three built-in tables it passed
    more of the acceptance than either (docs/calibration.md, "Three placements for every four
    touches"). The fit puts the estimated effect in its likelihood
    (``core.gp.with_placement_effect``), so the runs' shared offsets are not learned as
    responses to the actions. At least one placement per stage of the design.

    Args:
        sizes: Touches per object of each stage (:func:`stage_sizes`).
    """
    touches = sum(sizes)
    return max(len(sizes), touches - max(1, touches // 4))


def stage_placements(placements: int, sizes: list[int]) -> list[int]:
    """Split an object's ``placements`` over the stages of its collection.

    Every stage gets one placement (a stage's touches are planned after the previous stage, so
    no placement spans two), the rest in proportion to the stages' remaining touches by largest
    remainder, never more placements than touches.

    Args:
        placements: P, placements per object in all.
        sizes: Touches per object of each stage (:func:`stage_sizes`).

    Returns:
        Placements per object of each stage; they sum to P.

    Raises:
        BadInputError: P is smaller than the number of stages or larger than the touches.
    """
    touches = sum(sizes)
    if not len(sizes) <= placements <= touches:
        stages = (
            f" (the design touches in {len(sizes)} stages, each with placements of its own)"
            if len(sizes) > 1
            else ""
        )
        raise BadInputError(
            f"placements: must lie in {len(sizes)}..{touches}, the touches per object"
            f"{stages}, received {placements}.",
            field="placements",
        )
    capacity = np.asarray(sizes, dtype=np.float64) - 1.0
    extra = placements - len(sizes)
    if extra == 0 or capacity.sum() == 0:
        return [1] * len(sizes)
    quota = extra * capacity / capacity.sum()
    share = np.floor(quota).astype(np.int64)
    for stage in np.argsort(-(quota - share), kind="stable")[: extra - int(share.sum())]:
        share[stage] += 1
    return [1 + int(k) for k in share]


def collection_stages(
    design: str, touches: int, placements: int | None
) -> tuple[list[int], list[int]]:
    """Touches and placements per object of each stage of a collection.

    Args:
        design: The action design (``adaptive`` touches in stages, any other in one).
        touches: Touches per object in all.
        placements: P, placements per object in all; ``None``: :func:`default_placements`.

    Returns:
        :func:`stage_sizes` and :func:`stage_placements` of the collection.

    Raises:
        InvalidInputError: Too few touches for the adaptive design.
        BadInputError: (field ``placements``) P outside what the stages allow.
    """
    sizes = stage_sizes(design, touches)
    return sizes, stage_placements(
        default_placements(sizes) if placements is None else placements, sizes
    )


def check_objects(objects: Mapping[str, int] | list[tuple[str, int]]) -> None:
    """Every object of a collection needs its own name and its own slot.

    Args:
        objects: ``name → slot`` (or ``(name, slot)`` pairs, where a name may repeat).

    Raises:
        BadInputError: A name or a slot is repeated (the message lists them).
    """
    pairs = list(objects.items()) if isinstance(objects, Mapping) else list(objects)
    for field, values in (("name", [n for n, _ in pairs]), ("slot", [s for _, s in pairs])):
        repeated = [v for v, n in Counter(values).items() if n > 1]
        if repeated:
            raise BadInputError(
                f"objects: each object needs its own {field}; repeated: {repeated}.",
                field=f"objects[].{field}",
            )


#: The run a placement gets when there are fewer than two touches per placement: the touches
#: beyond one per placement go into runs of this length. Two: runs of three would show how a
#: placement creeps from touch to touch (docs/method.md (S3)), but on the look-alike cups they
#: made the planners sure and wrong far more often (docs/calibration.md, "Press depth by
#: default, and runs of three"); pairs stay the default until that is understood.
RUN_LENGTH = 2


def placement_runs(n_touches: int, placements: int) -> list[range]:
    """Split an object's ``n_touches`` touches (in design order) into ``placements`` runs.

    With two touches per placement or more, the runs differ in length by at most one (the
    first ones take the remainder). With fewer, the touches beyond one per placement go into
    runs of :data:`RUN_LENGTH` (the first runs; one shorter run takes what is left), and the
    other placements get one touch each.

    Raises:
        BadInputError: ``placements`` < 1 or larger than ``n_touches`` (a placement needs a
            touch).
    """
    if placements < 1 or placements > n_touches:
        raise BadInputError(
            f"placements: must lie in 1..{n_touches} (the touches per object), received "
            f"{placements}.",
            field="placements",
        )
    size, extra = divmod(n_touches, placements)
    if size >= 2:
        lengths = [size + (1 if p < extra else 0) for p in range(placements)]
    else:
        runs, rest = divmod(n_touches - placements, RUN_LENGTH - 1)
        lengths = [RUN_LENGTH] * runs + ([1 + rest] if rest else [])
        lengths += [1] * (placements - len(lengths))
    groups, start = [], 0
    for length in lengths:
        groups.append(range(start, start + length))
        start += length
    return groups


def iter_collection(
    lease: RigLease,
    actions: TouchActions,
    slots: Mapping[str, int],
    design: CollectionDesign,
    placements: int | None = None,
    order_seed: int = 0,
    first_placement: int = 0,
) -> Iterator[CollectedTouch]:
    """Touch the objects on the rig as ``design`` says, one event per touch as it is recorded.

    Every design runs in rounds, the table turning between touches: a shared design (every
    object, the same M actions) each object at its own random permutation of the actions
    (:func:`app.rig.collection.iter_collect`, seeded by ``order_seed``), so that no action's
    touches follow each other; any other design takes each object's next action in turn. So
    every touch meets a fresh placement of its object, and the slow drift of the sensor and
    the room is spread over all the objects and actions instead of being learned as one
    object's signature or as part of one action's response (docs/simulation.md: touching one
    object 30 times in a row moved its mean pressure by 0.1, as much as a deep press separates
    two cushions). An interrupted collection keeps whole rounds.

    With ``placements`` = P, each object is instead placed P times and touched N_l / P times in
    a row at each placement (the table stays put), placement by placement in rounds over the
    objects; every touch records its placement (``first_placement`` + 0..P-1: a later stage of
    the same collection numbers on). A recognition trial touches one placement several times,
    so such a collection shows how much a placement (and the drift over its touches) shifts
    them alike: the fit estimates that variance from it (docs/calibration.md). With a shared
    design every object still gets the same actions, each object in its own random order
    (seeded by ``order_seed``) before the actions are dealt to its placements.

    Args:
        lease: A lease on a connected rig.
        actions: Action → trajectory map.
        slots: Object name → slot; object l of the design is the l-th entry.
        design: Which action touches which object (``object_index`` indexes ``slots``).
        placements: P, placements per object (1..N_l); ``None``: a fresh placement per touch.
        order_seed: Seed of a shared design's order (vary it between rounds of one collection).
        first_placement: Number of the first placement of each object (with ``placements``).

    Yields:
        One :class:`~app.rig.collection.CollectedTouch` per touch (``index``/``total`` count the
        whole design; ``time_s`` from the design's first touch).

    Raises:
        BadInputError: The design touches an object that is not in ``slots``, a shared
            design gives the objects different numbers of actions, or ``placements`` is
            outside 1..N_l for some object.
    """
    yield from since_first_touch(
        _design_touches(lease, actions, slots, design, placements, order_seed, first_placement)
    )


def _design_touches(
    lease: RigLease,
    actions: TouchActions,
    slots: Mapping[str, int],
    design: CollectionDesign,
    placements: int | None,
    order_seed: int,
    first_placement: int,
) -> Iterator[CollectedTouch]:
    """:func:`iter_collection`'s touches, in the order they are made (undated)."""
    names = list(slots)
    index = np.asarray(design.object_index)
    if index.size and (int(index.min()) < 0 or int(index.max()) >= len(names)):
        raise BadInputError(
            f"design: touches object {int(index.max())}, but only {len(names)} objects "
            f"are given ({names}).",
            field="objects",
        )
    rows = [np.flatnonzero(index == obj) for obj in range(len(names))]
    if design.shared:
        counts = {len(r) for r in rows}
        if len(counts) != 1:
            raise BadInputError(
                f"design: a shared design gives every object the same actions; the objects "
                f"have {sorted(counts)} actions.",
                field="action_design",
            )
    total, done = design.n_touches, 0
    if placements is not None:
        if design.shared:
            rng = np.random.default_rng(order_seed)
            rows = [r[rng.permutation(r.size)] for r in rows]
        groups = [placement_runs(len(r), placements) for r in rows]
        for p in range(placements):
            for name, object_rows, object_groups in zip(names, rows, groups, strict=True):
                for k, position in enumerate(object_groups[p]):
                    row = object_rows[position]
                    record = actions.touch(
                        lease, design.actions[row], slot=slots[name] if k == 0 else None
                    )
                    yield CollectedTouch(
                        done,
                        total,
                        name,
                        slots[name],
                        design.actions[row].copy(),
                        record,
                        first_placement + p,
                    )
                    done += 1
        return
    if design.shared:
        yield from iter_collect(lease, actions, dict(slots), design.actions[rows[0]], order_seed)
        return
    for turn in range(max(len(r) for r in rows)):
        for name, object_rows in zip(names, rows, strict=True):
            if turn >= object_rows.size:
                continue
            action = design.actions[object_rows[turn] : object_rows[turn] + 1]
            for touch in iter_collect(lease, actions, {name: slots[name]}, action):
                yield dataclasses.replace(touch, index=done, total=total)
                done += 1


def iter_stages(
    lease: RigLease,
    actions: TouchActions,
    slots: Mapping[str, int],
    plan: CollectionDesign,
    placements: Sequence[int],
    next_round: Callable[[list[CollectedTouch]], CollectionDesign | None] | None = None,
    seed: int = 0,
    planning: Callable[[], None] | None = None,
) -> Iterator[CollectedTouch]:
    """The touches of ``plan``, then of each round ``next_round`` plans from the touches so far.

    Stage k is touched at ``placements[k]`` placements per object (:func:`iter_collection`),
    numbered on from the stage before, so that no placement spans two stages and every
    placement number of an object is its own; a shared design's order is seeded by ``seed``
    plus the stage's number.

    Args:
        lease: A lease on a connected rig.
        actions: Action → trajectory map.
        slots: Object name → slot; object l of a design is the l-th entry.
        plan: The first stage's design.
        placements: Placements per object of each stage (:func:`collection_stages`); their
            number is the number of stages.
        next_round: Plans the next stage from every touch recorded so far (e.g.
            :class:`AdaptiveRounds`); ``None``: ``plan`` is the only stage.
        seed: Seed of a shared design's order.
        planning: Called before each next round is planned (e.g. to say so on a progress bar).

    Yields:
        One :class:`~app.rig.collection.CollectedTouch` per touch, as it is recorded, its
        ``time_s`` counted from the first touch of the first stage.
    """
    yield from since_first_touch(
        _stage_touches(lease, actions, slots, plan, placements, next_round, seed, planning)
    )


def _stage_touches(
    lease: RigLease,
    actions: TouchActions,
    slots: Mapping[str, int],
    plan: CollectionDesign,
    placements: Sequence[int],
    next_round: Callable[[list[CollectedTouch]], CollectionDesign | None] | None,
    seed: int,
    planning: Callable[[], None] | None,
) -> Iterator[CollectedTouch]:
    """:func:`iter_stages`'s touches, stage after stage (each dated from its stage's first)."""
    recorded: list[CollectedTouch] = []
    current: CollectionDesign | None = plan
    for stage, count in enumerate(placements):
        if current is None:
            return
        first = sum(placements[:stage])
        for touch in iter_collection(lease, actions, slots, current, count, seed + stage, first):
            yield touch
            recorded.append(touch)
        current = None
        if next_round is not None and stage + 1 < len(placements):
            if planning is not None:
                planning()
            current = next_round(recorded)


def to_public(run: Run) -> RunPublic:
    """The API view of a run."""
    return from_row(RunPublic, run)


require = partial(crud.require, Run, kind=KIND)


def get(session: Session, run_id: int) -> RunPublic:
    """One collection run."""
    return to_public(require(session, run_id))


def list_page(session: Session, status: str | None, limit: int, offset: int) -> Page[RunPublic]:
    """Collection runs, newest first."""
    rows, count = crud.list_runs(session, KIND, status, limit, offset)
    return Page[RunPublic](data=[to_public(r) for r in rows], count=count)


class AdaptiveRounds:
    """The adaptive design's rounds: fit the touches so far, plan the next round from the model.

    The fit is ``fit``'s default (ds = 2, noise model auto); the round's actions come from
    :func:`core.evaluation.adaptive_design.planner_round`, each on every object.

    Args:
        names: The objects, in the order of the design's object indices.
        touches: Touches per object in all (initial design and rounds).
        sizes: Touches per object of each round after the initial random design.
        seed: Seeds the fits and the rounds' candidate sets.
        check: Called with each round's design before it is touched (e.g. the joint limits).
    """

    def __init__(
        self,
        names: list[str],
        touches: int,
        sizes: list[int],
        seed: int,
        check: Callable[[CollectionDesign], None] | None = None,
    ) -> None:
        self.names = tuple(names)
        self.touches = touches
        self.sizes = list(sizes)
        self.seed = seed
        self.check = check
        self.rng = np.random.default_rng([seed, 1])

    def __call__(self, recorded: list[CollectedTouch]) -> CollectionDesign | None:
        """The next round's design (``None``: the budget is spent)."""
        if not self.sizes:
            return None
        data = TrainingData(
            object_names=self.names,
            object_index=np.array([self.names.index(t.object_name) for t in recorded]),
            actions=np.array([t.action for t in recorded]),
            observations=np.array([t.record.observation for t in recorded]),
        )
        model = fit_manifold(data, 2, np.random.default_rng(self.seed), noise_model="auto")
        design = planner_round(model, self.sizes.pop(0), self.rng)
        if self.check is not None:
            self.check(design)
        return design


class CollectionService:
    """Starts, drives and controls collection runs on the rig."""

    def __init__(
        self, database: Database, events: EventBus, jobs: JobRunner, rig: RigService
    ) -> None:
        self._database = database
        self._events = events
        self._jobs = jobs
        self._rig = rig

    def create(self, session: Session, body: CollectionCreate) -> RunPublic:
        """Check a collection request, store the run and its (empty) dataset, start it."""
        check_objects([(o.name, o.slot) for o in body.objects])
        design = body.action_design
        if design is None:
            design, _ = default_design(body.samples_per_object)
        if design == "adaptive" and body.samples_per_object < ADAPTIVE_MIN_TOUCHES:
            raise BadInputError(
                f"samples_per_object: the adaptive design needs {ADAPTIVE_MIN_TOUCHES} or more "
                "(2 random touches per object, then at least one round), received "
                f"{body.samples_per_object}.",
                field="samples_per_object",
            )
        _, stages = collection_stages(design, body.samples_per_object, body.placements)
        # The run's params record the design and the placements used.
        body = body.model_copy(update={"action_design": design, "placements": sum(stages)})
        if body.action_scale is None:
            body = body.model_copy(update={"action_scale": self._rig.design_std})
        holder = self._rig.holder
        if holder is not None:
            raise ConflictError(f"The rig is in use by {holder}.", held_by=holder)
        actions = self._rig.actions(body.press_depth, body.touch_duration_s)
        dx, dy = actions.action_dim, self._rig.observation_dim
        dataset = crud.create_dataset(
            session,
            name=body.name or "rig collection",
            source="collection",
            status="collecting",
            object_names=[o.name for o in body.objects],
            action_dim=dx,
            observation_dim=dy,
            touch_duration_s=actions.duration_s,
        )
        for item in body.objects:
            crud.set_object_slot(session, item.name, item.slot)
        objects.record_known_properties(
            session, {o.name: o.slot for o in body.objects}, self._rig.object_properties()
        )
        run = crud.create_run(
            session,
            kind=KIND,
            status="queued",
            params=body.model_dump(mode="json"),
            done=0,
            total=len(body.objects) * body.samples_per_object,
            dataset_id=dataset.id,
        )
        run_id = run.id
        self._jobs.commit_and_start(
            session,
            KIND,
            run_id,
            lambda job: self._collect(job, run_id),
            announce=lambda: self._announce(run),
            fail=lambda reason: self._finish(run_id, "failed", reason),
            take_rig=self._rig.take,
        )
        session.refresh(run)
        return to_public(run)

    def _announce(self, run: Run) -> None:
        self._events.publish(
            "collection.status",
            {
                "collection_id": run.id,
                "status": run.status,
                "reason": run.reason,
                "done": run.done,
                "total": run.total,
                "dataset_id": run.dataset_id,
            },
        )

    def _collect(self, job: Job, run_id: int) -> None:
        """The job: touch, store each touch, give the rig back, then end the run."""
        try:
            with self._database.session() as session:
                run = require(session, run_id)
                body = CollectionCreate.model_validate(run.params)
            design = self._design(body)
            rounds = self._rounds(body)
            assert body.action_design is not None  # create() recorded the design used
            _, stages = collection_stages(
                body.action_design, body.samples_per_object, body.placements
            )
            slots = {o.name: o.slot for o in body.objects}
            assert job.lease is not None
            with job.lease as lease:
                job.checkpoint()
                self._rig.ensure_connected(lease)
                with self._jobs.run_lock(KIND, run_id), self._database.session() as session:
                    run = require(session, run_id)
                    if run.status != "queued":
                        return
                    crud.set_run_status(session, run, "running")
                    session.commit()
                self._announce(run)
                touches = iter_stages(
                    lease,
                    self._rig.actions(body.press_depth, body.touch_duration_s),
                    slots,
                    design,
                    stages,
                    rounds,
                    body.seed or 0,
                )
                for touch in touches:
                    self._store(run_id, touch)
                    if touch.index + 1 < touch.total or rounds is not None:
                        job.checkpoint()
            self._finish(run_id, "completed", None)
        except JobCancelled as cancelled:
            if cancelled.kind == "shutdown":
                self._finish(run_id, "failed", INTERRUPTED)
            else:  # normally already set by the request; an e-stop only tells the handle
                self._finish(run_id, cancelled.kind, f"{cancelled.kind} by the operator")
        except HardwareError as exc:
            requested = job.stop_requested
            if requested in ("stopped", "aborted"):  # the stop interrupted the touch
                self._finish(run_id, requested, f"{requested} by the operator ({exc})")
            else:
                self._finish(run_id, "failed", f"{type(exc).__name__}: {exc}")
        except (CoreError, AppError, ValueError) as exc:
            self._finish(run_id, "failed", f"{type(exc).__name__}: {exc}")
        except Exception as exc:
            logger.exception("collection %d crashed", run_id)
            self._finish(run_id, "failed", f"internal error: {type(exc).__name__}: {exc}")

    def _design(self, body: CollectionCreate) -> CollectionDesign:
        """The request's design (:mod:`core.evaluation.designs`), x ~ N(0, action_scale² I).

        ``random``: a fresh action for every touch (the paper's design; each object gets its own
        ``samples_per_object`` actions). ``shared``: M = ``samples_per_object`` actions
        (scrambled Sobol through the prior), each applied to every object in turn. ``teaching``:
        the teaching action x = 0, M times on every object.
        """
        rng = np.random.default_rng(body.seed)
        dx = self._rig.actions(body.press_depth).action_dim
        n_objects, per_object = len(body.objects), body.samples_per_object
        if body.action_design == "adaptive":  # its first, random half; then self._rounds
            per_object = stage_sizes("adaptive", per_object)[0]
        scale = self._rig.design_std if body.action_scale is None else body.action_scale
        mean, cov = np.zeros(dx), scale**2 * np.eye(dx)
        if body.action_design in ("random", "adaptive"):
            return random_design(n_objects, per_object, mean, cov, rng)
        if body.action_design == "shared":
            return shared_design(n_objects, per_object, mean, cov, rng)
        return CollectionDesign(
            object_index=np.repeat(np.arange(n_objects, dtype=np.int64), per_object),
            actions=np.zeros((n_objects * per_object, dx)),
            shared=True,
        )

    def _rounds(self, body: CollectionCreate) -> AdaptiveRounds | None:
        """The adaptive design's later rounds (``None`` for the other designs)."""
        if body.action_design != "adaptive":
            return None
        touches = body.samples_per_object
        sizes = stage_sizes("adaptive", touches)[1:]
        names = [o.name for o in body.objects]
        return AdaptiveRounds(names, touches, sizes, 0 if body.seed is None else body.seed)

    def _store(self, run_id: int, touch: CollectedTouch) -> None:
        """Store a touch as a sample of the run's dataset (with its raw series, placement and
        time) and announce it."""
        name, record = touch.object_name, touch.record
        with self._jobs.run_lock(KIND, run_id), self._database.session() as session:
            run = require(session, run_id)
            dataset = crud.get_dataset(session, run.dataset_id or 0)
            assert dataset is not None
            crud.add_samples(
                session,
                dataset,
                [
                    (
                        name,
                        touch.action,
                        record.observation,
                        raw_series(record),
                        touch.placement,
                        touch.time_s,
                    )
                ],
            )
            run.done += 1
            session.commit()
            done, total, status = run.done, run.total, run.status
        self._events.publish(
            "collection.progress",
            {
                "collection_id": run_id,
                "done": done,
                "total": total,
                "status": status,
                "object": name,
                "placement": touch.placement,
                "time_s": touch.time_s,
                "observation": record.observation.tolist(),
                "trace": trace_preview(record),
            },
        )

    def _finish(self, run_id: int, status: str | None, reason: str | None) -> None:
        """End the run (``status=None``: a stop/abort already set it) and settle its dataset."""
        with self._jobs.run_lock(KIND, run_id), self._database.session() as session:
            run = require(session, run_id)
            if status is not None and run.status in states.ACTIVE:
                crud.set_run_status(session, run, status, reason)
            dataset = crud.get_dataset(session, run.dataset_id or 0)
            if dataset is not None and dataset.status == "collecting":
                counts = Counter(row[0] for row in crud.dataset_samples(session, dataset.id))
                usable = len(counts) >= 2 and min(counts.values()) >= 2
                complete = usable and all(counts[n] >= 2 for n in dataset.object_names)
                dataset.status = "ready" if complete else "failed"
            session.commit()
        self._announce(run)

    def control(self, session: Session, run_id: int, action: states.Action) -> RunPublic:
        """Pause, resume, stop or abort a collection (409 with the current state if not allowed)."""
        with self._jobs.run_lock(KIND, run_id):
            run = require(session, run_id)
            target = states.check_action(f"collection {run_id}", run.status, action)
            crud.set_run_status(session, run, target, reason=f"{action} requested")
            session.commit()
            job = self._jobs.handle(KIND, run_id)
            if job is not None:
                job.control(action)
        if action == "abort":
            self._rig.halt()
        self._announce(run)
        return to_public(run)
