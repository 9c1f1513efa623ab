"""One recognition trial on the simulated rig: the one place that seats the trial's object.

Used by the evaluation engine (:class:`app.evaluation.context.TrialContext`, world ``rig``) and
by ``bench/sim_tables.py``. Every trial gets a fresh in-process rig (virtual time) seeded from
the trial's own seed (:func:`rig_seed`), so a trial can be re-run alone. With placement
``"touch"`` the object is placed anew before every touch, as a collection does.
A touch the hardware refuses (:func:`is_refusal`) is raised as
:class:`~core.errors.TouchRefused`, which ends only that trial.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from app.documents.raw_touches import record_observation
from core.errors import TouchRefused
from core.evaluation import Touch, seed_sequence
from core.validation import FloatArray
from hardware.errors import (
    HardwareError,
    ServoCommandError,
    ServoHardwareError,
    ServoHardwareErrorFlags,
    UnsafeTrajectoryError,
)

if TYPE_CHECKING:
    from app.evaluation.spec import Placement
    from app.rig.actions import TouchActions
    from core.features.pipeline import FeaturePipeline
    from hardware.records import TouchRecord
    from hardware.sim.materials import TactileObject
    from hardware.sim.noise import NoiseModel


def rig_seed(seed: tuple[int, ...]) -> int:
    """The world seed of a trial's simulated rig, drawn from the trial's seed tuple
    (:func:`core.evaluation.records.trial_seed`)."""
    return int(seed_sequence(seed).generate_state(1)[0])


def is_refusal(error: HardwareError) -> bool:
    """Whether a hardware error refuses one touch (its action), not the rig as a whole.

    Refusals: a servo overload (:class:`~hardware.errors.ServoHardwareError` with ``OVERLOAD``),
    a command a servo refuses (:class:`~hardware.errors.ServoCommandError`), a trajectory
    refused before anything moved (:class:`~hardware.errors.UnsafeTrajectoryError`). Every
    other error (disconnection, timeout, a servo's voltage or encoder fault, a turntable
    alarm, an emergency stop, a busy rig) is not.
    """
    if isinstance(error, UnsafeTrajectoryError | ServoCommandError):
        return True
    return isinstance(error, ServoHardwareError) and bool(
        error.flags & ServoHardwareErrorFlags.OVERLOAD
    )


@dataclass
class RigTrial:
    """One trial's simulated rig: a fresh in-process rig seeded from the trial's seed.

    With placement ``"touch"`` the table turns to the next slot and back before every touch
    after the first, so each touch meets a fresh placement of the object (as in a collection).

    Attributes:
        actions: The action → trajectory map.
        objects: The table's objects (preset names or objects), slot 0 first.
        target: The name of the object touched (one of ``objects``).
        rig_seed: World seed of the simulated rig (:func:`rig_seed`).
        placement: How often the object is placed anew: once per trial (``"trial"``) or before
            every touch (``"touch"``), as :attr:`app.evaluation.spec.EvaluationSpec.placement`.
        noise: Noise model of the simulated world (``None``: the simulator's default).
        features: The model's feature pipeline, which makes y of each touch (``None``: the
            channel means).
    """

    actions: TouchActions
    objects: tuple[str | TactileObject, ...]
    target: str
    rig_seed: int
    placement: Placement = "trial"
    noise: NoiseModel | None = None
    features: FeaturePipeline | None = None

    def __post_init__(self) -> None:
        from app.rig.build import SimulationMode, open_rig

        self._handle = open_rig(
            simulate=SimulationMode.in_process,
            objects=self.objects,
            seed=self.rig_seed,
            noise=self.noise,
        )
        try:
            self._lease = self._handle.rig.acquire("evaluation")
            self._lease.connect()
        except BaseException:
            self._handle.close()
            raise
        names = [item if isinstance(item, str) else item.name for item in self.objects]
        self._target_slot = names.index(self.target)
        self._slot: int | None = self._target_slot
        self.touched = 0  # touches asked for so far (the refused one included)

    def touch(self, action: FloatArray, rng: np.random.Generator) -> Touch:
        """Touch the target with ``action`` (dx,) (a
        :class:`core.evaluation.trial_engine.TouchSource`). ``rng`` is unused: the simulation's own
        randomness makes the noise.

        Raises:
            TouchRefused: The hardware refused this touch (:func:`is_refusal`).
            HardwareError: Anything else (noted with the touch it happened in).
        """
        self.touched += 1
        try:
            record = self._touch(action)
        except HardwareError as exc:
            if is_refusal(exc):
                raise TouchRefused(type(exc).__name__, str(exc)) from exc
            exc.add_note(f"at touch {self.touched} of the trial")
            raise
        observation = record_observation(record, self.features)
        return Touch(action=action, observation=np.asarray(observation, dtype=np.float64))

    def _touch(self, action: FloatArray) -> TouchRecord:
        target = self._target_slot
        if self._slot is None and self.placement == "touch" and len(self.objects) > 1:
            self._lease.move_to_slot((target + 1) % len(self.objects))
            self._slot = target
        record = self.actions.touch(self._lease, action, slot=self._slot)
        self._slot = None  # the table stays at the target after the touch
        return record

    def close(self) -> None:
        """Release the lease and stop the simulation."""
        try:
            self._lease.release()
        finally:
            self._handle.close()
