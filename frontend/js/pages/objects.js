// Objects: names, turntable slots, notes, known properties (GET /objects), with the datasets
// each object appears in. Without an /objects endpoint the names come from the datasets.

import { apiList, ApiError } from "../api.js";
import * as store from "../store.js";
import { $, el, fill } from "../ui.js";

function properties(props) {
  const entries = Object.entries(props || {});
  if (!entries.length) return el("span", { class: "muted" }, "—");
  return el(
    "dl",
    { class: "kv" },
    entries.flatMap(([k, v]) => [el("dt", {}, k), el("dd", {}, typeof v === "object" ? JSON.stringify(v) : String(v))]),
  );
}

export function init() {}

export async function show() {
  const datasets = await store.datasets(true);
  const inDatasets = new Map();
  for (const d of datasets) {
    for (const name of d.objects || []) {
      if (!inDatasets.has(name)) inDatasets.set(name, []);
      inDatasets.get(name).push(`#${d.id}`);
    }
  }
  let objects;
  try {
    objects = await apiList("/objects");
    $("objects-source").textContent = `${objects.length} objects registered.`;
  } catch (error) {
    if (!(error instanceof ApiError && error.status === 404)) throw error;
    objects = [...inDatasets.keys()].map((name) => ({ name }));
    $("objects-source").textContent = "Objects named in the datasets (the server lists no registry).";
  }
  fill(
    $("objects-body"),
    objects.map((o) =>
      el(
        "tr",
        { "data-testid": "object-row" },
        el("td", {}, el("strong", {}, o.name)),
        el("td", {}, o.slot ?? "—"),
        el("td", {}, o.notes || "—"),
        el("td", {}, properties(o.properties)),
        el("td", {}, (inDatasets.get(o.name) || []).join(", ") || "—"),
      ),
    ),
  );
}

export function onEvent() {}
