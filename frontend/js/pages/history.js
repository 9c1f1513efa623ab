// History: filter trials, compare policies (accuracy against touches, active vs passive),
// export CSV/JSON; run a batch of simulated trials per policy to compare on one model; the
// request audit (GET /audit): who started, stopped or e-stopped what, and the outcome.

import { api, apiList, download } from "../api.js";
import { lineChart } from "../charts.js";
import { accuracyByTouches, isotropicCov, toCSV, trialRow } from "../lib/analysis.js";
import { FINISHED } from "../states.js";
import * as store from "../store.js";
import { $, badge, el, fill, guarded, setOptions, throttle, timeOf, toast } from "../ui.js";

const POLICY_COLORS = { active: "#1f5fbf", passive: "#d9822b", fixed: "#7f7f7f" };
const detailCache = new Map(); // finished trials never change
let shown = []; // trial details currently listed
let batchRunning = false;

function filters() {
  const values = {};
  for (const key of ["model_id", "status", "policy", "mode"]) {
    const value = $(`hist-${key === "model_id" ? "model" : key}`).value;
    if (value) values[key] = value;
  }
  return values;
}

async function detail(summary) {
  const key = summary.id;
  if (detailCache.has(key)) return detailCache.get(key);
  const record = await api(`/trials/${summary.id}`);
  if (FINISHED.includes(record.status)) detailCache.set(key, record);
  return record;
}

async function details(summaries, parallel = 6) {
  const out = new Array(summaries.length);
  let next = 0;
  async function worker() {
    while (next < summaries.length) {
      const i = next;
      next += 1;
      out[i] = await detail(summaries[i]);
    }
  }
  await Promise.all(Array.from({ length: Math.min(parallel, summaries.length) }, worker));
  return out;
}

async function refreshModels() {
  const models = await store.models();
  setOptions(
    $("hist-model"),
    models.filter((m) => m.status === "ready").map((m) => ({ value: m.id, label: `#${m.id} (${m.objects.length} objects, ds = ${m.latent_dim})` })),
    { placeholder: "any" },
  );
}

async function refresh() {
  const f = filters();
  const query = new URLSearchParams();
  if (f.model_id) query.set("model_id", f.model_id);
  if (f.status) query.set("status", f.status);
  if (f.policy) query.set("policy", f.policy);
  if (f.mode) query.set("mode", f.mode);
  let summaries = await apiList(`/trials${query.toString() ? `?${query}` : ""}`, { max: 500 });
  summaries = summaries.filter((t) => (!f.policy || t.policy === f.policy) && (!f.mode || t.mode === f.mode));
  summaries.sort((a, b) => b.id - a.id);
  shown = await details(summaries);
  fill(
    $("history-body"),
    shown.map((t) => {
      const row = trialRow(t);
      return el(
        "tr",
        { "data-testid": "history-row", tabindex: 0, onclick: () => openTrial(t.id), onkeydown: (e) => e.key === "Enter" && openTrial(t.id) },
        el("td", {}, t.id),
        el("td", {}, `#${t.model_id}`),
        el("td", {}, t.mode),
        el("td", {}, t.policy),
        el("td", {}, row.target || "—"),
        el("td", {}, row.result ? `${row.result}${row.correct === true ? " ✓" : row.correct === false ? " ✗" : ""}` : "—"),
        el("td", {}, row.touches),
        el("td", {}, badge(t.status)),
        el("td", {}, timeOf(t.started_at || t.created_at)),
      );
    }),
  );
  $("history-count").textContent = `${shown.length} trial${shown.length === 1 ? "" : "s"}.`;
  drawAccuracy();
}

function drawAccuracy() {
  const maxTouches = Math.max(1, ...shown.map((t) => t.max_steps || (t.steps ? t.steps.length : 1)));
  const accuracy = accuracyByTouches(shown, Math.min(maxTouches, 50));
  const series = Object.entries(accuracy).map(([policy, a]) => ({
    label: `${policy} (n = ${a.n})`,
    x: a.touches,
    y: a.accuracy,
    color: POLICY_COLORS[policy],
  }));
  lineChart("chart-accuracy", series, { xTitle: "touches", yTitle: "accuracy", yMin: 0, yMax: 1 });
  $("accuracy-note").textContent = series.length
    ? "Fraction of finished trials with a known target whose answer after t touches is the target (a trial that stopped keeps its final answer)."
    : "No finished trials with a known target in this selection yet.";
}

function openTrial(id) {
  location.hash = "#trials";
  import("./trials.js").then((trials) => trials.load(id));
}

function exportCSV() {
  const rows = shown.map(trialRow);
  const columns = ["id", "model_id", "mode", "policy", "status", "target", "result", "correct", "touches", "confidence", "created_at", "finished_at", "reason"];
  download("trials.csv", toCSV(rows, columns), "text/csv");
}

function exportJSON() {
  download("trials.json", `${JSON.stringify({ filters: filters(), trials: shown }, null, 2)}\n`, "application/json");
}

async function waitUntilFinished(id) {
  for (;;) {
    const record = await api(`/trials/${id}`);
    if (FINISHED.includes(record.status)) return record;
    await new Promise((resolve) => setTimeout(resolve, 300));
  }
}

async function runBatch() {
  if (batchRunning) return;
  const models = (await store.models()).filter((m) => m.status === "ready");
  const modelId = Number($("hist-model").value) || (models.length ? Math.max(...models.map((m) => m.id)) : null);
  if (!modelId) throw new Error("Fit a model first.");
  const model = await store.model(modelId);
  const perPolicy = Number($("batch-n").value);
  const world = model.action_dim === 1 && model.observation_dim === 3 ? "exp1" : "rig";
  batchRunning = true;
  let done = 0;
  const total = 2 * perPolicy;
  try {
    for (let i = 0; i < perPolicy; i += 1) {
      const target = model.objects[i % model.objects.length].name;
      for (const policy of ["active", "passive"]) {
        $("batch-status").textContent = `Running ${done + 1} of ${total} (${policy}, target ${target})…`;
        const body = {
          model_id: modelId,
          mode: world === "exp1" ? "simulated" : "rig",
          policy,
          max_steps: 10,
          prior_cov: isotropicCov(model.latent_dim, 5),
          target,
          seed: 1000 + i,
        };
        if (body.mode === "simulated") body.simulation = { world, step_interval_s: 0 };
        const created = await api("/trials", { method: "POST", body });
        await waitUntilFinished(created.id);
        done += 1;
      }
    }
    $("batch-status").textContent = `Batch done: ${total} trials on model #${modelId}.`;
    toast(`Comparison batch done (${total} trials).`, "ok");
  } finally {
    batchRunning = false;
  }
  $("hist-model").value = String(modelId);
  await refresh();
}

const refreshSoon = throttle(refresh, 1500);

const AUDIT_ROWS = 200;

function auditAuth(row) {
  if (!row.authenticated) return "no";
  return row.auth_method === "session" ? "yes (signed-in dashboard)" : "yes (API token)";
}

async function refreshAudit() {
  const page = await api(`/audit?limit=${AUDIT_ROWS}`);
  fill(
    $("audit-body"),
    page.data.map((row) =>
      el(
        "tr",
        { "data-testid": "audit-row", class: row.status_code >= 400 ? "audit-refused" : "" },
        el("td", {}, timeOf(row.time)),
        el("td", { "data-testid": "audit-client" }, row.client || "—"),
        el("td", { "data-testid": "audit-request" }, `${row.method} ${row.path}`),
        el("td", { "data-testid": "audit-status" }, String(row.status_code)),
        el("td", { "data-testid": "audit-auth" }, auditAuth(row)),
      ),
    ),
  );
  $("audit-count").textContent =
    page.count > page.data.length ? `Newest ${page.data.length} of ${page.count}.` : `${page.count} recorded.`;
}

const refreshAuditSoon = throttle(() => refreshAudit().catch(() => {}), 1500);
// The server writes audit rows a moment after each answer (off the request path): while the
// page is open, the table is re-read every few seconds.
const AUDIT_POLL_MS = 3000;

export function init() {
  $("history-form").addEventListener("submit", (e) => {
    e.preventDefault();
    guarded(refresh, e.submitter);
  });
  $("export-csv").addEventListener("click", exportCSV);
  $("export-json").addEventListener("click", exportJSON);
  $("batch-form").addEventListener("submit", (e) => {
    e.preventDefault();
    guarded(runBatch, e.submitter);
  });
  $("audit-refresh").addEventListener("click", (e) => guarded(refreshAudit, e.currentTarget));
  setInterval(() => {
    if (!$("page-history").hidden && !document.hidden) refreshAuditSoon();
  }, AUDIT_POLL_MS);
}

export async function show() {
  await refreshModels();
  await Promise.all([refresh(), refreshAudit()]);
}

export function onEvent(event, kind) {
  if (kind === "trial" && !$("page-history").hidden && !batchRunning && /status|finished|completed/.test(event.type)) refreshSoon();
  // A change was made (by anyone): its audit row is there by now or shortly.
  if (!$("page-history").hidden && /status|estop|created/.test(event.type || "")) refreshAuditSoon();
}
