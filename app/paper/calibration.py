"""How a paper experiment states one policy's calibration in its table."""

from __future__ import annotations

from typing import Any


def calibration_text(summary: dict[str, Any]) -> str:
    """ "ECE 0.031 (0.040 from sampling alone if calibrated), Brier 0.120, log-loss 0.41 nats;
    sure (p ≥ 0.95) and wrong: 3 of 120 (2.5 %)" over every (trial, touch) of a policy's
    summary (:func:`core.evaluation.summary.summarise`; the bracket when it has
    :func:`core.evaluation.calibration.ece_if_calibrated`)."""
    scored = summary["calibration"]["all_touches"]
    sure = scored["sure_and_wrong"]

    def value(key: str, digits: int) -> str:
        return "—" if scored[key] is None else f"{scored[key]:.{digits}f}"

    share = "" if sure["share_wrong"] is None else f" ({100 * sure['share_wrong']:.1f} %)"
    null = scored.get("ece_if_calibrated")
    sampling = "" if not null else f" ({null['mean']:.3f} from sampling alone if calibrated)"
    return (
        f"ECE {value('ece', 3)}{sampling}, Brier {value('brier', 3)}, "
        f"log-loss {value('log_loss', 2)} nats; sure (p ≥ {sure['threshold']:g}) and wrong: "
        f"{sure['wrong']:d} of {sure['sure']:d}{share}"
    )
