"""The result of an evaluation: its trials and their summary, as JSON and CSV."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from app.evaluation.spec import EvaluationSpec
from core.evaluation_records import TrialRecord
from core.evaluation_summary import comparison_sentence, summarise

FORMAT = "activetouch-evaluation/1"


@dataclass(frozen=True)
class EvaluationReport:
    """Trials of an evaluation and their summary.

    Attributes:
        spec: What was asked.
        records: Every finished trial, sorted by (policy, target, trial).
        seconds: Wall time of the run.
        workers: Processes that ran trials (1 in process; the cluster's workers otherwise).
        stopped: Whether the run was stopped before every trial finished.
        object_names: The model's objects (the order of the records' probabilities).
        steps: T actually run (``spec.steps``, or fewer when a replay pool caps it).
    """

    spec: EvaluationSpec
    records: tuple[TrialRecord, ...]
    seconds: float
    workers: int
    stopped: bool
    object_names: tuple[str, ...] = field(default_factory=tuple)
    steps: int = 0

    def __post_init__(self) -> None:
        ordered = tuple(sorted(self.records, key=lambda r: r.key))
        object.__setattr__(self, "records", ordered)
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
        if self.stopped:
            notes.append("stopped before every trial finished; the summary covers those that did.")
        return notes

    def summary(self) -> dict[str, dict[str, Any]]:
        """:func:`core.evaluation_summary.summarise` of the records (empty when there are none)."""
        if not self.records:
            return {}
        return summarise(self.records, self.object_names, self.steps, self.spec.confidence)

    def comparison(self) -> str:
        """ "active reaches 95 % accuracy after k touches, passive after m"."""
        summary = self.summary()
        return comparison_sentence(summary, self.spec.confidence) if summary else ""

    def to_dict(self, include_trials: bool = True) -> dict[str, Any]:
        """The ``activetouch-evaluation/1`` document."""
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
            "objects": list(self.object_names),
            "targets": list(spec.targets) if spec.targets is not None else None,
            "table": spec.table,
            "stopped": self.stopped,
            "notes": self.notes,
            "comparison": self.comparison(),
            "policies": self.summary(),
            "trials": [r.to_dict() for r in self.records] if include_trials else [],
        }

    def csv_rows(self) -> list[list[str | int | float | bool]]:
        """One row per trial and touch, header first.

        Columns: policy, target, trial, touch, answer, answer_probability, target_probability,
        correct (of this touch's answer), mutual_information, action_1..action_dx,
        stop_reason (on the trial's last touch, else empty).
        """
        dx = len(self.records[0].actions[0]) if self.records else 0
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
        for record in self.records:
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
                        record.stop_reason if touch + 1 == record.touches else "",
                    ]
                )
        return rows
