"""One evaluation trial as a record, and the seed that reproduces it alone.

Every trial of an evaluation draws its randomness from one ``np.random.SeedSequence`` whose
entropy is the evaluation's seed and whose spawn key names the trial: (target, trial). The target
enters the key through a stable hash of its name (CRC-32), so a trial's stream does not depend on
which other targets were asked for, nor on the order the trials are run in, nor on which process
runs them. The policy is not part of the key: trial k of a target sees the same random streams under
every policy, so policies are compared on the same targets and seeds (docs/method.md, "Evaluation
protocols") and their difference is not blurred by different noise.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass
from typing import Any, Literal, get_args

import numpy as np

from core.errors import InvalidInputError


def name_key(name: str) -> int:
    """A stable non-negative integer for an object name (CRC-32 of its UTF-8)."""
    return zlib.crc32(name.encode("utf-8"))


def trial_seed(seed: int, target: str, trial: int) -> tuple[int, ...]:
    """The seed tuple of one trial: (evaluation seed, target key, trial index).

    Raises:
        InvalidInputError: A negative seed or trial index.
    """
    if seed < 0 or trial < 0:
        raise InvalidInputError(f"seed and trial: must be ≥ 0, received {seed} and {trial}.")
    return (int(seed), name_key(target), int(trial))


def seed_sequence(seed: tuple[int, ...]) -> np.random.SeedSequence:
    """The ``SeedSequence`` of a trial's seed tuple (entropy first, then the spawn key)."""
    if len(seed) < 1:
        raise InvalidInputError("seed: expected (entropy, *spawn_key), received ().")
    return np.random.SeedSequence(entropy=seed[0], spawn_key=tuple(seed[1:]))


def trial_generators(seed: tuple[int, ...]) -> tuple[np.random.Generator, np.random.Generator]:
    """Two independent generators of a trial: (policy's, world's).

    The policy's stream draws passive actions and replay choices; the world's stream draws the
    observation noise. Keeping them apart means a policy's choices do not shift the noise.
    """
    policy, world = seed_sequence(seed).spawn(2)
    return np.random.default_rng(policy), np.random.default_rng(world)


#: Why a trial ended: its T-th touch (``"max_steps"``), the confidence rule (``"confident"``: the
#: object posterior's largest probability reached the threshold), the tolerance (``"converged"``:
#: the belief's mean moved less than it), or a touch the world refused (``"refused"``, only
#: :class:`RefusedTrial`).
StopReason = Literal["max_steps", "converged", "confident", "refused"]

#: Every :data:`StopReason`.
STOP_REASONS: tuple[StopReason, ...] = get_args(StopReason)

#: ``stop_reason`` of a refused trial (:class:`RefusedTrial`).
REFUSED: StopReason = "refused"


@dataclass(frozen=True)
class TrialRecord:
    """What one evaluation trial did, touch by touch.

    Attributes:
        policy: Name of the policy (``"active"``, ``"passive"``, …).
        target: Name of the object touched.
        trial: Index of this trial within its (policy, target) cell.
        seed: The seed tuple that reproduces the trial alone (:func:`trial_seed`).
        answers: The answer after each touch performed. Length ``touches``.
        probabilities: Object posterior after each touch, in the model's object order.
            ``touches`` tuples of length L.
        actions: The action of each touch. ``touches`` tuples of length dx.
        mutual_information: U1 of each action under the belief it was chosen for, in nats.
        touches: Touches performed (≤ T; fewer after an early stop).
        stop_reason: Why the trial ended (:data:`StopReason`, never ``"refused"``); ``None``
            when a document written without it is read.
        correct: Whether the final answer is the target.
        nearest: The object whose learned latent is nearest the Gaussian belief's mean after
            each touch (the paper's decision rule), when recorded; empty otherwise.
    """

    policy: str
    target: str
    trial: int
    seed: tuple[int, ...]
    answers: tuple[str, ...]
    probabilities: tuple[tuple[float, ...], ...]
    actions: tuple[tuple[float, ...], ...]
    mutual_information: tuple[float, ...]
    touches: int
    stop_reason: StopReason | None
    correct: bool
    nearest: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        n = self.touches
        lengths = {
            "answers": len(self.answers),
            "probabilities": len(self.probabilities),
            "actions": len(self.actions),
            "mutual_information": len(self.mutual_information),
        }
        if self.nearest:
            lengths["nearest"] = len(self.nearest)
        wrong = {name: length for name, length in lengths.items() if length != n}
        if n < 1 or wrong:
            raise InvalidInputError(
                f"TrialRecord: touches={n} must be ≥ 1 and equal the length of every per-touch "
                f"field; received lengths {lengths}."
            )
        if self.stop_reason is not None and (
            self.stop_reason not in STOP_REASONS or self.stop_reason == REFUSED
        ):
            completed = [r for r in STOP_REASONS if r != REFUSED]
            raise InvalidInputError(
                f"TrialRecord: stop_reason {self.stop_reason!r} is not one of {completed}."
            )

    @property
    def stopped_by_confidence(self) -> bool:
        """Whether the confidence rule ended the trial (before its T-th touch or at it)."""
        return self.stop_reason == "confident"

    @property
    def key(self) -> tuple[str, str, int]:
        """(policy, target, trial): the record's place in a report."""
        return (self.policy, self.target, self.trial)

    def answers_by_touch(self, steps: int) -> tuple[str, ...]:
        """The answer after touch 1..``steps``; after an early stop the last one carries forward.

        Raises:
            InvalidInputError: ``steps`` is smaller than the touches performed.
        """
        if steps < self.touches:
            raise InvalidInputError(
                f"steps: {steps} is fewer than the {self.touches} touches of this trial."
            )
        return self.answers + (self.answers[-1],) * (steps - self.touches)

    def nearest_by_touch(self, steps: int) -> tuple[str, ...]:
        """:attr:`nearest` after touch 1..``steps``, carried forward like the answers.

        Raises:
            InvalidInputError: ``steps`` is smaller than the touches, or nothing was recorded.
        """
        if not self.nearest:
            raise InvalidInputError("nearest: this record has no nearest-latent answers.")
        if steps < self.touches:
            raise InvalidInputError(
                f"steps: {steps} is fewer than the {self.touches} touches of this trial."
            )
        return self.nearest + (self.nearest[-1],) * (steps - self.touches)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready; :meth:`from_dict` gives back an equal record (floats round-trip)."""
        return {
            **_touch_fields_to_dict(self),
            "stop_reason": self.stop_reason,
            "correct": self.correct,
            "nearest": list(self.nearest),
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> TrialRecord:
        """The record of a :meth:`to_dict` document (one without ``stop_reason``, as older
        documents may be, reads with ``stop_reason=None``).

        Raises:
            InvalidInputError: A field is missing or of the wrong kind.
        """
        try:
            reason = d.get("stop_reason")
            return cls(
                **_touch_fields_from_dict(d, required=True),
                touches=int(d["touches"]),
                stop_reason=None if reason is None else _stop_reason(reason),
                correct=bool(d["correct"]),
                nearest=tuple(str(n) for n in d.get("nearest", ())),
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise InvalidInputError(f"trial record: missing or malformed field ({exc}).") from None


def _stop_reason(value: Any) -> StopReason:
    for reason in STOP_REASONS:
        if value == reason:
            return reason
    raise ValueError(f"stop_reason {value!r} is not one of {list(STOP_REASONS)}")


@dataclass(frozen=True)
class RefusedTrial:
    """An evaluation trial that ended because the world refused one touch (e.g. a servo overload).

    It is neither right nor wrong: an evaluation's accuracy counts only completed trials
    (:class:`TrialRecord`) and reports the refused ones beside them.

    Attributes:
        policy: Name of the policy.
        target: Name of the object touched.
        trial: Index of this trial within its (policy, target) cell.
        seed: The seed tuple that reproduces the trial alone (:func:`trial_seed`).
        touch: The refused touch, 1-based (``touch - 1`` touches were performed before it).
        action: The action refused, length dx.
        error: What refused it (the device error's class name, e.g. ``"ServoHardwareError"``).
        reason: The device's message.
        answers: The answer after each touch performed before the refusal. Length
            ``touch - 1``, as the three fields below.
        probabilities: Object posterior after each of those touches, in the model's order.
        actions: Their actions.
        mutual_information: U1 of each of their actions, in nats.
    """

    policy: str
    target: str
    trial: int
    seed: tuple[int, ...]
    touch: int
    action: tuple[float, ...]
    error: str
    reason: str
    answers: tuple[str, ...] = ()
    probabilities: tuple[tuple[float, ...], ...] = ()
    actions: tuple[tuple[float, ...], ...] = ()
    mutual_information: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        done = self.touch - 1
        lengths = {
            "answers": len(self.answers),
            "probabilities": len(self.probabilities),
            "actions": len(self.actions),
            "mutual_information": len(self.mutual_information),
        }
        wrong = {name: length for name, length in lengths.items() if length != done}
        if self.touch < 1 or wrong or not self.action:
            raise InvalidInputError(
                f"RefusedTrial: touch={self.touch} must be ≥ 1, the refused action non-empty, "
                f"and the touches before it (touch - 1 = {done}) the length of every per-touch "
                f"field; received lengths {lengths}, action of length {len(self.action)}."
            )

    @property
    def key(self) -> tuple[str, str, int]:
        """(policy, target, trial): the trial's place in a report."""
        return (self.policy, self.target, self.trial)

    @property
    def touches(self) -> int:
        """Touches performed before the refusal."""
        return self.touch - 1

    @property
    def correct(self) -> bool:
        """Always false: a refused trial is never counted as right."""
        return False

    @property
    def stop_reason(self) -> StopReason:
        """``"refused"``: the world refused a touch."""
        return REFUSED

    @property
    def stopped_by_confidence(self) -> bool:
        """Always false: the refusal ended the trial."""
        return False

    def describe(self) -> str:
        """ "touch 2 of active/paper_cup #0, action [0.10, …]: ServoHardwareError: …"."""
        action = ", ".join(f"{v:.3g}" for v in self.action)
        return (
            f"touch {self.touch} of {self.policy}/{self.target} #{self.trial}, action "
            f"[{action}]: {self.error}: {self.reason}"
        )

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready, with ``refused`` (touch, action, error, reason); ``correct`` is false and
        ``stop_reason`` ``"refused"``. :meth:`from_dict` gives back an equal record."""
        return {
            **_touch_fields_to_dict(self),
            "stop_reason": REFUSED,
            "correct": False,
            "refused": {
                "touch": self.touch,
                "action": list(self.action),
                "error": self.error,
                "reason": self.reason,
            },
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> RefusedTrial:
        """The record of a :meth:`to_dict` document.

        Raises:
            InvalidInputError: A field is missing or of the wrong kind.
        """
        try:
            refused = d["refused"]
            return cls(
                **_touch_fields_from_dict(d, required=False),
                touch=int(refused["touch"]),
                action=tuple(float(v) for v in refused["action"]),
                error=str(refused["error"]),
                reason=str(refused["reason"]),
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise InvalidInputError(
                f"refused trial record: missing or malformed field ({exc})."
            ) from None


#: What one trial ends as (the one outcome type of :mod:`core.evaluation.trial_engine`): completed,
#: with why it stopped, or refused by the world.
TrialOutcome = TrialRecord | RefusedTrial


def _touch_fields_to_dict(record: TrialOutcome) -> dict[str, Any]:
    """The fields both kinds of record share (who, which trial, and every touch performed)."""
    return {
        "policy": record.policy,
        "target": record.target,
        "trial": record.trial,
        "seed": list(record.seed),
        "answers": list(record.answers),
        "probabilities": [list(p) for p in record.probabilities],
        "actions": [list(a) for a in record.actions],
        "mutual_information": list(record.mutual_information),
        "touches": record.touches,
    }


def _touch_fields_from_dict(d: dict[str, Any], required: bool) -> dict[str, Any]:
    """Constructor arguments of the shared fields (not ``touches``, which only
    :class:`TrialRecord` stores). The per-touch lists may be absent when not ``required``
    (a trial refused at its first touch).

    Raises:
        KeyError, TypeError, ValueError: A field is missing or malformed (the callers turn
            these into :class:`~core.errors.InvalidInputError`).
    """

    def per_touch(name: str) -> Any:
        return d[name] if required else d.get(name, ())

    return {
        "policy": str(d["policy"]),
        "target": str(d["target"]),
        "trial": int(d["trial"]),
        "seed": tuple(int(v) for v in d["seed"]),
        "answers": tuple(str(a) for a in per_touch("answers")),
        "probabilities": tuple(tuple(float(v) for v in p) for p in per_touch("probabilities")),
        "actions": tuple(tuple(float(v) for v in a) for a in per_touch("actions")),
        "mutual_information": tuple(float(v) for v in per_touch("mutual_information")),
    }


def outcome_from_dict(d: dict[str, Any]) -> TrialOutcome:
    """A :class:`RefusedTrial` when the document has ``refused``, else a :class:`TrialRecord`.

    Raises:
        InvalidInputError: A field is missing or of the wrong kind.
    """
    if d.get("refused"):
        return RefusedTrial.from_dict(d)
    return TrialRecord.from_dict(d)
