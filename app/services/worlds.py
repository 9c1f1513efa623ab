"""Touch sources of server-driven trials: synthetic worlds (core.worlds) and the rig.

A :class:`TouchSource` performs an action on the target object and returns what was felt.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from app.errors import BadInputError, DeviceUnavailableError
from app.schemas import SimulationOptions
from core.types import ManifoldModel
from core.validation import FloatArray
from core.worlds import Experiment1World, World, random_experiment2_world


@dataclass(frozen=True)
class Touch:
    """One touch: the action performed (dx,), the observation (dy,), optional trajectory."""

    action: FloatArray
    observation: FloatArray
    trajectory: dict[str, Any] | None = None


class TouchSource(Protocol):
    """Something that touches the target object."""

    def touch(self, action: FloatArray, rng: np.random.Generator) -> Touch:
        """Perform ``action`` (dx,) and return the touch."""
        ...

    def close(self) -> None:
        """Release what the source holds."""
        ...


@dataclass
class WorldTouchSource:
    """Touches object ``object_index`` of a synthetic world."""

    world: World
    object_index: int

    def touch(self, action: FloatArray, rng: np.random.Generator) -> Touch:
        """y = h(object, x) + noise."""
        observation = self.world.observe(self.object_index, action[None, :], rng)[0]
        return Touch(action=np.asarray(action, dtype=np.float64), observation=observation)

    def close(self) -> None:
        """Nothing to release."""


def make_world(options: SimulationOptions) -> World:
    """The synthetic world of a simulated trial."""
    if options.world == "experiment1":
        noise = 0.1 if options.noise_std is None else options.noise_std
        return Experiment1World(noise_std=noise)
    if options.world == "experiment2":
        noise = 0.05 if options.noise_std is None else options.noise_std
        return random_experiment2_world(np.random.default_rng(options.world_seed), noise_std=noise)
    raise BadInputError(
        f"simulation.world: {options.world!r} is not a synthetic world.", field="simulation.world"
    )


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
    """Checks and opens the touch source of a simulated or rig trial."""

    def check(
        self,
        mode: str,
        simulation: SimulationOptions | None,
        model: ManifoldModel,
        target: str | None,
        target_slot: int | None,
    ) -> None:
        """Raise a 422/503 error now if :meth:`open` would fail for these settings."""
        if mode == "simulated" and simulation is not None and simulation.world != "rig":
            world = make_world(simulation)
            _check_dims(world, model, "simulation.world")
            _target_index(world.object_names, target)
            return
        raise DeviceUnavailableError(
            "No rig is available on this server (the hardware layer is not installed)."
        )

    def open(
        self,
        mode: str,
        simulation: SimulationOptions | None,
        model: ManifoldModel,
        target: str | None,
        target_slot: int | None,
    ) -> TouchSource:
        """The touch source for a trial (checked by :meth:`check` at creation)."""
        self.check(mode, simulation, model, target, target_slot)
        assert simulation is not None
        world = make_world(simulation)
        return WorldTouchSource(world, _target_index(world.object_names, target))

    def halt(self) -> None:
        """Stop the rig at once (abort of a rig trial)."""
