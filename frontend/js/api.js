// The dashboard's only way to the server: /api/v1 (REST, JSON) and /api/v1/events (SSE).
//
// Authentication is a server-side session in an HttpOnly, SameSite=Strict cookie set by
// POST /api/v1/session (the sign-in): the page never keeps the token, and no URL carries it.
// Every call sends `X-Requested-With: activetouch`, the server's CSRF check for changes made
// with the cookie.

export const API = "api/v1";

const CSRF_HEADER = { "X-Requested-With": "activetouch" };
const unauthorizedListeners = new Set();

/** Call `fn(error)` when the server answers 401 (not signed in, or the session expired). */
export function onUnauthorized(fn) {
  unauthorizedListeners.add(fn);
  return () => unauthorizedListeners.delete(fn);
}

/** An HTTP error with the server's `detail` (and extra keys such as `current_state`). */
export class ApiError extends Error {
  constructor(status, body, path) {
    super(ApiError.describe(status, body, path));
    this.status = status;
    this.body = body;
    this.path = path;
  }

  static describe(status, body, path) {
    let detail = body && body.detail !== undefined ? body.detail : body;
    if (Array.isArray(detail)) {
      detail = detail.map((e) => `${(e.loc || []).join(".")}: ${e.msg}`).join("; ");
    } else if (detail && typeof detail === "object") {
      detail = JSON.stringify(detail);
    }
    const extra = body && body.current_state ? ` (current state: ${body.current_state})` : "";
    return `${status} on ${path}: ${detail || "no detail"}${extra}`;
  }
}

/**
 * Call the API. `body` is sent as JSON unless it is FormData, a Blob or a string.
 * @returns the parsed JSON (or text for non-JSON answers)
 */
export async function api(path, { method = "GET", body, headers = {}, signal } = {}) {
  const init = {
    method,
    headers: { Accept: "application/json", ...CSRF_HEADER, ...headers },
    credentials: "same-origin",
    signal,
  };
  if (body !== undefined) {
    if (body instanceof FormData || body instanceof Blob || typeof body === "string") {
      init.body = body;
    } else {
      init.body = JSON.stringify(body);
      init.headers["Content-Type"] = "application/json";
    }
  }
  const url = `${API}${path}`;
  const response = await fetch(url, init);
  const type = response.headers.get("content-type") || "";
  const payload = type.includes("json") ? await response.json().catch(() => null) : await response.text();
  if (!response.ok) {
    const error = new ApiError(response.status, payload, `${method} ${path}`);
    if (response.status === 401 && path !== "/session") {
      for (const fn of unauthorizedListeners) fn(error);
    }
    throw error;
  }
  return payload;
}

/** How this page is authenticated: {authenticated, method, auth_required, reads_need_auth};
 * null when the server wants a sign-in before it says anything (off loopback). */
export async function sessionStatus() {
  try {
    return await api("/session");
  } catch (error) {
    if (error instanceof ApiError && error.status === 401) return null;
    throw error;
  }
}

/** Sign in with the API token: the server sets the session cookie (the token is not kept). */
export function signIn(token) {
  return api("/session", { method: "POST", body: { token } });
}

/** Sign out: the server ends the session and deletes the cookie. */
export function signOut() {
  return api("/session", { method: "DELETE" });
}

/** GET that answers null on 404 (an endpoint or record that does not exist). */
export async function apiOptional(path) {
  try {
    return await api(path);
  } catch (error) {
    if (error instanceof ApiError && (error.status === 404 || error.status === 405)) return null;
    throw error;
  }
}

/** `{data, count}` pages: every row (up to `max`), following offsets. */
export async function apiList(path, { max = 1000, pageSize = 200 } = {}) {
  const rows = [];
  const sep = path.includes("?") ? "&" : "?";
  for (let offset = 0; offset < max; offset += pageSize) {
    const page = await api(`${path}${sep}limit=${pageSize}&offset=${offset}`);
    const data = Array.isArray(page) ? page : page.data || [];
    rows.push(...data);
    const count = Array.isArray(page) ? data.length : page.count;
    if (data.length < pageSize || rows.length >= count) break;
  }
  return rows;
}

/** Trigger a browser download of `text`. */
export function download(filename, text, type = "text/plain") {
  const url = URL.createObjectURL(new Blob([text], { type }));
  const link = document.createElement("a");
  link.href = url;
  link.download = filename;
  document.body.appendChild(link);
  link.click();
  link.remove();
  setTimeout(() => URL.revokeObjectURL(url), 1000);
}
