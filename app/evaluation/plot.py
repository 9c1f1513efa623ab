"""The figure of an evaluation: accuracy by touch with 95 % Wilson bands, per-object bars, and the
reliability diagram of each policy's answers (stated probability against observed accuracy)."""

from __future__ import annotations

from pathlib import Path
from typing import Any


def draw_reliability(axes: Any, policies: dict[str, dict[str, Any]]) -> None:
    """The reliability diagram of each policy's answers over every (trial, touch) on ``axes``.

    Per non-empty bin of stated probability: the answers' mean probability against the share
    of them that were right, a marker whose area grows with the count, the count written beside
    it; the diagonal is a perfectly calibrated recogniser. The legend gives each policy's ECE and
    "sure and wrong". Policies without calibration (``/1`` summaries) are left out.
    """
    axes.plot([0, 1], [0, 1], color="grey", linestyle="--", linewidth=1, label="calibrated")
    for name, summary in policies.items():
        calibration = summary.get("calibration")
        if not calibration:
            continue
        scored = calibration["all_touches"]
        used = [b for b in scored["reliability"] if b["count"]]
        stated = [b["mean_confidence"] for b in used]
        observed = [b["accuracy"] for b in used]
        counts = [b["count"] for b in used]
        sure = scored["sure_and_wrong"]
        ece = "—" if scored["ece"] is None else f"{scored['ece']:.3f}"
        (line,) = axes.plot(
            stated,
            observed,
            marker="o",
            label=f"{name}: ECE {ece}, sure and wrong {sure['wrong']} of {sure['sure']}",
        )
        total = max(sum(counts), 1)
        axes.scatter(
            stated, observed, s=[20 + 400 * c / total for c in counts], color=line.get_color()
        )
        for x, y, count in zip(stated, observed, counts, strict=True):
            axes.annotate(
                str(count), (x, y), textcoords="offset points", xytext=(4, -10), fontsize=7
            )
    axes.set_xlim(0, 1)
    axes.set_ylim(0, 1.02)
    axes.set_xlabel("stated probability of the answer")
    axes.set_ylabel("observed accuracy")
    axes.set_title("reliability (every trial and touch; numbers: answers)")
    axes.grid(alpha=0.3)
    axes.legend(fontsize=7, loc="upper left")


def plot_report(document: dict[str, Any], path: Path) -> None:
    """Write the figure of an ``activetouch-evaluation`` document (``/1`` or ``/2``) to ``path``
    (PNG, …).

    Left: accuracy after touch 1..T of each policy, its 95 % Wilson interval as a band. Middle:
    final accuracy of each target object, one bar per policy. Right (``/2``, which has each
    policy's calibration): the reliability diagram (:func:`draw_reliability`).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    policies: dict[str, dict[str, Any]] = document["policies"]
    steps = int(document["steps"])
    touches = list(range(1, steps + 1))
    calibrated = any(s.get("calibration") for s in policies.values())
    figure, panels = plt.subplots(
        1,
        3 if calibrated else 2,
        figsize=(16.5 if calibrated else 11, 4.2),
        constrained_layout=True,
    )
    curves, bars = panels[0], panels[1]
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
    if calibrated:
        draw_reliability(panels[2], policies)
    figure.savefig(path, dpi=120)
    plt.close(figure)
