// Collection: gather a dataset on the rig (a run with progress, ETA, the live tactile trace of
// the current touch, pause/resume/stop), or upload a CSV; the list of datasets.

import { api, apiList, apiOptional, ApiError } from "../api.js";
import { compactNumber, lineChart } from "../charts.js";
import { etaSeconds, formatDuration, normalizeTrace } from "../lib/analysis.js";
import * as store from "../store.js";
import { $, badge, el, fill, guarded, throttle, toast, vec } from "../ui.js";
import { ACTIVE } from "../states.js";
import { newestLoads } from "../lib/newest.js";
import { bindRunControls, enableRunControls, runControls } from "../run_controls.js";

let run = null; // the collection on show
const beginLoad = newestLoads(); // only the newest load draws

// What each action design (the API's action_design) does, shown under the select.
const DESIGN_HELP = {
  random: "Random: a fresh action x ~ N(0, σ²I) for every touch, so each object gets its own actions.",
  shared:
    "Shared: “touches per object” actions drawn once (Sobol points through N(0, σ²I)) and applied to " +
    "every object, each in its own random order (so slow drift is not learned as part of an " +
    "action's response); fits and plans then take the exact Kronecker path.",
  teaching: "Teaching: the teaching action x = 0, repeated on every object.",
  adaptive:
    "Adaptive: the first half random, then rounds at the actions the planners would choose from a " +
    "model fitted to the touches so far (same budget; 3 touches per object or more).",
};

function showDesignHelp() {
  $("col-design-help").textContent = DESIGN_HELP[$("col-design").value] ?? "";
}

function objectRow(name = "", slot = "") {
  const row = el(
    "div",
    { class: "object-row" },
    el("input", { type: "text", placeholder: "object name", value: name, "aria-label": "Object name", required: true }),
    el("input", { type: "number", min: 0, placeholder: "slot", value: slot, "aria-label": "Turntable slot", required: true }),
    el("button", { type: "button", class: "icon", "aria-label": "Remove object", onclick: () => row.remove() }, "✕"),
  );
  return row;
}

async function prefillObjects() {
  const box = $("col-objects");
  if (box.children.length) return;
  let objects = null;
  try {
    objects = await apiOptional("/objects?limit=100");
  } catch {
    objects = null;
  }
  const rows = objects ? objects.data || objects : [];
  const withSlots = rows.filter((o) => o.slot !== null && o.slot !== undefined).sort((a, b) => a.slot - b.slot);
  if (withSlots.length >= 2) withSlots.forEach((o) => box.append(objectRow(o.name, o.slot)));
  else {
    box.append(objectRow("cup A", 0));
    box.append(objectRow("cup B", 1));
  }
}

function renderRun() {
  const box = $("collection-run");
  if (!run) {
    fill(box, el("p", { class: "muted" }, "No collection yet."));
    $("collection-bar").style.width = "0";
    return;
  }
  const done = run.done ?? 0;
  const total = run.total ?? 0;
  const started = run.started_at ? new Date(run.started_at).getTime() : null;
  const end = run.finished_at ? new Date(run.finished_at).getTime() : Date.now();
  const elapsed = started ? (end - started) / 1000 : null;
  const eta = ACTIVE.includes(run.status) ? etaSeconds(done, total, elapsed) : null;
  $("collection-bar").style.width = total ? `${(100 * done) / total}%` : "0";
  fill(
    box,
    el(
      "p",
      {},
      el("strong", {}, `Collection #${run.id} `),
      badge(run.status, "collection-status"),
      run.reason ? el("span", { class: "muted" }, ` ${run.reason}`) : null,
    ),
    el(
      "dl",
      { class: "kv" },
      el("dt", {}, "touches"),
      el("dd", { "data-testid": "collection-progress" }, `${done} / ${total}`),
      el("dt", {}, "elapsed"),
      el("dd", {}, formatDuration(elapsed)),
      el("dt", {}, "ETA"),
      el("dd", { "data-testid": "collection-eta" }, ACTIVE.includes(run.status) ? formatDuration(eta) : "—"),
      el("dt", {}, "dataset"),
      el("dd", {}, run.dataset_id ? `#${run.dataset_id}` : "—"),
    ),
  );
  enableRunControls(runControls("collection-controls"), run.status);
}

// The channels differ by orders of magnitude (vibration vs heat flux vs temperature): each is
// drawn scaled to its own range over the touch, which the legend states.
function renderTrace(raw) {
  const trace = normalizeTrace(raw);
  if (!trace) return;
  lineChart(
    "chart-trace",
    trace.channels.map((c) => {
      const finite = c.values.filter(Number.isFinite);
      const lo = Math.min(...finite);
      const hi = Math.max(...finite);
      const span = hi - lo || 1;
      return {
        label: `${c.name} [${compactNumber(lo)}, ${compactNumber(hi)}]`,
        x: trace.times,
        y: c.values.map((v) => (v - lo) / span),
      };
    }),
    { xTitle: "time (s)", yTitle: "scaled to its range", yMin: 0, yMax: 1 },
  );
}

async function loadRun(id) {
  const current = beginLoad();
  const record = await api(`/collections/${id}`);
  if (!current()) return; // a later load (another run) has begun
  run = record;
  renderRun();
  const trace = run.trace || run.last_trace || (run.params && run.params.last_trace);
  if (trace) renderTrace(trace);
}

async function refreshDatasets() {
  const rows = await store.datasets(true);
  fill(
    $("datasets-body"),
    rows.map((d) =>
      el(
        "tr",
        { "data-testid": "dataset-row" },
        el("td", {}, d.id),
        el("td", {}, d.name || "—"),
        el("td", {}, d.source, d.status && d.status !== "ready" ? ` (${d.status})` : ""),
        el("td", {}, (d.objects || []).join(", ")),
        el("td", {}, d.n_samples),
        el("td", {}, `${d.action_dim} / ${d.observation_dim}`),
        el("td", {}, el("a", { href: `api/v1/datasets/${d.id}/export?format=csv`, download: `dataset-${d.id}.csv` }, "CSV")),
      ),
    ),
  );
}

const refreshRunSoon = throttle(async () => {
  if (run) await loadRun(run.id);
}, 400);

async function startCollection(form) {
  const objects = [...$("col-objects").querySelectorAll(".object-row")].map((row) => {
    const [name, slot] = row.querySelectorAll("input");
    return { name: name.value.trim(), slot: Number(slot.value) };
  });
  const body = {
    name: $("col-name").value.trim(),
    objects,
    samples_per_object: Number($("col-samples").value),
    action_design: $("col-design").value,
    press_depth: $("col-press-depth").checked,
  };
  if ($("col-scale").value !== "") body.action_scale = Number($("col-scale").value);
  if ($("col-seed").value !== "") body.seed = Number($("col-seed").value);
  if ($("col-placements").value !== "") body.placements = Number($("col-placements").value);
  const created = await api("/collections", { method: "POST", body });
  toast(`Collection #${created.id} started.`, "ok");
  await loadRun(created.id);
  form.reset();
  showDesignHelp();
}

async function upload(form) {
  const file = $("upload-file").files[0];
  if (!file) throw new Error("Choose a CSV file first.");
  const data = new FormData();
  data.append("file", file);
  if ($("upload-name").value.trim()) data.append("name", $("upload-name").value.trim());
  const created = await api("/datasets", { method: "POST", body: data });
  toast(`Dataset #${created.id}: ${created.n_samples} touches of ${created.objects.length} objects.`, "ok");
  form.reset();
  await refreshDatasets();
}

export function init() {
  $("col-add-object").addEventListener("click", () => $("col-objects").append(objectRow()));
  $("col-design").addEventListener("change", showDesignHelp);
  showDesignHelp();
  $("collection-form").addEventListener("submit", (e) => {
    e.preventDefault();
    guarded(() => startCollection(e.currentTarget), e.submitter);
  });
  $("upload-form").addEventListener("submit", (e) => {
    e.preventDefault();
    guarded(() => upload(e.currentTarget), e.submitter);
  });
  bindRunControls(runControls("collection-controls"), "/collections", () => run, loadRun);
  renderRun();
}

export async function show() {
  await prefillObjects();
  await refreshDatasets();
  if (!run) {
    try {
      const runs = await apiList("/collections", { max: 20, pageSize: 20 });
      if (runs.length) {
        const newest = runs.reduce((a, b) => (a.id > b.id ? a : b));
        await loadRun(newest.id);
      }
    } catch (error) {
      if (!(error instanceof ApiError && error.status === 404)) throw error;
    }
  } else {
    await loadRun(run.id);
  }
}

export function onEvent(event, kind) {
  if (kind !== "collection" && kind !== "run" && kind !== "dataset") return;
  const data = event.data || {};
  const id = data.collection_id ?? data.run_id ?? (kind === "collection" ? data.id : null);
  const trace = data.trace || data.raw;
  if (Array.isArray(data.observation)) {
    $("trace-note").textContent = `Touch ${data.done ?? "?"} of ${data.total ?? "?"}: ${data.object ?? "?"}, features y = ${vec(data.observation)}${trace ? "" : " (the server sends no raw trace)"}`;
  }
  if (id !== null && id !== undefined && (!run || run.id === id || ["queued", "running"].includes(data.status))) {
    if (!run || run.id !== id) run = { id };
    if (trace) renderTrace(trace);
    if (!$("page-collection").hidden) refreshRunSoon();
  }
  const finished = kind === "collection" && data.status && !ACTIVE.includes(data.status);
  if ((kind === "dataset" || finished) && !$("page-collection").hidden) refreshDatasets();
}
