"""Touch sources of server-driven trials: synthetic worlds (core.evaluation.worlds) and the rig.

A :class:`~app.services.touch.TouchSource` performs an action on the target object and returns
what was felt.
"""

from __future__ import annotations

from app.documents.raw_touches import raw_channel_names
from app.errors import BadInputError
from app.rig.build import SimulationMode, open_rig
from app.schemas import SimulationOptions
from app.services.rig import RigService, RigTouchSource
from app.services.touch import Touch, TouchSource
from core.errors import InvalidInputError
from core.evaluation import World, WorldTouches, make_world
from core.types import ManifoldModel
from hardware.rig import RigLease

__all__ = ["Touch", "TouchSource", "WorldFactory", "simulated_world"]


def simulated_world(options: SimulationOptions) -> World:
    """The synthetic world of a simulated trial (:func:`core.evaluation.worlds.make_world`).

    Raises:
        BadInputError: Not a synthetic world (the field is named).
    """
    try:
        return make_world(options.world, world_seed=options.world_seed, noise_std=options.noise_std)
    except InvalidInputError as exc:
        raise BadInputError(f"simulation.{exc}", field="simulation.world") from exc


def _check_dims(world: World, model: ManifoldModel, what: str) -> None:
    h = model.hyperparameters
    if (world.action_dim, world.observation_dim) != (h.action_dim, h.observation_dim):
        raise BadInputError(
            f"{what}: the world has dx={world.action_dim}, dy={world.observation_dim} but the "
            f"model has dx={h.action_dim}, dy={h.observation_dim}.",
            field=what,
        )


def _target_index(names: tuple[str, ...], target: str | None) -> int:
    if target is None:
        raise BadInputError(
            f"target: a simulated trial needs the object to touch, one of {list(names)}.",
            field="target",
        )
    if target not in names:
        raise BadInputError(
            f"target: {target!r} is not an object of the world; choose one of {list(names)}.",
            field="target",
        )
    return names.index(target)


class WorldFactory:
    """Checks and opens the touch source of a simulated or rig trial.

    Args:
        rig: This server's rig (for ``rig`` trials and the DMP action map).
    """

    def __init__(self, rig: RigService) -> None:
        self._rig = rig

    def _check_rig_dims(self, model: ManifoldModel, field: str) -> None:
        """The rig's touches must make the model's y: dy frame channels (the channel means),
        or, for a model with a feature pipeline, the raw channels the pipeline reads."""
        h = model.hyperparameters
        dx, dy = self._rig.rig_action_dim(model), self._rig.observation_dim
        if model.features is not None and h.action_dim == dx:
            made = raw_channel_names(self._rig.channel_names)
            needed = [p.name for p in model.features.channels]
            if sorted(made) != sorted(needed):
                raise BadInputError(
                    f"{field}: the rig's sensor gives the channels {list(made)}, the model's "
                    f"features read {needed}.",
                    field=field,
                )
            return
        if (h.action_dim, h.observation_dim) != (dx, dy):
            raise BadInputError(
                f"{field}: rig touches have dx={dx}, dy={dy} but the model has "
                f"dx={h.action_dim}, dy={h.observation_dim}; fit it on a rig collection.",
                field=field,
            )

    def check(
        self,
        mode: str,
        simulation: SimulationOptions | None,
        model: ManifoldModel,
        target: str | None,
        target_slot: int | None,
    ) -> None:
        """Raise a 422/503 error now if :meth:`open` would fail for these settings."""
        if mode == "simulated":
            options = simulation or SimulationOptions()
            if options.world == "rig":
                self._check_rig_dims(model, "simulation.world")
                _target_index(self._rig.sim_table, target)
                return
            world = simulated_world(options)
            _check_dims(world, model, "simulation.world")
            _target_index(world.object_names, target)
            return
        self._check_rig_dims(model, "mode")
        if target_slot is None:
            raise BadInputError(
                "target_slot: a rig trial needs the slot to touch (or a target whose slot is "
                "known from a collection).",
                field="target_slot",
            )

    def open(
        self,
        mode: str,
        simulation: SimulationOptions | None,
        model: ManifoldModel,
        target: str | None,
        target_slot: int | None,
        owner: str,
        lease: RigLease | None = None,
    ) -> TouchSource:
        """The touch source for a trial (checked by :meth:`check` at creation).

        ``owner`` names the trial to a simulated rig; a ``rig`` trial drives this server's rig
        through ``lease``, taken when the trial was created (the source's ``close`` gives it
        back).
        """
        self.check(mode, simulation, model, target, target_slot)
        if mode == "simulated":
            options = simulation or SimulationOptions()
            if options.world != "rig":
                world = simulated_world(options)
                return WorldTouches(
                    world, world.object_names[_target_index(world.object_names, target)]
                )
            handle = open_rig(
                simulate=SimulationMode.in_process,
                objects=self._rig.simulated_table.slots,
                seed=options.world_seed,
            )
            try:
                lease = handle.rig.acquire(owner)
                lease.connect()
                slot = _target_index(self._rig.sim_table, target)
            except BaseException:
                handle.close()
                raise
            return RigTouchSource(
                lease,
                self._rig.actions_for(model),
                slot,
                release=handle.close,
                features=model.features,
            )
        assert target_slot is not None
        if lease is None:
            raise ValueError("a rig trial drives the rig through the lease it was created with.")
        self._rig.ensure_connected(lease)
        return RigTouchSource(
            lease, self._rig.actions_for(model), target_slot, features=model.features
        )

    def halt(self) -> None:
        """Stop the rig at once (abort of a rig trial)."""
        self._rig.halt()
