// Rig: device status, connect, home, go to slot; the live event log.

import { api, ApiError } from "../api.js";
import { showRigChip } from "../app.js";
import { $, el, fill, guarded, throttle, toast } from "../ui.js";

const MAX_LOG = 80;

function kv(dl, entries) {
  fill(dl, entries.flatMap(([k, v]) => [el("dt", {}, k), el("dd", {}, v)]));
}

async function refresh() {
  let status;
  try {
    status = await api("/rig");
  } catch (error) {
    const missing = error instanceof ApiError && error.status === 404;
    kv($("rig-summary"), [["status", missing ? "the server has no rig endpoint" : error.message]]);
    return;
  }
  showRigChip(status);
  kv($("rig-summary"), [
    ["hardware", status.hardware ?? "—"],
    ["connected", status.connected ? "yes" : "no"],
    ["state", status.state ?? "—"],
    ["held by", status.held_by ?? "free"],
  ]);
  fill($("rig-detail"), el("pre", {}, JSON.stringify(status.detail ?? {}, null, 2)));
}

const refreshSoon = throttle(refresh, 500);

async function rigAction(path, body, message) {
  await api(path, { method: "POST", body });
  toast(message, "ok");
  await refresh();
}

export function init() {
  $("rig-connect").addEventListener("click", (e) =>
    guarded(() => rigAction("/rig/connect", undefined, "Rig connected."), e.currentTarget),
  );
  $("rig-home").addEventListener("click", (e) =>
    guarded(() => rigAction("/rig/home", undefined, "Rig homed."), e.currentTarget),
  );
  $("rig-slot-form").addEventListener("submit", (e) => {
    e.preventDefault();
    const slot = Number($("rig-slot").value);
    guarded(() => rigAction("/rig/turntable", { slot }, `Turntable at slot ${slot}.`), e.submitter);
  });
}

export async function show() {
  await refresh();
}

export function onEvent(event, kind) {
  const log = $("event-log");
  const summary = JSON.stringify(event.data ?? {});
  log.prepend(
    el(
      "li",
      {},
      el("span", { class: "muted" }, `#${event.id ?? "?"} `),
      el("span", { class: "etype" }, event.type ?? "?"),
      summary.length > 160 ? `${summary.slice(0, 160)}…` : summary,
    ),
  );
  while (log.children.length > MAX_LOG) log.lastChild.remove();
  if (kind === "rig" && !$("page-rig").hidden) refreshSoon();
}
