// Evaluation: start one (model, world, policies, trials, T, replay dataset); watch it fill in
// from the event stream; accuracy after each touch with its 95 % interval band per policy, final
// accuracy per object, the reliability diagram and the calibration measures (ECE, Brier, log-loss,
// sure and wrong) of each policy, the confusion matrix; a finished trial opens in the Trials view.
// Trials the rig refused a touch of are counted apart (the accuracy and the calibration are over
// the completed ones) and listed.

import { api, apiList } from "../api.js";
import { bottomLegend, colorOf, compactNumber, renderChart, scatterPlugins } from "../charts.js";
import * as store from "../store.js";
import { $, badge, el, fill, guarded, num, setOptions, throttle, toast } from "../ui.js";
import { ACTIVE } from "../states.js";
import { newestLoads } from "../lib/newest.js";

const SHOWN_TRIALS = 500; // finished trials listed (the newest)
const POLICY_COLORS = { active: "#1f5fbf", discriminative: "#2e9e5b", passive: "#d9822b" };
let evaluation = null; // GET /evaluations/{id}
const beginLoad = newestLoads(); // only the newest load draws
let pollTimer = null;
let worldChosen = false; // the world follows the first model offered, then the user's choice

function policyColor(policy, index) {
  return POLICY_COLORS[policy] || colorOf(index + 2);
}

function worldFor(model) {
  if (model.action_dim === 1 && model.observation_dim === 3) return "exp1";
  return "rig";
}

async function refreshForm() {
  const [models, datasets] = await Promise.all([store.models(), store.datasets()]);
  const ready = models.filter((m) => m.status === "ready").sort((a, b) => b.id - a.id);
  setOptions(
    $("eval-model"),
    ready.map((m) => ({ value: m.id, label: `#${m.id} — ${m.objects.length} objects, ds = ${m.latent_dim}` })),
  );
  $("page-evaluation").querySelector("[data-testid=eval-start]").disabled = !ready.length;
  setOptions(
    $("eval-dataset"),
    datasets
      .filter((d) => d.status === "ready")
      .map((d) => ({ value: d.id, label: `#${d.id} ${d.name || d.source} — ${d.n_samples} touches` })),
    { placeholder: "—" },
  );
  if (!worldChosen && ready.length) {
    worldChosen = true;
    await modelChosen();
  }
  worldChanged();
}

async function modelChosen() {
  const id = $("eval-model").value;
  if (!id) return;
  const model = await store.model(id);
  $("eval-world").value = worldFor(model);
  worldChanged();
}

function worldChanged() {
  $("eval-dataset").disabled = $("eval-world").value !== "replay";
}

function requestBody() {
  const policies = [...document.querySelectorAll("#eval-form input[name=policy]:checked")].map((i) => i.value);
  if (!policies.length) throw new Error("Choose at least one policy.");
  const body = {
    model_id: Number($("eval-model").value),
    world: $("eval-world").value,
    policies,
    trials_per_target: Number($("eval-trials").value),
    steps: Number($("eval-steps").value),
    confidence: Number($("eval-confidence").value),
    seed: Number($("eval-seed").value || 0),
    stop_at_confidence: $("eval-stop-at-confidence").checked,
  };
  if (body.world === "replay") {
    if (!$("eval-dataset").value) throw new Error("A replay evaluation needs a dataset of held-out touches.");
    body.dataset_id = Number($("eval-dataset").value);
  }
  if ($("eval-workers").value !== "") body.workers = Number($("eval-workers").value);
  return body;
}

async function startEvaluation() {
  const created = await api("/evaluations", { method: "POST", body: requestBody() });
  toast(`Evaluation #${created.id} started.`, "ok");
  await load(created.id);
  await refreshList();
}

export async function load(id) {
  const current = beginLoad();
  const record = await api(`/evaluations/${id}`);
  if (!current()) return; // a later load (another evaluation) has begun
  evaluation = record;
  render();
  await renderTrials();
  schedulePoll();
}

function schedulePoll() {
  clearTimeout(pollTimer);
  if (evaluation && ACTIVE.includes(evaluation.status)) {
    // A fallback beside the event stream.
    pollTimer = setTimeout(() => load(evaluation.id).catch(() => schedulePoll()), 2000);
  }
}

async function refreshList() {
  const rows = await apiList("/evaluations", { max: 200, pageSize: 200 });
  fill(
    $("eval-list"),
    rows.map((e) =>
      el(
        "tr",
        {
          "data-testid": "eval-row",
          class: evaluation && evaluation.id === e.id ? "selected" : "",
          tabindex: 0,
          onclick: () => guarded(() => load(e.id)),
          onkeydown: (ev) => ev.key === "Enter" && guarded(() => load(e.id)),
        },
        el("td", {}, e.id),
        el("td", {}, `#${e.model_id}`),
        el("td", {}, e.spec.world),
        el("td", {}, (e.spec.policies || []).join(", ")),
        el("td", {}, `${e.done} / ${e.total}`),
        el("td", {}, badge(e.status)),
      ),
    ),
  );
}

function policies() {
  return Object.entries((evaluation.summary && evaluation.summary.policies) || {});
}

function render() {
  const e = evaluation;
  const stopRule = e.spec.stop_at_confidence ? `, trials stop at p ≥ ${e.spec.confidence}` : "";
  $("eval-title").textContent = `Evaluation #${e.id} — model #${e.model_id}, ${e.spec.world}${stopRule}`;
  $("eval-status").textContent = e.status;
  $("eval-status").className = `badge ${e.status}`;
  $("eval-bar").style.width = `${e.total ? (100 * e.done) / e.total : 0}%`;
  const parts = [`${e.done} of ${e.total} trials`];
  const refused = (e.summary && e.summary.refused_trials) || 0;
  if (refused) parts.push(`${refused} refused by the rig (left out of the accuracy)`);
  if (e.seconds !== null && e.seconds !== undefined) parts.push(`${num(e.seconds, 3)} s`);
  if (e.workers) parts.push(`${e.workers} worker${e.workers === 1 ? "" : "s"}`);
  if (e.reason) parts.push(e.reason);
  $("eval-progress").textContent = parts.join(" · ");
  $("eval-stop").disabled = !ACTIVE.includes(e.status);
  $("eval-export-json").href = `api/v1/evaluations/${e.id}/export?format=json`;
  $("eval-export-csv").href = `api/v1/evaluations/${e.id}/export?format=csv`;
  for (const row of $("eval-list").querySelectorAll("tr")) {
    row.classList.toggle("selected", row.firstChild.textContent === String(e.id));
  }
  $("eval-comparison").textContent = comparison();
  drawAccuracy();
  drawObjects();
  drawReliability();
  drawCalibration();
  drawConfusion();
}

/** The engine's sentence: "active reaches 95 % accuracy after 3 touches, passive after 6". */
function comparison() {
  const summary = evaluation.summary;
  if (!summary || !summary.comparison) return "";
  return `${summary.comparison}${summary.partial ? " (so far)" : ""}.`;
}

function drawAccuracy() {
  const datasets = [];
  policies().forEach(([policy, s], i) => {
    const color = policyColor(policy, i);
    const x = s.accuracy_by_touch.map((_, t) => t + 1);
    // The band: upper bound filled down to the lower bound (the dataset just before it).
    datasets.push({
      label: `${policy} 95 % interval (low)`,
      data: x.map((t, j) => ({ x: t, y: s.accuracy_interval[j][0] })),
      borderColor: "transparent",
      pointRadius: 0,
      fill: false,
      band: true,
    });
    datasets.push({
      label: `${policy} 95 % interval`,
      data: x.map((t, j) => ({ x: t, y: s.accuracy_interval[j][1] })),
      borderColor: "transparent",
      backgroundColor: `${color}33`,
      pointRadius: 0,
      fill: "-1",
      band: true,
    });
    datasets.push({
      label: `${policy} (n = ${s.trials ?? "?"}${s.refused ? `, ${s.refused} refused` : ""})`,
      data: x.map((t, j) => ({ x: t, y: s.accuracy_by_touch[j] })),
      borderColor: color,
      backgroundColor: color,
      borderWidth: 2,
      pointRadius: x.length > 40 ? 0 : 3,
      fill: false,
    });
  });
  renderChart("chart-eval-accuracy", {
    type: "line",
    data: { datasets },
    options: {
      parsing: false,
      scales: {
        x: { type: "linear", title: { display: true, text: "touches" }, ticks: { precision: 0 } },
        y: { min: 0, max: 1, title: { display: true, text: "accuracy" }, ticks: { callback: (v) => compactNumber(v) } },
      },
      plugins: {
        legend: {
          position: "bottom",
          labels: { boxWidth: 12, filter: (item, data) => !data.datasets[item.datasetIndex].band },
        },
      },
    },
  });
}

/** Per policy: stated probability against observed accuracy of every answer, per bin. */
function drawReliability() {
  const datasets = [
    {
      label: "calibrated",
      data: [{ x: 0, y: 0 }, { x: 1, y: 1 }],
      borderColor: "#7f7f7f",
      borderDash: [5, 4],
      borderWidth: 1,
      pointRadius: 0,
      showLine: true,
    },
  ];
  policies().forEach(([policy, s], i) => {
    if (!s.calibration) return;
    const color = policyColor(policy, i);
    const scored = s.calibration.all_touches;
    const bins = scored.reliability.filter((b) => b.count > 0);
    const largest = Math.max(1, ...bins.map((b) => b.count));
    datasets.push({
      label: `${policy} (ECE ${num(scored.ece, 3)})`,
      data: bins.map((b) => ({ x: b.mean_confidence, y: b.accuracy, count: b.count, label: String(b.count) })),
      borderColor: color,
      backgroundColor: color,
      labelColor: color,
      borderWidth: 2,
      pointRadius: bins.map((b) => 3 + 7 * Math.sqrt(b.count / largest)),
      showLine: true,
      showLabels: true,
    });
  });
  renderChart("chart-eval-reliability", {
    type: "scatter",
    data: { datasets },
    options: {
      parsing: false,
      scales: {
        x: { type: "linear", min: 0, max: 1, title: { display: true, text: "stated probability of the answer" } },
        // Room above 1 for the points at 1 and their counts; no tick there.
        y: { min: 0, max: 1.05, title: { display: true, text: "observed accuracy" }, ticks: { callback: (v) => (v <= 1 ? compactNumber(v) : "") } },
      },
      plugins: scatterPlugins((p, item) =>
        p.count === undefined ? item.dataset.label : `${item.dataset.label}: stated ${num(p.x, 3)}, right ${num(p.y, 3)} of ${p.count} answers`,
      ),
    },
  });
}

/** "3 of 120 (2.5 %)": the answers given with p ≥ the threshold, and the wrong ones. */
function sureAndWrong(sure) {
  const share = sure.share_wrong === null ? "" : ` (${num(100 * sure.share_wrong, 3)} %)`;
  return `${sure.wrong} of ${sure.sure}${share}`;
}

/** "0.041, 0.063": the ECE the same stated probabilities would show by sampling alone were
 * they calibrated (an observed ECE below the 95th percentile is within that noise); "—" for a
 * report without it. */
function eceIfCalibrated(scored) {
  return scored ? `${num(scored.mean, 3)}, ${num(scored.p95, 3)}` : "—";
}

/** ECE, Brier, log-loss and sure-and-wrong per policy, over every (trial, touch) and at T, with
 * the ECE expected from sampling alone. */
function drawCalibration() {
  const entries = policies();
  if (!entries.length) {
    fill($("eval-calibration"), el("p", { class: "muted" }, "No finished trials yet."));
    return;
  }
  if (!entries.some(([, s]) => s.calibration)) {
    fill($("eval-calibration"), el("p", { class: "muted" }, "This summary has no calibration."));
    return;
  }
  const threshold = entries.map(([, s]) => s.calibration).find(Boolean).all_touches.sure_and_wrong.threshold;
  const head = [
    "policy",
    "answers",
    "ECE",
    "Brier",
    "log-loss (nats)",
    `sure (p ≥ ${threshold}) and wrong`,
    "ECE if calibrated",
  ];
  const rows = [];
  for (const [policy, s] of entries) {
    if (!s.calibration) continue;
    for (const [scope, scored] of [["every touch", s.calibration.all_touches], ["at T", s.calibration.final]]) {
      rows.push(
        el(
          "tr",
          { "data-testid": "eval-calibration-row", "data-policy": policy, "data-scope": scope },
          el("th", { scope: "row" }, `${policy}, ${scope}`),
          el("td", {}, scored.answers),
          el("td", { "data-testid": "eval-ece" }, num(scored.ece, 3)),
          el("td", {}, num(scored.brier, 3)),
          el("td", {}, num(scored.log_loss, 3)),
          el("td", { "data-testid": "eval-sure-wrong" }, sureAndWrong(scored.sure_and_wrong)),
          el("td", { "data-testid": "eval-ece-null" }, eceIfCalibrated(scored.ece_if_calibrated)),
        ),
      );
    }
  }
  fill(
    $("eval-calibration"),
    el(
      "table",
      { class: "table compact", "data-testid": "eval-calibration-table" },
      el("thead", {}, el("tr", {}, head.map((h) => el("th", { scope: "col" }, h)))),
      el("tbody", {}, rows),
    ),
    byTouchTable(entries.filter(([, s]) => s.calibration)),
  );
}

/** ECE and sure-and-wrong after each touch, beside the accuracy curve's touches. */
function byTouchTable(entries) {
  const steps = Math.max(...entries.map(([, s]) => s.calibration.by_touch.length));
  const touches = Array.from({ length: steps }, (_, t) => t + 1);
  const rows = [];
  for (const [policy, s] of entries) {
    const byTouch = s.calibration.by_touch;
    rows.push(
      el(
        "tr",
        { "data-testid": "eval-ece-by-touch", "data-policy": policy },
        el("th", { scope: "row" }, `${policy}: ECE`),
        byTouch.map((t) => el("td", {}, num(t.ece, 3))),
      ),
      el(
        "tr",
        { "data-testid": "eval-sure-wrong-by-touch", "data-policy": policy },
        el("th", { scope: "row" }, `${policy}: sure and wrong`),
        byTouch.map((t) => el("td", { title: sureAndWrong(t.sure_and_wrong) }, `${t.sure_and_wrong.wrong}/${t.sure_and_wrong.sure}`)),
      ),
    );
  }
  return el(
    "table",
    { class: "table compact", "data-testid": "eval-calibration-by-touch" },
    el("thead", {}, el("tr", {}, el("th", { scope: "col" }, "after touch"), touches.map((t) => el("th", { scope: "col" }, t)))),
    el("tbody", {}, rows),
  );
}

function objectNames() {
  const names = [];
  for (const [, s] of policies()) {
    for (const name of Object.keys(s.per_object || {})) if (!names.includes(name)) names.push(name);
  }
  return names;
}

function drawObjects() {
  const names = objectNames();
  renderChart("chart-eval-objects", {
    type: "bar",
    data: {
      labels: names,
      datasets: policies().map(([policy, s], i) => ({
        label: policy,
        data: names.map((n) => (s.per_object[n] ? s.per_object[n].accuracy : null)),
        backgroundColor: policyColor(policy, i),
      })),
    },
    options: {
      scales: { y: { min: 0, max: 1, title: { display: true, text: "final accuracy" } } },
      plugins: { legend: bottomLegend() },
    },
  });
}

function drawConfusion() {
  const entries = policies();
  const select = $("eval-confusion-policy");
  setOptions(select, entries.map(([policy]) => ({ value: policy, label: policy })));
  const found = entries.find(([policy]) => policy === select.value) || entries[0];
  if (!found) {
    fill($("eval-confusion"), el("p", { class: "muted" }, "No finished trials yet."));
    return;
  }
  const confusion = found[1].confusion || {};
  const rows = Object.keys(confusion);
  const columns = [...new Set(rows.flatMap((r) => Object.keys(confusion[r])))];
  const table = el(
    "table",
    { class: "table compact confusion", "data-testid": "eval-confusion-table" },
    el(
      "thead",
      {},
      el("tr", {}, el("th", { scope: "col" }, "target ↓ / answer →"), columns.map((c) => el("th", { scope: "col" }, c))),
    ),
    el(
      "tbody",
      {},
      rows.map((r) => {
        const total = columns.reduce((sum, c) => sum + (confusion[r][c] || 0), 0) || 1;
        return el(
          "tr",
          {},
          el("th", { scope: "row" }, r),
          columns.map((c) => {
            const count = confusion[r][c] || 0;
            const shade = Math.round(200 * (count / total));
            return el(
              "td",
              {
                class: r === c ? "diagonal" : "",
                style: `background: rgba(31, 95, 191, ${(shade / 255).toFixed(3)})`,
                title: `${r} answered as ${c}: ${count}`,
              },
              count,
            );
          }),
        );
      }),
    ),
  );
  fill($("eval-confusion"), table);
}

async function renderTrials() {
  const id = evaluation.id;
  // The newest SHOWN_TRIALS finished trials.
  const page = await api(`/evaluations/${id}/trials?limit=${SHOWN_TRIALS}&offset=${Math.max(0, evaluation.done - SHOWN_TRIALS)}`);
  const rows = page.data;
  if (!evaluation || evaluation.id !== id) return;
  const open = (n) => {
    location.hash = `#trials?evaluation=${id}&trial=${n}`;
  };
  fill(
    $("eval-trials-body"),
    [...rows].reverse().map((t) =>
      el(
        "tr",
        // Every trial opens in the Trials view; a refused one's row also says what was refused.
        {
          "data-testid": "eval-trial-row",
          class: t.refused ? "refused" : false,
          tabindex: 0,
          onclick: () => open(t.number),
          onkeydown: (e) => e.key === "Enter" && open(t.number),
        },
        el("td", {}, t.number),
        el("td", {}, t.policy),
        el("td", {}, t.target),
        el("td", {}, t.refused ? "refused" : `${t.answer ?? "—"}${t.correct ? " ✓" : " ✗"}`),
        el("td", {}, t.touches),
        t.refused && t.refusal
          ? el(
              "td",
              { "data-testid": "eval-trial-refusal", title: `action [${t.refusal.action.map((v) => num(v, 3)).join(", ")}]` },
              `refused at touch ${t.refusal.touch}: ${t.refusal.error}: ${t.refusal.reason}`,
            )
          : el("td", {}, t.stop_reason ?? "—"),
      ),
    ),
  );
  const count = page.count;
  $("eval-trials-count").textContent = `${count} finished trial${count === 1 ? "" : "s"}${count > rows.length ? ` (the newest ${rows.length} listed)` : ""}.`;
}

const reloadSoon = throttle(async () => {
  if (evaluation) await load(evaluation.id);
}, 400);

const refreshListSoon = throttle(refreshList, 1000);

export function init() {
  $("eval-form").addEventListener("submit", (e) => {
    e.preventDefault();
    guarded(startEvaluation, e.submitter);
  });
  $("eval-model").addEventListener("change", () => guarded(modelChosen));
  $("eval-world").addEventListener("change", worldChanged);
  $("eval-confusion-policy").addEventListener("change", drawConfusion);
  $("eval-stop").addEventListener("click", () =>
    guarded(async () => {
      if (!evaluation) return;
      await api(`/evaluations/${evaluation.id}/stop`, { method: "POST" });
      await load(evaluation.id);
    }, $("eval-stop")),
  );
  worldChanged();
}

export async function show() {
  await refreshForm();
  await refreshList();
  if (evaluation) await load(evaluation.id);
  else {
    const recent = await apiList("/evaluations", { max: 1, pageSize: 1 }).catch(() => []);
    if (recent.length) await load(recent[0].id);
  }
}

export function onEvent(event, kind) {
  if (kind !== "evaluation" && kind !== "model" && kind !== "dataset") return;
  if ($("page-evaluation").hidden) return;
  if (kind !== "evaluation") {
    refreshForm();
    return;
  }
  const id = (event.data || {}).evaluation_id;
  if (evaluation && id === evaluation.id) reloadSoon();
  if (/status/.test(event.type)) refreshListSoon();
}
