// How a model's fit is described on the Models page (pure: unit-tested with node).

import { num } from "./format.js";

// σ_b² / σ_n² per feature (how much of a touch's noise the touches of one placement share), and
// whether the fit has the shared offset in its own likelihood or uses it to score trials only.
export function placementText(model) {
  const effect = model.placement_effect;
  if (!effect) {
    return model.status === "ready" ? "none (no placements recorded: touches scored as independent)" : "—";
  }
  const ratios = `σ_b²/σ_n² = ${effect.noise_ratio.map((v) => num(v, 2)).join(", ")}`;
  return effect.in_training_covariance
    ? `${ratios} — in the fit's likelihood and in scoring trials`
    : `${ratios} — in scoring trials only (the fit took the touches as independent)`;
}

// Whether every feature has its own length-scales or the features share one set (tied kernels,
// one factorisation for all: docs/fitting.md "Tied kernels"). Older models record none: per feature.
export function kernelsText(model) {
  if (model.status !== "ready") return "—";
  return model.diagnostics?.kernels === "tied"
    ? "tied: the features share their length-scales"
    : "one per feature";
}
