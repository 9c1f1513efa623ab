// Unit tests of the Models page's model descriptions: `node --test tests/` (run by the pytest suite).
import assert from "node:assert/strict";
import test from "node:test";

import { num } from "../js/lib/format.js";
import { kernelsText, placementText } from "../js/lib/model_text.js";

test("num keeps significant digits and marks missing values", () => {
  assert.equal(num(0.123456, 2), "0.12");
  assert.equal(num(123456, 3), "1.23e+5");
  assert.equal(num(null), "—");
  assert.equal(num(Number.NaN), "—");
});

test("a placement effect in the fit's likelihood says so", () => {
  const text = placementText({
    status: "ready",
    placement_effect: { noise_ratio: [0.36, 0.954], variance: [0.3, 9.7], in_training_covariance: true },
  });
  assert.equal(text, "σ_b²/σ_n² = 0.36, 0.95 — in the fit's likelihood and in scoring trials");
});

test("a placement effect for scoring only says so", () => {
  const text = placementText({
    status: "ready",
    placement_effect: { noise_ratio: [0.5], variance: [0.4], in_training_covariance: false },
  });
  assert.match(text, /^σ_b²\/σ_n² = 0\.5 — in scoring trials only/);
});

test("no placement effect: independent touches once fitted, a dash before", () => {
  assert.match(placementText({ status: "ready", placement_effect: null }), /^none/);
  assert.equal(placementText({ status: "fitting", placement_effect: null }), "—");
});

test("kernels: tied, per feature, or not yet fitted", () => {
  assert.equal(kernelsText({ status: "ready", diagnostics: { kernels: "tied" } }), "tied: the features share their length-scales");
  assert.equal(kernelsText({ status: "ready", diagnostics: { kernels: "per_feature" } }), "one per feature");
  assert.equal(kernelsText({ status: "ready", diagnostics: null }), "one per feature");
  assert.equal(kernelsText({ status: "fitting", diagnostics: null }), "—");
});
