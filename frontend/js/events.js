// Live events: one EventSource on /api/v1/events. Browsers resend Last-Event-ID when they
// reconnect, so no event is missed. Each message's data is {"id", "type", "time", "data"}.

import { API } from "./api.js";

const listeners = new Set();
const statusListeners = new Set();
let source = null;

/** Call `fn(event)` for every event ({id, type, time, data}); returns an unsubscribe function. */
export function onEvent(fn) {
  listeners.add(fn);
  return () => listeners.delete(fn);
}

/** Call `fn("open" | "error" | "closed")` when the stream connects, drops (the browser
 * reconnects by itself) or is closed for good (refused, e.g. 401 after a sign-out). */
export function onStreamStatus(fn) {
  statusListeners.add(fn);
}

function dispatch(raw, fallbackType) {
  let event;
  try {
    event = JSON.parse(raw.data);
  } catch {
    return;
  }
  if (!event || typeof event !== "object") return;
  if (event.type === undefined) event = { id: raw.lastEventId, type: fallbackType, data: event };
  for (const fn of listeners) {
    try {
      fn(event);
    } catch (error) {
      console.error("event listener failed", error);
    }
  }
}

/** Open the stream (once; again after `disconnectEvents` or a refusal). The session cookie
 * authenticates it: no token in the URL. */
export function connectEvents() {
  if (source && source.readyState !== EventSource.CLOSED) return;
  source = new EventSource(`${API}/events`, { withCredentials: true });
  const opened = source;
  source.onopen = () => statusListeners.forEach((fn) => fn("open"));
  source.onerror = () => {
    const state = opened.readyState === EventSource.CLOSED ? "closed" : "error";
    statusListeners.forEach((fn) => fn(state));
  };
  source.onmessage = (raw) => dispatch(raw, "message");
  // Named events (if the server sets `event:`) are delivered too.
  for (const type of ["trial", "model", "collection", "rig", "dataset", "run"]) {
    source.addEventListener(type, (raw) => dispatch(raw, type));
  }
}

/** Close the stream (at sign-out). */
export function disconnectEvents() {
  if (!source) return;
  source.close();
  source = null;
  statusListeners.forEach((fn) => fn("closed"));
}

/** Whether an event concerns a kind of record: "trial", "model", "collection", "rig", ... */
export function eventKind(event) {
  return String(event.type || "").split(/[./:]/)[0];
}

/** The id of the record an event is about (e.g. data.trial_id), if any. */
export function eventRecordId(event, kind) {
  const data = event.data || {};
  return data[`${kind}_id`] ?? data.run_id ?? data.id ?? null;
}
