// Unit tests of the dashboard's pure helpers: `node --test tests/` (run by the pytest suite).
import assert from "node:assert/strict";
import test from "node:test";

import {
  accuracyByTouches,
  answersByTouch,
  ellipsePoints,
  etaSeconds,
  formatDuration,
  normalizeTrajectory,
  rankedProbabilities,
  toCSV,
  trialRow,
} from "../js/lib/analysis.js";

function mahalanobis(p, mean, cov) {
  const det = cov[0][0] * cov[1][1] - cov[0][1] * cov[1][0];
  const inv = [
    [cov[1][1] / det, -cov[0][1] / det],
    [-cov[1][0] / det, cov[0][0] / det],
  ];
  const dx = p.x - mean[0];
  const dy = p.y - mean[1];
  return Math.sqrt(dx * (inv[0][0] * dx + inv[0][1] * dy) + dy * (inv[1][0] * dx + inv[1][1] * dy));
}

test("ellipse points lie on the n-sigma contour, closed", () => {
  for (const cov of [
    [[1, 0], [0, 1]],
    [[2, 0.9], [0.9, 0.5]],
    [[0.01, -0.004], [-0.004, 0.003]],
    [[0.3, 0], [0, 2]],
  ]) {
    const mean = [0.3, -1.2];
    const points = ellipsePoints(mean, cov, 2, 40);
    assert.equal(points.length, 41);
    assert.deepEqual(points[0], points[40]);
    for (const p of points) assert.ok(Math.abs(mahalanobis(p, mean, cov) - 2) < 1e-9);
  }
  assert.throws(() => ellipsePoints([0], [[1]]), /2D mean/);
});

test("ETA and durations", () => {
  assert.equal(etaSeconds(0, 10, 5), null);
  assert.equal(etaSeconds(5, 10, 5), 5);
  assert.equal(etaSeconds(10, 10, 5), 0);
  assert.equal(formatDuration(null), "—");
  assert.equal(formatDuration(0.42), "0.4 s");
  assert.equal(formatDuration(42), "42 s");
  assert.equal(formatDuration(185), "3 min 05 s");
  assert.equal(formatDuration(3720), "1 h 02 min");
});

const trial = (policy, target, answers, result, status = "completed") => ({
  policy,
  target,
  status,
  steps: answers.map((a, i) => ({ step: i + 1, nearest_object: a, probabilities: { [a]: 0.9 } })),
  result: result ? { object: result, correct: result === target } : null,
});

test("answers carry the final result forward", () => {
  assert.deepEqual(answersByTouch(trial("active", "A", ["B", "A"], "A"), 4), ["B", "A", "A", "A"]);
});

test("accuracy against touches, per policy, only finished trials with a target", () => {
  const trials = [
    trial("active", "A", ["A"], "A"),
    trial("active", "B", ["A", "B"], "B"),
    trial("passive", "A", ["B", "B", "A"], "A"),
    trial("passive", "A", ["B", "B", "B"], "B"),
    trial("passive", null, ["B"], "B"), // no target: ignored
    trial("active", "A", ["B"], null, "running"), // not finished: ignored
  ];
  const acc = accuracyByTouches(trials, 3);
  assert.deepEqual(acc.active.accuracy, [0.5, 1, 1]);
  assert.equal(acc.active.n, 2);
  assert.deepEqual(acc.passive.accuracy, [0, 0, 0.5]);
  assert.deepEqual(acc.passive.touches, [1, 2, 3]);
});

test("CSV quoting", () => {
  const csv = toCSV([{ a: 'x,"y"', b: 2 }, { a: null, b: { k: 1 } }], ["a", "b"]);
  assert.equal(csv, 'a,b\n"x,""y""",2\n,"{""k"":1}"\n');
});

test("trial rows", () => {
  const row = trialRow({ id: 3, model_id: 1, n_steps: 2, ...trial("active", "A", ["B", "A"], "A") });
  assert.equal(row.result, "A");
  assert.equal(row.correct, true);
  assert.equal(row.touches, 2);
  assert.equal(row.confidence, 0.9);
});

test("trajectories in either layout", () => {
  const rows = normalizeTrajectory({ angles_deg: [[0, 1], [2, 3], [4, 5]], timestep_s: 0.5 });
  assert.deepEqual(rows.times, [0, 0.5, 1]);
  assert.deepEqual(rows.joints.map((j) => j.name), ["FFJ3", "FFJ4"]);
  assert.deepEqual(rows.joints[1].angles, [1, 3, 5]);
  const named = normalizeTrajectory({ joints: { flex: [1, 2] }, times_s: [0, 0.1] });
  assert.deepEqual(named.times, [0, 0.1]);
  assert.equal(named.joints[0].name, "flex");
  const rig = normalizeTrajectory({ joint_names: ["FFJ3", "FFJ4"], dt_s: 0.01, commanded_deg: [[1, 2], [3, 4]] });
  assert.deepEqual(rig.times, [0, 0.01]);
  assert.deepEqual(rig.joints[0].angles, [1, 3]);
  assert.equal(normalizeTrajectory(null), null);
  assert.equal(normalizeTrajectory({ foo: 1 }), null);
});

test("ranked probabilities", () => {
  assert.deepEqual(rankedProbabilities({ a: 0.1, b: 0.7, c: 0.2 }).map((r) => r.name), ["b", "c", "a"]);
});

test("tactile traces in either layout", async () => {
  const { normalizeTrace } = await import("../js/lib/analysis.js");
  const named = normalizeTrace({ channels: { pressure: [1, 2, 3] }, sample_rate_hz: 10 });
  assert.deepEqual(named.times, [0, 0.1, 0.2]);
  assert.equal(named.channels[0].name, "pressure");
  const rows = normalizeTrace({ channel_names: ["a", "b"], samples: [[1, 2], [3, 4]], times_s: [0, 5] });
  assert.deepEqual(rows.channels[1].values, [2, 4]);
  assert.deepEqual(rows.times, [0, 5]);
  const rig = normalizeTrace({ channel_names: ["pdc"], tactile: [[5], [6]], tactile_times_s: [0, 0.01] });
  assert.deepEqual(rig.times, [0, 0.01]);
  assert.deepEqual(rig.channels[0].values, [5, 6]);
  assert.equal(normalizeTrace({ samples: [] }), null);
});
