// Models: fit a manifold (latent dim or auto, noise model, optimizer, restarts), its progress (or its
// place in the queue of fits) and a stop, the manifold plot with object labels, the
// hyperparameters, export and import of the model document.

import { api } from "../api.js";
import { manifoldChart } from "../charts.js";
import { formatDuration } from "../lib/analysis.js";
import { kernelsText, placementText } from "../lib/model_text.js";
import { MODEL_ACTIVE } from "../states.js";
import * as store from "../store.js";
import { $, badge, el, fill, guarded, num, setOptions, throttle, timeOf, toast } from "../ui.js";

let selected = null;

// The time the running stage (the choice of ds, then the fit) has left at its last progress
// event, estimated by the server from its pace (app/services/remaining.py).
function remainingText(model) {
  const p = model.progress || {};
  if (p.remaining_s === null || p.remaining_s === undefined) return "";
  const left = p.remaining_s;
  const what = p.stage === "latent selection" ? "choice of ds" : "fit";
  return left > 0 ? `about ${formatDuration(left)} left of the ${what}` : `${what} finishing`;
}

function progressText(model) {
  const p = model.progress || {};
  const parts = [];
  if (p.stage === "latent selection" && p.phase) parts.push(p.phase);
  else if (p.start !== undefined && p.n_starts) parts.push(`start ${Math.min(p.start + 1, p.n_starts)} of ${p.n_starts}`);
  if (p.iteration !== undefined) parts.push(`iteration ${p.iteration}`);
  if (p.best_log_likelihood !== undefined && p.best_log_likelihood !== null) parts.push(`best log-lik ${num(p.best_log_likelihood, 6)}`);
  const left = remainingText(model);
  if (left) parts.push(left);
  return parts.join(" · ") || "starting…";
}

function statusText(model) {
  if (model.status === "queued" && model.queue_position) return `queued: number ${model.queue_position} in the queue of fits`;
  if (model.status === "fitting") return `fitting: ${progressText(model)}`;
  return model.status;
}

async function stopFit(id) {
  await api(`/models/${id}/stop`, { method: "POST" });
  toast(`Fit of model #${id} stopped.`, "ok");
  await refreshList();
}

function progressFraction(model) {
  const p = model.progress || {};
  if (p.fraction !== undefined && p.fraction !== null) return Math.min(1, Math.max(0, p.fraction));
  if (!p.n_starts) return 0;
  return Math.min(1, (p.start ?? 0) / p.n_starts);
}

async function refreshList() {
  const [models, datasets] = await Promise.all([store.models(true), store.datasets()]);
  setOptions(
    $("fit-dataset"),
    datasets.map((d) => ({ value: d.id, label: `#${d.id} ${d.name || d.source} — ${d.objects.length} objects, ${d.n_samples} touches` })),
  );
  fill(
    $("models-body"),
    models.map((m) =>
      el(
        "tr",
        {
          "data-testid": "model-row",
          class: selected === m.id ? "selected" : "",
          tabindex: 0,
          onclick: () => select(m.id),
          onkeydown: (e) => e.key === "Enter" && select(m.id),
        },
        el("td", {}, m.id),
        el("td", {}, `#${m.dataset_id}`),
        el("td", {}, MODEL_ACTIVE.includes(m.status) && m.latent_dim === 0 ? "auto" : m.latent_dim),
        el("td", {}, badge(m.status), m.status === "queued" && m.queue_position ? el("span", { class: "small muted", "data-testid": "queue-position" }, ` #${m.queue_position}`) : ""),
        el("td", {}, num(m.log_likelihood, 6)),
        el("td", {}, m.fit_seconds !== null && m.fit_seconds !== undefined ? formatDuration(m.fit_seconds) : "—"),
      ),
    ),
  );
  // Fits not ended: the running ones with their progress, the queued ones with their place.
  const active = models.filter((m) => MODEL_ACTIVE.includes(m.status)).sort((a, b) => a.id - b.id);
  fill(
    $("fit-progress"),
    active.map((m) =>
      el(
        "div",
        { "data-testid": m.status === "fitting" ? "fit-running" : "fit-queued" },
        el(
          "p",
          { class: "small" },
          `Model #${m.id} ${statusText(m)} `,
          el("button", { type: "button", class: "small", "data-testid": "fit-stop", onclick: (e) => guarded(() => stopFit(m.id), e.currentTarget) }, "Stop"),
        ),
        m.status === "fitting" ? el("div", { class: "progress" }, el("div", { class: "progress-bar", style: `width:${100 * progressFraction(m)}%` })) : "",
      ),
    ),
  );
  if (selected === null && models.length) {
    const ready = models.find((m) => m.status === "ready");
    if (ready) await select(ready.id);
  }
}

export async function select(id) {
  selected = id;
  for (const row of $("models-body").querySelectorAll("tr")) {
    row.classList.toggle("selected", row.firstChild.textContent === String(id));
  }
  const model = await api(`/models/${id}`);
  $("model-detail").hidden = false;
  $("model-detail-title").textContent = `Model #${model.id} — ds = ${model.latent_dim}, dataset #${model.dataset_id}`;
  $("model-export").href = `api/v1/models/${model.id}/export`;
  $("model-export").setAttribute("download", `model-${model.id}.json`);
  if (model.status === "ready" && model.objects.length) manifoldChart("chart-manifold", model.objects);
  const ds = model.latent_dim;
  const dx = model.action_dim;
  fill(
    $("hyper-head"),
    el(
      "tr",
      {},
      el("th", {}, "feature"),
      el("th", {}, "σ²_f"),
      el("th", {}, "σ²_n"),
      el("th", {}, `latent ℓ (${ds})`),
      el("th", {}, `action ℓ (${dx})`),
    ),
  );
  fill(
    $("hyper-body"),
    (model.hyperparameters || []).map((h) =>
      el(
        "tr",
        {},
        el("td", {}, `y_${h.feature + 1}`),
        el("td", {}, num(h.signal_variance)),
        el("td", {}, num(h.noise_variance)),
        el("td", {}, h.latent_lengthscales.map((v) => num(v, 3)).join(", ")),
        el("td", {}, h.action_lengthscales.map((v) => num(v, 3)).join(", ")),
      ),
    ),
  );
  const diag = model.diagnostics || {};
  fill(
    $("model-facts"),
    [
      ["status", statusText(model) + (model.reason ? ` — ${model.reason}` : "")],
      ["objects", model.objects.map((o) => o.name).join(", ")],
      ["optimizer", `${model.optimizer}, ${model.restarts} restarts, seed ${model.seed ?? "—"}`],
      ["log-likelihood", num(model.log_likelihood, 8)],
      ["features", featuresText(model.features)],
      ["noise model", noiseText(model.noise_model)],
      ["kernels", kernelsText(model)],
      ["placement effect", placementText(model)],
      ["latent dim", latentText(model)],
      ["fit time", formatDuration(model.fit_seconds)],
      ["converged", diag.converged === undefined ? "—" : String(diag.converged)],
      ["at bounds", (diag.hyperparameters_at_bounds || []).join(", ") || "none"],
      ["finished", timeOf(model.finished_at)],
    ].flatMap(([k, v]) => [el("dt", {}, k), el("dd", {}, v)]),
  );
}

function featuresText(features) {
  if (!features) return "as recorded (channel means of a rig touch)";
  const channels = features.channels.join(", ");
  if (features.kind === "means") return `channel means of ${channels} (dy = ${features.output_names.length})`;
  const how = `${features.reduced_features} numbers of ${channels} → ${features.projection.toUpperCase()} to dy = ${features.output_names.length}`;
  return `whole touch: ${how}${features.explanation ? ` — ${features.explanation}` : ""}`;
}

function noiseText(noise) {
  if (!noise) return "—";
  if (noise.kind !== "correlated") return `${noise.kind}${noise.note ? ` — ${noise.note}` : ""}`;
  const n = noise.correlation.length;
  let largest = 0;
  let pair = "";
  for (let a = 0; a < n; a++) {
    for (let b = a + 1; b < n; b++) {
      if (Math.abs(noise.correlation[a][b]) > Math.abs(largest)) {
        largest = noise.correlation[a][b];
        pair = `y_${a + 1}/y_${b + 1}`;
      }
    }
  }
  return `correlated (largest ${pair}: ${num(largest, 2)}) — ${noise.note}`;
}

function latentText(model) {
  const sel = model.latent_selection;
  if (!sel) return String(model.latent_dim);
  const scores = sel.candidates.map((c) => `ds=${c.latent_dim}: ${num(c.mean, 4)} ± ${num(c.standard_error, 2)}`).join("; ");
  return `${model.latent_dim} (auto) — ${sel.explanation} [${scores}]`;
}

async function fit() {
  const body = {
    dataset_id: Number($("fit-dataset").value),
    latent_dim: $("fit-dim").value.trim().toLowerCase() === "auto" ? "auto" : Number($("fit-dim").value),
    noise_model: $("fit-noise").value,
    optimizer: $("fit-optimizer").value,
    kernels: $("fit-kernels").value,
    restarts: Number($("fit-restarts").value),
  };
  if ($("fit-seed").value !== "") body.seed = Number($("fit-seed").value);
  const created = await api("/models", { method: "POST", body });
  toast(created.status === "queued" ? `Model #${created.id} is queued: number ${created.queue_position} in the queue of fits.` : `Model #${created.id} is fitting in the background.`, "ok");
  selected = created.id;
  await refreshList();
}

async function importModel() {
  const file = $("import-file").files[0];
  if (!file) throw new Error("Choose a model JSON document first.");
  const text = await file.text();
  const created = await api("/models/import", { method: "POST", body: text, headers: { "Content-Type": "application/json" } });
  toast(`Model imported as #${created.id}.`, "ok");
  await refreshList();
  await select(created.id);
}

const refreshSoon = throttle(async () => {
  await refreshList();
  if (selected !== null) await select(selected);
}, 500);

export function init() {
  $("fit-form").addEventListener("submit", (e) => {
    e.preventDefault();
    guarded(fit, e.submitter);
  });
  $("import-form").addEventListener("submit", (e) => {
    e.preventDefault();
    guarded(importModel, e.submitter);
  });
}

export async function show() {
  await refreshList();
  if (selected !== null) await select(selected);
}

export function onEvent(event, kind) {
  if ((kind === "model" || kind === "dataset" || kind === "collection") && !$("page-models").hidden) refreshSoon();
}
