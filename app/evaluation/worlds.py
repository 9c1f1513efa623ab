"""The worlds of an evaluation: the checks that name what does not fit the model."""

from __future__ import annotations

from typing import TYPE_CHECKING

from app.errors import BadInputError
from app.evaluation.context import rig_tables, synthetic_world
from app.rig.press_depth import rig_action_dim
from core.evaluation import WORLD_NAMES
from core.types import ManifoldModel, TrainingData
from hardware.sim.materials import table_name

if TYPE_CHECKING:
    from app.evaluation.spec import EvaluationSpec
    from hardware.sim.materials import Table


def table_objects(name: str | Table | None) -> tuple[str, ...]:
    """The objects of a rig table by name, or of a table read from a file (slot 0 first).

    Raises:
        BadInputError: Unknown table (the message lists them).
    """
    if name is not None and not isinstance(name, str):
        return name.objects
    tables = rig_tables()
    key = "default" if name is None else name
    if key not in tables:
        raise BadInputError(
            f"table: {name!r} is not a simulated table; choose from {sorted(tables)}.",
            field="table",
        )
    return tables[key]


def _dims_error(field: str, what: str, dx: int, dy: int, model: ManifoldModel) -> BadInputError:
    h = model.hyperparameters
    return BadInputError(
        f"{field}: {what} has dx={dx}, dy={dy} but the model has dx={h.action_dim}, "
        f"dy={h.observation_dim}.",
        field=field,
    )


def check_world(spec: EvaluationSpec, model: ManifoldModel, replay: TrainingData | None) -> None:
    """World-specific checks of :meth:`EvaluationSpec.check`."""
    h = model.hyperparameters
    targets = spec.target_names(model)
    if spec.world != "rig" and spec.table is not None:
        raise BadInputError("table: only the rig world has a table.", field="table")
    if spec.world != "rig" and spec.placement != "trial":
        raise BadInputError(
            "placement: only the rig world places objects ('touch' is for world 'rig').",
            field="placement",
        )
    if spec.world != "replay" and replay is not None:
        raise BadInputError(
            f"data: held-out touches are for the replay world, not {spec.world!r}.", field="data"
        )
    if spec.world in WORLD_NAMES:
        world = synthetic_world(spec)
        if (world.action_dim, world.observation_dim) != (h.action_dim, h.observation_dim):
            raise _dims_error(
                "world", f"{spec.world}", world.action_dim, world.observation_dim, model
            )
        missing = [t for t in targets if t not in world.object_names]
        if missing:
            raise BadInputError(
                f"targets: {missing} are not objects of the {spec.world} world "
                f"{list(world.object_names)}.",
                field="targets",
            )
    elif spec.world == "rig":
        objects = table_objects(spec.table)
        _check_rig_channels(objects, model)
        missing = [t for t in targets if t not in objects]
        if missing:
            raise BadInputError(
                f"targets: {missing} are not on the simulated table "
                f"{table_name(spec.table or 'default')!r} ({list(objects)}).",
                field="targets",
            )
    elif spec.world == "replay":
        _check_replay(spec, model, replay)


def _check_rig_channels(objects: tuple[str, ...], model: ManifoldModel) -> None:
    """The simulated table's sensor must make the model's y: as many frame channels as dy
    (channel means), or the raw channels the model's feature pipeline reads."""
    from app.documents.raw_touches import raw_channel_names
    from hardware.sim.rig import table_channel_names

    h = model.hyperparameters
    frames = table_channel_names(objects)
    # The rig's actions: the DMP components, and the press depth if the model was trained with it.
    dx = rig_action_dim(h.action_dim)
    if model.features is None:
        if (h.action_dim, h.observation_dim) != (dx, len(frames)):
            raise _dims_error("world", "the simulated rig", dx, len(frames), model)
        return
    if h.action_dim != dx:
        raise _dims_error("world", "the simulated rig", dx, h.observation_dim, model)
    needed = [p.name for p in model.features.channels]
    made = raw_channel_names(frames)
    if sorted(needed) != sorted(made):
        raise BadInputError(
            f"world: the simulated rig's sensor gives the channels {list(made)}, the model's "
            f"features read {needed}.",
            field="world",
        )


def _check_replay(spec: EvaluationSpec, model: ManifoldModel, replay: TrainingData | None) -> None:
    if replay is None:
        raise BadInputError("data: the replay world needs held-out touches.", field="data")
    h = model.hyperparameters
    if (replay.action_dim, replay.observation_dim) != (h.action_dim, h.observation_dim):
        raise _dims_error(
            "data", "the held-out data", replay.action_dim, replay.observation_dim, model
        )
    foreign = [n for n in replay.object_names if n not in model.object_names]
    if foreign:
        raise BadInputError(
            f"data: objects {foreign} of the held-out data are not objects of the model "
            f"{list(model.object_names)}.",
            field="data",
        )
    missing = [t for t in spec.target_names(model) if t not in replay.object_names]
    if missing:
        raise BadInputError(
            f"data: the held-out data has no touches of {missing} (it has "
            f"{list(replay.object_names)}); choose targets among them.",
            field="data",
        )
