// The dashboard shell: pages by URL hash, status chips, the e-stop, sign-in/out, live events.

import { api, ApiError, onUnauthorized, sessionStatus, signIn, signOut } from "./api.js";
import { connectEvents, disconnectEvents, eventKind, onEvent, onStreamStatus } from "./events.js";
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
let booted = false;
let auth = null; // GET /session: {authenticated, method, auth_required, reads_need_auth}

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
    if (health.status !== "ok") {
      // Off loopback without a session the server only says that auth is required.
      chip("chip-server", "server: sign-in needed", "warn");
      return health;
    }
    chip("chip-server", `server ok · ${health.hardware || "?"}`, "ok");
    if (health.auth_required && !(auth && auth.authenticated)) {
      chip("chip-server", "server ok · sign in for changes", "warn");
    }
    return health;
  } catch (error) {
    chip("chip-server", error instanceof ApiError && error.status === 401 ? "server: sign-in needed" : "server unreachable", "warn");
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

function showAuthButtons() {
  const signedIn = Boolean(auth && auth.method === "session");
  $("signin-button").hidden = !(auth && auth.auth_required && !auth.authenticated);
  $("signout-button").hidden = !signedIn;
}

/** Show the sign-in form. Off loopback it cannot be dismissed: nothing is readable without it. */
function askToSignIn(message = "") {
  const dialog = $("signin-dialog");
  const required = !auth || auth.reads_need_auth;
  $("signin-cancel").hidden = required;
  $("signin-error").textContent = message;
  $("signin-error").hidden = !message;
  // Once the dashboard runs (a session ended mid-work) the form is not modal: the E-STOP
  // button stays reachable (it answers 401 without a session; use the hardware stop then).
  if (!dialog.open) {
    if (booted) dialog.show();
    else dialog.showModal();
  }
  $("signin-token").focus();
}

async function submitSignIn(event) {
  event.preventDefault();
  const input = $("signin-token");
  const button = $("signin-submit");
  button.disabled = true;
  try {
    await signIn(input.value.trim());
    input.value = "";
    $("signin-dialog").close("signed-in");
    await afterSignIn();
    toast("Signed in.", "ok");
  } catch (error) {
    const refused = error instanceof ApiError && error.status === 401;
    // 429: too many wrong tokens from this address; the server's message says when to retry.
    const waiting = error instanceof ApiError && error.status === 429 && error.body && error.body.detail;
    $("signin-error").textContent = refused ? "That is not this server's API token." : waiting || error.message;
    $("signin-error").hidden = false;
    input.select();
  } finally {
    button.disabled = false;
  }
}

async function afterSignIn() {
  auth = await sessionStatus();
  showAuthButtons();
  if (!booted) boot();
  else {
    connectEvents();
    checkHealth();
    refreshRigChip();
    showPage();
  }
}

async function doSignOut() {
  try {
    await signOut();
  } catch (error) {
    if (!(error instanceof ApiError && error.status === 401)) {
      toast(`Sign-out failed: ${error.message}`, "error");
      return;
    }
  }
  disconnectEvents();
  // A fresh page: nothing read while signed in stays on screen.
  location.reload();
}

function setUpSignIn() {
  const dialog = $("signin-dialog");
  $("signin-form").addEventListener("submit", submitSignIn);
  $("signin-cancel").addEventListener("click", () => dialog.close("cancel"));
  dialog.addEventListener("cancel", (event) => {
    if (!auth || auth.reads_need_auth) event.preventDefault(); // Escape cannot skip it
  });
  $("signin-button").addEventListener("click", () => askToSignIn());
  $("signout-button").addEventListener("click", doSignOut);
  onUnauthorized(() => {
    const hadSession = Boolean(auth && auth.authenticated);
    if (auth) auth = { ...auth, authenticated: false, method: null };
    showAuthButtons();
    askToSignIn(hadSession ? "Your session has ended: sign in again." : "This needs the API token: sign in.");
  });
}

/**
 * A login link may carry the token in the fragment (`#token=...`, which browsers never send to
 * the server): sign in with it once, then drop it from the address.
 */
async function signInFromUrl() {
  const hash = new URLSearchParams(location.hash.replace(/^#/, "").replace(/^[a-z]*\?/, ""));
  const token = hash.get("token");
  if (!token) return;
  window.history.replaceState(null, "", `${location.pathname}${location.search}#trials`); // `history` is the page module
  try {
    await signIn(token);
  } catch (error) {
    toast(`The login link's token was refused: ${error.message}`, "error");
  }
}

/** Start the pages and the live stream (once signed in, when the server asks for it). */
function boot() {
  booted = true;
  for (const page of Object.values(pages)) page.init();
  window.addEventListener("hashchange", showPage);
  connectEvents();
  checkHealth();
  refreshRigChip();
  setInterval(refreshRigChip, 5000);
  setInterval(checkHealth, 15000);
  showPage();
}

async function start() {
  $("estop").addEventListener("click", emergencyStop);
  setUpSignIn();
  onStreamStatus((status) => {
    if (status === "open") chip("chip-events", "live", "ok");
    else if (status === "closed") chip("chip-events", "not connected", "warn");
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
  await signInFromUrl();
  try {
    auth = await sessionStatus();
  } catch (error) {
    // Unreachable (or an error): start anyway; the chips say what is wrong.
    auth = { authenticated: false, method: null, auth_required: false, reads_need_auth: false };
  }
  showAuthButtons();
  if (auth === null) {
    chip("chip-server", "server: sign-in needed", "warn");
    askToSignIn();
    return; // boot() runs after the sign-in
  }
  boot();
}

export function currentPage() {
  return current;
}

start();
