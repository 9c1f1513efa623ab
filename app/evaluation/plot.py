"""The figure of an evaluation: accuracy by touch with 95 % Wilson bands, and per-object bars."""

from __future__ import annotations

from pathlib import Path
from typing import Any


def plot_report(document: dict[str, Any], path: Path) -> None:
    """Write the figure of an ``activetouch-evaluation/1`` document to ``path`` (PNG, …).

    Left: accuracy after touch 1..T of each policy, its 95 % Wilson interval as a band. Right:
    final accuracy of each target object, one bar per policy.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    policies: dict[str, dict[str, Any]] = document["policies"]
    steps = int(document["steps"])
    touches = list(range(1, steps + 1))
    figure, (curves, bars) = plt.subplots(1, 2, figsize=(11, 4.2), constrained_layout=True)
    for name, summary in policies.items():
        accuracy = [100 * a for a in summary["accuracy_by_touch"]]
        lower = [100 * lo for lo, _ in summary["accuracy_interval"]]
        upper = [100 * hi for _, hi in summary["accuracy_interval"]]
        (line,) = curves.plot(touches, accuracy, marker="o", label=name)
        curves.fill_between(touches, lower, upper, color=line.get_color(), alpha=0.2)
    curves.set_xlabel("touch")
    curves.set_ylabel("accuracy (%)")
    curves.set_ylim(0, 101)
    curves.set_xticks(touches)
    curves.set_title(
        f"{document['world']}: accuracy by touch (95 % Wilson), "
        f"{document['trials_per_target']} trials per target"
    )
    curves.grid(alpha=0.3)
    curves.legend()
    objects = sorted({o for s in policies.values() for o in s["per_object"]})
    width = 0.8 / max(len(policies), 1)
    for index, (name, summary) in enumerate(policies.items()):
        heights = [
            100 * summary["per_object"].get(o, {"accuracy": 0.0})["accuracy"] for o in objects
        ]
        positions = [k + (index - (len(policies) - 1) / 2) * width for k in range(len(objects))]
        bars.bar(positions, heights, width=width, label=name)
    bars.set_xticks(range(len(objects)))
    bars.set_xticklabels(objects, rotation=30, ha="right")
    bars.set_ylabel(f"accuracy after touch {steps} (%)")
    bars.set_ylim(0, 101)
    bars.set_title("per object")
    bars.legend()
    figure.savefig(path, dpi=120)
    plt.close(figure)
