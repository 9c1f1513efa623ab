// The dashboard shell: pages by URL hash, status chips, the e-stop, the API token, live events.

import { api, ApiError, getToken, setToken } from "./api.js";
import { connectEvents, eventKind, onEvent, onStreamStatus } from "./events.js";
import * as store from "./store.js";
import { $, el, toast } from "./ui.js";
import * as rig from "./pages/rig.js";
import * as objects from "./pages/objects.js";
import * as collection from "./pages/collection.js";
import * as models from "./pages/models.js";
import * as trials from "./pages/trials.js";
import * as history from "./pages/history.js";
import * as evaluation from "./pages/evaluation.js";

const pages = { rig, objects, collection, models, trials, history, evaluation };
let current = null;

function chip(id, text, kind) {
  const node = $(id);
  node.textContent = text;
  node.className = `chip ${kind || ""}`;
}

async function showPage() {
  const name = (location.hash || "#trials").slice(1).split("?")[0];
  const page = pages[name] ? name : "trials";
  for (const key of Object.keys(pages)) {
    $(`page-${key}`).hidden = key !== page;
    const link = document.querySelector(`.tabs a[data-page="${key}"]`);
    if (key === page) link.setAttribute("aria-current", "page");
    else link.removeAttribute("aria-current");
  }
  current = page;
  document.title = `ActiveTouch — ${page[0].toUpperCase()}${page.slice(1)}`;
  try {
    await pages[page].show();
  } catch (error) {
    console.error(error);
    toast(error.message || String(error), "error");
  }
}

async function checkHealth() {
  try {
    const health = await api("/health");
    chip("chip-server", `server ok · ${health.hardware || "?"}`, "ok");
    $("token-button").hidden = !health.auth_required;
    if (health.auth_required && !getToken()) chip("chip-server", "server: token needed", "warn");
    return health;
  } catch (error) {
    chip("chip-server", "server unreachable", "bad");
    return null;
  }
}

export function showRigChip(status) {
  if (!status) return chip("chip-rig", "rig ?", "");
  const state = status.state || (status.connected ? "connected" : "disconnected");
  let kind = status.connected ? "ok" : "warn";
  if (/estop|alarm|fault|error/i.test(state)) kind = "bad";
  chip("chip-rig", `rig ${state}${status.held_by ? ` · ${status.held_by}` : ""}`, kind);
}

async function refreshRigChip() {
  try {
    showRigChip(await api("/rig"));
  } catch (error) {
    if (error instanceof ApiError && error.status === 404) chip("chip-rig", "rig: no endpoint", "");
    else chip("chip-rig", "rig ?", "warn");
  }
}

async function emergencyStop() {
  const button = $("estop");
  button.disabled = true;
  try {
    const status = await api("/rig/estop", { method: "POST" });
    toast("Emergency stop sent: the rig is halted.", "ok");
    if (status && typeof status === "object") showRigChip(status);
  } catch (error) {
    toast(`E-STOP FAILED — ${error.message}. Use the hardware stop.`, "error");
  } finally {
    button.disabled = false;
  }
}

function setUpToken() {
  const dialog = $("token-dialog");
  $("token-button").addEventListener("click", () => {
    $("token-input").value = getToken();
    dialog.showModal();
  });
  dialog.addEventListener("close", () => {
    if (dialog.returnValue === "save") {
      setToken($("token-input").value.trim());
      checkHealth();
    }
  });
}

/** A login link may carry the token (`#token=...` or `?token=...`): keep it for this tab. */
function takeTokenFromUrl() {
  const hash = new URLSearchParams(location.hash.replace(/^#/, "").replace(/^[a-z]*\?/, ""));
  const query = new URLSearchParams(location.search);
  const token = hash.get("token") || query.get("token");
  if (!token) return;
  setToken(token);
  query.delete("token");
  const search = query.toString();
  history.replaceState(null, "", `${location.pathname}${search ? `?${search}` : ""}#trials`);
}

function start() {
  takeTokenFromUrl();
  $("estop").addEventListener("click", emergencyStop);
  setUpToken();
  for (const page of Object.values(pages)) page.init();
  window.addEventListener("hashchange", showPage);
  onStreamStatus((status) => {
    if (status === "open") chip("chip-events", "live", "ok");
    else chip("chip-events", "reconnecting…", "warn");
  });
  onEvent((event) => {
    const kind = eventKind(event);
    store.invalidate(kind);
    if (kind === "rig" || /status/.test(event.type || "")) refreshRigChip();
    for (const page of Object.values(pages)) {
      if (page.onEvent) page.onEvent(event, kind);
    }
  });
  connectEvents();
  checkHealth();
  refreshRigChip();
  setInterval(refreshRigChip, 5000);
  setInterval(checkHealth, 15000);
  showPage();
}

export function currentPage() {
  return current;
}

start();
