// Pure helpers of the dashboard: no DOM, no network. Unit-tested with `node --test tests/`.

/**
 * Points on the n-sigma contour of a 2D Gaussian: {s : (s-m)ᵀ C⁻¹ (s-m) = nSigma²}.
 * @param {number[]} mean  [m1, m2]
 * @param {number[][]} cov [[c11, c12], [c21, c22]], symmetric positive semi-definite
 * @param {number} nSigma  Mahalanobis radius (> 0)
 * @param {number} n       number of points; the first point is repeated at the end (closed)
 * @returns {{x: number, y: number}[]} n + 1 points
 */
export function ellipsePoints(mean, cov, nSigma = 2, n = 64) {
  if (mean.length !== 2 || cov.length !== 2 || cov[0].length !== 2 || cov[1].length !== 2) {
    throw new Error(`ellipsePoints: expected a 2D mean and a 2×2 covariance`);
  }
  const a = cov[0][0];
  const b = 0.5 * (cov[0][1] + cov[1][0]);
  const d = cov[1][1];
  // Eigen-decomposition of [[a, b], [b, d]] in closed form.
  const half = 0.5 * (a + d);
  const root = Math.sqrt(Math.max(0, 0.25 * (a - d) ** 2 + b * b));
  const l1 = Math.max(0, half + root);
  const l2 = Math.max(0, half - root);
  let v1;
  if (Math.abs(b) > 1e-15) v1 = [l1 - d, b];
  else v1 = a >= d ? [1, 0] : [0, 1];
  const norm = Math.hypot(v1[0], v1[1]);
  v1 = [v1[0] / norm, v1[1] / norm];
  const v2 = [-v1[1], v1[0]];
  const r1 = nSigma * Math.sqrt(l1);
  const r2 = nSigma * Math.sqrt(l2);
  const out = [];
  for (let i = 0; i <= n; i += 1) {
    const t = (2 * Math.PI * (i % n)) / n;
    const c = Math.cos(t) * r1;
    const s = Math.sin(t) * r2;
    out.push({ x: mean[0] + c * v1[0] + s * v2[0], y: mean[1] + c * v1[1] + s * v2[1] });
  }
  return out;
}

/** Seconds left at a constant rate: null until there is a rate to go by. */
export function etaSeconds(done, total, elapsedSeconds) {
  if (!(done > 0) || !(total > 0) || !(elapsedSeconds > 0)) return null;
  if (done >= total) return 0;
  return ((total - done) * elapsedSeconds) / done;
}

/** "1 h 02 min", "3 min 05 s", "12 s", "0.4 s"; "—" for null. */
export function formatDuration(seconds) {
  if (seconds === null || seconds === undefined || !Number.isFinite(seconds)) return "—";
  if (seconds < 10) return `${seconds.toFixed(1)} s`;
  const s = Math.round(seconds);
  if (s < 60) return `${s} s`;
  if (s < 3600) return `${Math.floor(s / 60)} min ${String(s % 60).padStart(2, "0")} s`;
  return `${Math.floor(s / 3600)} h ${String(Math.floor((s % 3600) / 60)).padStart(2, "0")} min`;
}

/**
 * The object named after each touch count t = 1..maxTouches: the nearest object after step t,
 * or, once the trial has stopped, its final answer (a stopped trial keeps its answer).
 * @param {{steps: {step: number, nearest_object: string}[], result?: {object: string}|null}} trial
 */
export function answersByTouch(trial, maxTouches) {
  const steps = [...(trial.steps || [])].sort((p, q) => p.step - q.step);
  const answers = [];
  let last = null;
  for (let t = 1; t <= maxTouches; t += 1) {
    if (t <= steps.length) last = steps[t - 1].nearest_object;
    else if (trial.result && trial.result.object) last = trial.result.object;
    answers.push(last);
  }
  return answers;
}

/**
 * Recognition accuracy against the number of touches, per policy.
 * Only finished trials with a known target and at least one step count.
 * @returns {Record<string, {touches: number[], accuracy: number[], n: number}>}
 */
export function accuracyByTouches(trials, maxTouches) {
  const groups = {};
  for (const trial of trials) {
    if (!trial.target || !(trial.steps && trial.steps.length)) continue;
    if (!["completed", "stopped"].includes(trial.status)) continue;
    const key = trial.policy;
    groups[key] = groups[key] || [];
    groups[key].push(answersByTouch(trial, maxTouches).map((a) => (a === trial.target ? 1 : 0)));
  }
  const out = {};
  for (const [policy, rows] of Object.entries(groups)) {
    const touches = [];
    const accuracy = [];
    for (let t = 0; t < maxTouches; t += 1) {
      touches.push(t + 1);
      accuracy.push(rows.reduce((sum, r) => sum + r[t], 0) / rows.length);
    }
    out[policy] = { touches, accuracy, n: rows.length };
  }
  return out;
}

/** One CSV field, quoted when needed (RFC 4180). */
function csvField(value) {
  if (value === null || value === undefined) return "";
  const text = typeof value === "object" ? JSON.stringify(value) : String(value);
  return /[",\n\r]/.test(text) ? `"${text.replace(/"/g, '""')}"` : text;
}

/** Rows of objects as CSV with the given columns (header first, \n line ends). */
export function toCSV(rows, columns) {
  const lines = [columns.map(csvField).join(",")];
  for (const row of rows) lines.push(columns.map((c) => csvField(row[c])).join(","));
  return `${lines.join("\n")}\n`;
}

/** The flat row of a trial used in the History table and its CSV export. */
export function trialRow(trial) {
  const result = trial.result || {};
  const last = trial.steps && trial.steps.length ? trial.steps[trial.steps.length - 1] : null;
  return {
    id: trial.id,
    model_id: trial.model_id,
    mode: trial.mode,
    policy: trial.policy,
    status: trial.status,
    target: trial.target ?? "",
    result: result.object ?? "",
    correct: result.correct === undefined || result.correct === null ? "" : result.correct,
    touches: trial.n_steps ?? (trial.steps ? trial.steps.length : 0),
    confidence: last && result.object ? (last.probabilities || {})[result.object] ?? "" : "",
    created_at: trial.created_at,
    finished_at: trial.finished_at ?? "",
    reason: trial.reason ?? "",
  };
}

/**
 * Joint trajectories of a step or plan in one shape, whatever the producer wrote:
 * `{commanded_deg | angles_deg: [[j1, j2], ...] (T, J), dt_s | timestep_s | times_s, joint_names?}`, or
 * `{joints: {name: [deg, ...]}, timestep_s | times_s}` or `{positions_deg: ...}`.
 * @returns {{times: number[], joints: {name: string, angles: number[]}[]} | null}
 */
export function normalizeTrajectory(trajectory) {
  if (!trajectory || typeof trajectory !== "object") return null;
  const series = namedSeries(
    trajectory.joints,
    trajectory.commanded_deg || trajectory.angles_deg || trajectory.positions_deg || trajectory.joint_angles_deg,
    trajectory.joint_names,
    (j) => ["FFJ3", "FFJ4"][j] || `J${j + 1}`,
  );
  if (!series || !series.length) return null;
  const joints = series.map(({ name, values }) => ({ name, angles: values }));
  const dt = Number(trajectory.timestep_s ?? trajectory.dt_s ?? 1);
  return { times: sampleTimes(trajectory.times_s, joints[0].angles.length, dt), joints };
}

/** Prior covariance v·I of dimension ds, as nested lists. */
export function isotropicCov(ds, variance) {
  return Array.from({ length: ds }, (_, i) => Array.from({ length: ds }, (_, j) => (i === j ? variance : 0)));
}

/** Posterior probabilities as [{name, p}] sorted by decreasing p. */
export function rankedProbabilities(probabilities) {
  return Object.entries(probabilities || {})
    .map(([name, p]) => ({ name, p }))
    .sort((a, b) => b.p - a.p);
}

/**
 * A touch's raw tactile time series in one shape, whatever the producer wrote:
 * `{channels: {name: [..]}, times_s | timestep_s | sample_rate_hz}` or
 * `{channel_names: [..], tactile | samples: [[c1, c2, ..], ..] (T, C), tactile_times_s?, ...}`.
 * @returns {{times: number[], channels: {name: string, values: number[]}[]} | null}
 */
export function normalizeTrace(raw) {
  if (!raw || typeof raw !== "object") return null;
  const series = namedSeries(
    raw.channels,
    raw.tactile || raw.samples || raw.frames || raw.values,
    raw.channel_names || raw.names,
    (c) => `ch${c + 1}`,
  );
  const channels = (series || []).filter((c) => Array.isArray(c.values) && c.values.length);
  if (!channels.length) return null;
  const dt = raw.timestep_s ?? (raw.sample_rate_hz ? 1 / raw.sample_rate_hz : 1);
  return { times: sampleTimes(raw.tactile_times_s || raw.times_s, channels[0].values.length, dt), channels };
}

/**
 * Series by name, from `{name: [..]}` (`byName`) or from the columns of rows (T, C) (`rows`), column c
 * named `names[c]` or `fallbackName(c)`: what a trajectory's joints and a trace's channels share.
 * @returns {{name: string, values: number[]}[] | null} null when neither layout is there.
 */
function namedSeries(byName, rows, names, fallbackName) {
  if (byName && typeof byName === "object" && !Array.isArray(byName)) {
    return Object.entries(byName).map(([name, values]) => ({ name, values }));
  }
  if (!Array.isArray(rows) || !rows.length || !Array.isArray(rows[0])) return null;
  const labels = names || rows[0].map((_, c) => fallbackName(c));
  return rows[0].map((_, c) => ({ name: labels[c], values: rows.map((r) => r[c]) }));
}

/** `times` when it has one entry per sample, else 0, dt, 2·dt, … for `length` samples. */
function sampleTimes(times, length, dt) {
  if (Array.isArray(times) && times.length === length) return times;
  return Array.from({ length }, (_, i) => i * dt);
}
