// Trials: start one (model, target, policy, T, prior); follow it live: the belief on the manifold
// (mean path and ellipse), mutual information per touch, the posterior over objects, the joint
// trajectories, the steps; pause/resume/stop; the result. The 3D view (viser) is embedded.
// A trial opens by #trials?trial=ID; the result says why it stopped (the confidence rule, ...).
// A finished trial of an evaluation (#trials?evaluation=ID&trial=N) is shown read-only
// (evaluation_trial.js): its touches' actions, mutual information, answers and object
// probabilities; for a trial the rig refused, the refused touch and no answer.

import { api, apiList, apiOptional } from "../api.js";
import { lineChart, manifoldChart, posteriorChart } from "../charts.js";
import { formatDuration, isotropicCov, normalizeTrajectory, rankedProbabilities } from "../lib/analysis.js";
import { newestLoads } from "../lib/newest.js";
import * as store from "../store.js";
import { fact, renderEvaluationTrial } from "./evaluation_trial.js";
import { $, badge, el, fill, guarded, num, setOptions, throttle, toast, vec } from "../ui.js";
import { ACTIVE } from "../states.js";
import { bindRunControls, enableRunControls, runControls } from "../run_controls.js";

let trial = null; // GET /trials/{id}
let trialModel = null; // GET /models/{id} of that trial
let plannedTrajectory = null; // from a plan event, if the server sends one
let pollTimer = null;
let viserLoaded = false;
let evaluationTrial = null; // GET /evaluations/{id}/trials/{n}, shown read-only
let stepsHead = null; // the steps table's own header, restored after an evaluation trial
// A reload of the trial shown, fired by its late events, may answer after the page has moved on
// to another trial (e.g. "Run with passive"): only the newest load draws.
const beginLoad = newestLoads();

function worldFor(model) {
  if (model.action_dim === 1 && model.observation_dim === 3) return "exp1";
  return "rig";
}

async function refreshForm() {
  const models = (await store.models()).filter((m) => m.status === "ready");
  const select = $("trial-model");
  setOptions(
    select,
    models
      .sort((a, b) => b.id - a.id)
      .map((m) => ({ value: m.id, label: `#${m.id} — ${m.objects.length} objects, ds = ${m.latent_dim}` })),
  );
  $("page-trials").querySelector("[data-testid=start-trial]").disabled = !models.length;
  if (!models.length) {
    fill($("trial-target"), el("option", { value: "" }, "no ready model yet"));
    return;
  }
  await modelChosen();
}

async function modelChosen() {
  const id = $("trial-model").value;
  if (!id) return;
  const model = await store.model(id);
  const target = $("trial-target");
  const keep = target.value;
  setOptions(target, model.objects.map((o) => ({ value: o.name, label: o.name })), { placeholder: "unknown (no target)" });
  if (keep && model.objects.some((o) => o.name === keep)) target.value = keep;
  else if (model.objects.length) target.value = model.objects[Math.floor(Math.random() * model.objects.length)].name;
  // Experiment 1 models run against the paper's world; rig models (dx = 6, dy = 5) on the rig
  // (the simulated one in the demo).
  const world = worldFor(model);
  $("trial-world").value = world;
  $("trial-mode").value = world === "exp1" ? "simulated" : "rig";
  modeChanged();
  if (!trial && !evaluationTrial) drawManifold(model, null);
}

function modeChanged() {
  const simulated = $("trial-mode").value === "simulated";
  $("trial-world").disabled = !simulated;
  $("trial-interval").disabled = !simulated;
}

async function startTrial() {
  const modelId = Number($("trial-model").value);
  const model = await store.model(modelId);
  const body = {
    model_id: modelId,
    mode: $("trial-mode").value,
    policy: $("trial-policy").value,
    max_steps: Number($("trial-steps").value),
    tolerance: Number($("trial-tolerance").value),
    prior_cov: isotropicCov(model.latent_dim, Number($("trial-prior").value)),
  };
  if ($("trial-target").value) body.target = $("trial-target").value;
  // A seed is always recorded, so the same trial can be run again with the other policy.
  body.seed = $("trial-seed").value !== "" ? Number($("trial-seed").value) : Math.floor(Math.random() * 2 ** 31);
  if (body.mode === "simulated") {
    body.simulation = { world: $("trial-world").value, step_interval_s: Number($("trial-interval").value || 0) };
  }
  const created = await api("/trials", { method: "POST", body });
  plannedTrajectory = null;
  toast(`Trial #${created.id} started.`, "ok");
  await load(created.id);
}

/** The policy to compare a finished trial with: passive for a planned one, the default
 * (discriminative) for passive. */
/** Why a finished trial stopped, in words: the stop rule of its `reason`, else the reason. */
export function stopText(record) {
  if (record.reason === "confident") {
    return `stopped by the confidence rule (an object reached p ≥ ${record.confidence_threshold})`;
  }
  if (record.reason === "converged") return "stopped: the belief stopped moving";
  if (record.reason === "max_steps") return `all ${record.max_steps} touches made`;
  return record.reason || "";
}

export function otherPolicy(policy) {
  if (policy === "passive") return "discriminative";
  if (policy === "active" || policy === "discriminative") return "passive";
  return null;
}

/** The request that runs `record` again (same model, target, seed, settings) with `policy`. */
export function siblingTrial(record, policy) {
  const body = {
    model_id: record.model_id,
    mode: record.mode,
    policy,
    max_steps: record.max_steps,
    tolerance: record.tolerance,
    prior_mean: record.prior_mean,
    prior_cov: record.prior_cov,
  };
  if (record.confidence_threshold !== null && record.confidence_threshold !== undefined) body.confidence_threshold = record.confidence_threshold;
  if (record.action_bounds) body.action_bounds = record.action_bounds;
  if (record.target) body.target = record.target;
  if (record.seed !== null && record.seed !== undefined) body.seed = record.seed;
  const options = record.options || {};
  if (options.target_slot !== undefined) body.target_slot = options.target_slot;
  if (options.simulation) body.simulation = options.simulation;
  return body;
}

async function runOtherPolicy(policy) {
  const created = await api("/trials", { method: "POST", body: siblingTrial(trial, policy) });
  plannedTrajectory = null;
  toast(`Trial #${created.id} started: ${policy} on the same object and seed as #${trial.id}.`, "ok");
  await load(created.id);
}

function otherPolicyButton() {
  const policy = otherPolicy(trial.policy);
  if (!policy || !["simulated", "rig"].includes(trial.mode)) return null;
  const button = el(
    "button",
    { type: "button", class: "secondary", "data-testid": "trial-run-other", title: `A new trial: the same model, target, seed and settings, policy ${policy}` },
    `Run with ${policy}`,
  );
  button.addEventListener("click", () => guarded(() => runOtherPolicy(policy), button));
  return el("div", { class: "small" }, button);
}

export async function load(id) {
  const current = beginLoad();
  const record = await api(`/trials/${id}`);
  const model = !trialModel || trialModel.id !== record.model_id ? await store.model(record.model_id) : trialModel;
  if (!current()) return;
  showTrialHeader();
  if (!trial || trial.id !== record.id) plannedTrajectory = null;
  trial = record;
  trialModel = model;
  render();
  schedulePoll();
}

function schedulePoll() {
  clearTimeout(pollTimer);
  if (trial && ACTIVE.includes(trial.status)) {
    // A fallback beside the event stream: refetch while the trial runs.
    pollTimer = setTimeout(() => load(trial.id).catch(() => schedulePoll()), 1500);
  }
}

function beliefPath() {
  const path = [];
  if (trial.prior_mean) path.push(trial.prior_mean);
  for (const step of trial.steps) path.push(step.belief.mean);
  return path;
}

function drawManifold(model, currentTrial) {
  if (!model || model.status !== "ready") return;
  if (!currentTrial) {
    manifoldChart("chart-belief", model.objects);
    return;
  }
  const last = currentTrial.steps[currentTrial.steps.length - 1];
  const belief = last ? last.belief : { mean: currentTrial.prior_mean, cov: currentTrial.prior_cov };
  manifoldChart("chart-belief", model.objects, {
    belief,
    path: beliefPath(),
    nearest: last ? last.nearest_object : null,
  });
}

function render() {
  const steps = trial.steps || [];
  const last = steps[steps.length - 1] || null;
  const names = trialModel.objects.map((o) => o.name);
  $("trial-title").textContent = `Trial #${trial.id} — ${trial.policy}, ${trial.mode}${trial.target ? `, target ${trial.target}` : ""}`;
  $("trial-status").textContent = trial.status;
  $("trial-status").className = `badge ${trial.status}`;

  const started = trial.started_at ? new Date(trial.started_at).getTime() : null;
  const ended = trial.finished_at ? new Date(trial.finished_at).getTime() : Date.now();
  const ranked = last ? rankedProbabilities(last.probabilities) : [];
  fill(
    $("trial-facts"),
    fact("touches", `${steps.length} / ${trial.max_steps}`, "trial-touches"),
    fact("nearest object", last ? last.nearest_object : "—", "trial-nearest"),
    fact("p(nearest)", ranked.length ? num(ranked[0].p, 3) : "—"),
    fact("last MI (nats)", last ? num(last.mutual_information, 3) : "—"),
    fact("elapsed", started ? formatDuration((ended - started) / 1000) : "—"),
  );

  const result = $("trial-result");
  if (!ACTIVE.includes(trial.status)) {
    result.hidden = false;
    if (trial.result && trial.result.object) {
      const correct = trial.result.correct;
      result.className = `result ${correct === true ? "correct" : correct === false ? "wrong" : "unknown"}`;
      fill(
        result,
        "Recognised: ",
        el("strong", { "data-testid": "trial-result-object" }, trial.result.object),
        correct === true ? " ✓ correct" : correct === false ? ` ✗ wrong (target ${trial.target})` : "",
        el("div", { class: "small muted", "data-testid": "trial-stopped-by" }, `after ${steps.length} touch${steps.length === 1 ? "" : "es"} · ${trial.status}${trial.reason ? ` — ${stopText(trial)}` : ""}`),
        otherPolicyButton(),
      );
    } else {
      result.className = "result wrong";
      fill(result, `Trial ${trial.status}`, trial.reason ? `: ${trial.reason}` : "", " — no answer.");
    }
  } else {
    result.hidden = true;
  }

  enableRunControls(runControls("trial-controls"), trial.status);

  drawManifold(trialModel, trial);
  posteriorChart("chart-posterior", names, last ? last.probabilities : {}, last ? last.nearest_object : null);
  lineChart(
    "chart-mi",
    [{ label: "I(s; y | x) of the chosen action", x: steps.map((s) => s.step), y: steps.map((s) => s.mutual_information ?? null) }],
    { xTitle: "touch", yTitle: "mutual information (nats)", yMin: 0 },
  );

  const trajectory = normalizeTrajectory(plannedTrajectory) || normalizeTrajectory(last && last.trajectory);
  if (trajectory) {
    lineChart(
      "chart-plan",
      trajectory.joints.map((j) => ({ label: `${j.name} (deg)`, x: trajectory.times, y: j.angles })),
      { xTitle: "time (s)", yTitle: "joint angle (deg)" },
    );
    $("plan-note").textContent = plannedTrajectory ? "Next planned touch." : `Touch ${last.step}: the DMP trajectory sent to the finger.`;
  } else {
    $("plan-note").textContent = last ? `Action x of touch ${last.step}: ${vec(last.action)} (this world has no joint trajectories).` : "";
  }

  fill(
    $("steps-body"),
    [...steps].reverse().map((s) =>
      el(
        "tr",
        { "data-testid": "step-row" },
        el("td", {}, s.step),
        el("td", {}, vec(s.action)),
        el("td", {}, vec(s.observation)),
        el("td", {}, num(s.mutual_information, 3)),
        el("td", {}, vec(s.belief.mean)),
        el("td", {}, s.nearest_object),
        el("td", {}, num((s.probabilities || {})[s.nearest_object], 3)),
        el("td", {}, formatDuration(s.duration_s)),
      ),
    ),
  );
}

async function loadViser() {
  if (viserLoaded) return;
  viserLoaded = true;
  let info = null;
  try {
    info = await apiOptional("/viz");
  } catch {
    info = null;
  }
  const params = new URLSearchParams(location.search);
  let url = params.get("viser");
  // Off loopback the view is proxied by the app (`path`, behind the sign-in); else its port.
  if (!url && info && info.path) url = new URL(info.path, location.href).href;
  if (!url && info && info.port) url = `${location.protocol}//${location.hostname}:${info.port}/`;
  if (!url) return;
  $("viser-open").href = url;
  $("viser-open").hidden = false;
  const embed = () => {
    const frame = el("iframe", { src: url, title: "3D view of the manifold, belief and finger (viser)", "data-testid": "viser-frame" });
    fill($("viser-box"), frame);
  };
  // ?viz=off: a button instead (machines without a GPU render WebGL in software, slowly).
  if (params.get("viz") === "off") {
    fill($("viser-box"), el("button", { type: "button", class: "secondary", "data-testid": "viser-load", onclick: embed }, "Show the 3D view"));
  } else {
    embed();
  }
}

const reloadSoon = throttle(async () => {
  if (trial) await load(trial.id);
}, 250);

function showTrialHeader() {
  evaluationTrial = null;
  const head = $("steps-body").parentElement.tHead;
  if (stepsHead !== null) head.innerHTML = stepsHead;
}

/** Show finished trial `number` of evaluation `evaluationId` (read-only; a refused trial too). */
export async function loadEvaluationTrial(evaluationId, number) {
  const current = beginLoad();
  const record = await api(`/evaluations/${evaluationId}/trials/${number}`);
  const model = await store.model(record.model_id);
  if (!current()) return;
  clearTimeout(pollTimer);
  trial = null;
  evaluationTrial = record;
  const head = $("steps-body").parentElement.tHead;
  if (stepsHead === null) stepsHead = head.innerHTML;
  renderEvaluationTrial(record, model, evaluationId, number);
}

function hashParams() {
  return new URLSearchParams(location.hash.split("?")[1] || "");
}

export function init() {
  $("trial-form").addEventListener("submit", (e) => {
    e.preventDefault();
    guarded(startTrial, e.submitter);
  });
  $("trial-model").addEventListener("change", () => guarded(modelChosen));
  $("trial-mode").addEventListener("change", modeChanged);
  const controls = runControls("trial-controls");
  bindRunControls(controls, "/trials", () => trial, load);
  enableRunControls(controls, null);
  fill($("trial-facts"), el("p", { class: "muted" }, "Choose a model and a target, then start a trial: its touches, belief and answer appear here live."));
  modeChanged();
}

export async function show() {
  await refreshForm();
  loadViser();
  const params = hashParams();
  if (params.get("evaluation") && params.get("trial")) {
    await loadEvaluationTrial(Number(params.get("evaluation")), Number(params.get("trial")));
    return;
  }
  if (params.get("trial")) await load(Number(params.get("trial"))); // #trials?trial=ID
  else if (trial) await load(trial.id);
  else {
    const recent = await apiList("/trials?status=running", { max: 1, pageSize: 1 }).catch(() => []);
    if (recent.length) await load(recent[0].id);
  }
}

export function onEvent(event, kind) {
  if (kind === "model" && !$("page-trials").hidden) refreshForm();
  if (kind !== "trial") return;
  const data = event.data || {};
  const id = data.trial_id ?? data.id;
  if (trial && id === trial.id) {
    if (data.trajectory && /plan/.test(event.type)) plannedTrajectory = data.trajectory;
    reloadSoon();
  }
}
