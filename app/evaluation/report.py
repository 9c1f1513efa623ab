"""The result of an evaluation: its trials and their summary, as JSON and CSV.

Trials the rig refused (:class:`~core.evaluation.records.RefusedTrial`: one touch refused by the
hardware, e.g. a servo overload) are kept beside the completed ones and counted per policy
(``refused``); they are excluded from the accuracy, which is over the completed trials only
(``trials``, its denominator) — a refused trial counts neither as right nor as wrong — and so is
the calibration of the answers' probabilities. What the final accuracy would be with every refused
trial counted as wrong is given beside it (``accuracy_if_refused_wrong``), and a note says so
whenever a trial was refused.

Format ``activetouch-evaluation/2`` adds each policy's ``calibration``
(:func:`core.evaluation.summary.calibration_summary`) to ``/1``; the rest is unchanged, so a
reader of ``/1`` documents reads ``/2`` ones, and a ``/1`` document is a ``/2`` one without
calibration (:data:`FORMATS`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from app.evaluation.spec import EvaluationSpec
from core.evaluation import REFUSED, RefusedTrial, TrialRecord, comparison_sentence, summarise
from hardware.sim.materials import table_name

FORMAT = "activetouch-evaluation/2"

#: Every format of the evaluation document that is still read (``/1``: without calibration).
FORMATS: tuple[str, ...] = ("activetouch-evaluation/1", FORMAT)


@dataclass(frozen=True)
class EvaluationReport:
    """Trials of an evaluation and their summary.

    Attributes:
        spec: What was asked.
        records: Every completed trial, sorted by (policy, target, trial).
        seconds: Wall time of the run.
        workers: Processes that ran trials (1 in process; the cluster's workers otherwise).
        stopped: Whether the run was stopped before every trial finished.
        object_names: The model's objects (the order of the records' probabilities).
        steps: T actually run (``spec.steps``, or fewer when a replay pool caps it).
        refused: Every trial that ended because the rig refused a touch, sorted likewise.
    """

    spec: EvaluationSpec
    records: tuple[TrialRecord, ...]
    seconds: float
    workers: int
    stopped: bool
    object_names: tuple[str, ...] = field(default_factory=tuple)
    steps: int = 0
    refused: tuple[RefusedTrial, ...] = ()

    def __post_init__(self) -> None:
        ordered = tuple(sorted(self.records, key=lambda r: r.key))
        object.__setattr__(self, "records", ordered)
        object.__setattr__(self, "refused", tuple(sorted(self.refused, key=lambda r: r.key)))
        if self.steps == 0:
            object.__setattr__(self, "steps", self.spec.steps)

    @property
    def notes(self) -> list[str]:
        """What a reader must know: a capped T, a stopped run."""
        notes = []
        if self.steps < self.spec.steps:
            notes.append(
                f"T capped at {self.steps} (asked {self.spec.steps}): the smallest pool of "
                f"recorded touches of a target has {self.steps}."
            )
        if self.spec.world == "replay" and self.spec.trials_per_target > 1:
            from core.recognition import policy_entry

            fixed = [p for p in self.spec.policies if policy_entry(p).replay_score is not None]
            if fixed:
                notes.append(
                    f"replay: {', '.join(fixed)} choose(s) the recorded touch deterministically, "
                    "so their trials of one target repeat each other (unless a trial stops "
                    "early); their intervals count trials, not independent draws."
                )
        if self.stopped:
            notes.append("stopped before every trial finished; the summary covers those that did.")
        notes.extend(self._refusal_notes())
        return notes

    def refused_by_policy(self) -> dict[str, int]:
        """Refused trials per policy (every policy of the spec, 0 when none was refused)."""
        counts = dict.fromkeys(self.spec.policies, 0)
        for record in self.refused:
            counts[record.policy] = counts.get(record.policy, 0) + 1
        return counts

    def _refusal_notes(self) -> list[str]:
        if not self.refused:
            return []
        notes = []
        completed = {p: 0 for p in self.refused_by_policy()}
        right = dict(completed)
        for record in self.records:
            completed[record.policy] = completed.get(record.policy, 0) + 1
            right[record.policy] = right.get(record.policy, 0) + int(record.correct)
        for policy, refused in self.refused_by_policy().items():
            if refused == 0:
                continue
            done = completed.get(policy, 0)
            asked = done + refused
            notes.append(
                f"{policy}: the rig refused a touch in {refused} of {asked} trials; its accuracy "
                f"and calibration are over the {done} completed trials only (a refused trial "
                f"counts neither as "
                f"right nor as wrong); counted as wrong, its final accuracy would be "
                f"{right.get(policy, 0)}/{asked} = {100 * right.get(policy, 0) / asked:.1f} %."
            )
        notes.append(f"first refusal: {self.refused[0].describe()}")
        return notes

    def summary(self) -> dict[str, dict[str, Any]]:
        """:func:`core.evaluation.summary.summarise` of the completed trials, per policy, with
        ``refused`` (trials refused by the rig, not in ``trials``) and
        ``accuracy_if_refused_wrong`` (final accuracy over ``trials + refused``) added.

        Empty when no trial completed; a policy whose every trial was refused has no entry here
        (see :meth:`refused_by_policy`).
        """
        if not self.records:
            return {}
        summary = summarise(self.records, self.object_names, self.steps, self.spec.confidence)
        refused = self.refused_by_policy()
        for policy, entry in summary.items():
            count = refused.get(policy, 0)
            right = sum(r.correct for r in self.records if r.policy == policy)
            entry["refused"] = count
            entry["accuracy_if_refused_wrong"] = right / (entry["trials"] + count)
        return summary

    def comparison(self) -> str:
        """ "active reaches 95 % accuracy after k touches, passive after m"."""
        summary = self.summary()
        return comparison_sentence(summary, self.spec.confidence) if summary else ""

    def to_dict(self, include_trials: bool = True) -> dict[str, Any]:
        """The ``activetouch-evaluation/2`` document."""
        spec = self.spec
        return {
            "format": FORMAT,
            "world": spec.world,
            "steps": self.steps,
            "steps_requested": spec.steps,
            "trials_per_target": spec.trials_per_target,
            "seed": spec.seed,
            "workers": self.workers,
            "seconds": self.seconds,
            "confidence": spec.confidence,
            "stop_at_confidence": spec.stop_at_confidence,
            "objects": list(self.object_names),
            "targets": list(spec.targets) if spec.targets is not None else None,
            "table": None if spec.table is None else table_name(spec.table),
            "stopped": self.stopped,
            "notes": self.notes,
            "comparison": self.comparison(),
            "policies": self.summary(),
            "refused_trials": len(self.refused),
            "refused_by_policy": self.refused_by_policy(),
            "trials": [r.to_dict() for r in self.records] if include_trials else [],
            "refused": [r.to_dict() for r in self.refused] if include_trials else [],
        }

    def csv_rows(self) -> list[list[str | int | float | bool]]:
        """One row per trial and touch, header first.

        Columns: policy, target, trial, touch, answer, answer_probability, target_probability,
        correct (of this touch's answer), mutual_information, action_1..action_dx,
        stop_reason (on the trial's last touch, else empty). A refused trial has its touches
        before the refusal, then a row of the refused touch: its action, empty answer and
        probabilities, and stop_reason ``refused: <error>: <device message>``.
        """
        dx = (
            len(self.records[0].actions[0])
            if self.records
            else len(self.refused[0].action)
            if self.refused
            else 0
        )
        header: list[str | int | float | bool] = [
            "policy",
            "target",
            "trial",
            "touch",
            "answer",
            "answer_probability",
            "target_probability",
            "correct",
            "mutual_information",
            *[f"action_{i + 1}" for i in range(dx)],
            "stop_reason",
        ]
        rows = [header]
        names = self.object_names
        trials: list[TrialRecord | RefusedTrial] = [*self.records, *self.refused]
        for record in sorted(trials, key=lambda r: r.key):
            for touch in range(record.touches):
                answer = record.answers[touch]
                probabilities = record.probabilities[touch]
                rows.append(
                    [
                        record.policy,
                        record.target,
                        record.trial,
                        touch + 1,
                        answer,
                        probabilities[names.index(answer)],
                        probabilities[names.index(record.target)],
                        answer == record.target,
                        record.mutual_information[touch],
                        *record.actions[touch],
                        (record.stop_reason or "")
                        if isinstance(record, TrialRecord) and touch + 1 == record.touches
                        else "",
                    ]
                )
            if isinstance(record, RefusedTrial):
                rows.append(
                    [
                        record.policy,
                        record.target,
                        record.trial,
                        record.touch,
                        "",
                        "",
                        "",
                        False,
                        "",
                        *record.action,
                        f"{REFUSED}: {record.error}: {record.reason}",
                    ]
                )
        return rows
