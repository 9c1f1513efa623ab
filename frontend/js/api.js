// The dashboard's only way to the server: /api/v1 (REST, JSON) and /api/v1/events (SSE).

export const API = "api/v1";

const TOKEN_KEY = "activetouch.token";

/** The API token kept for this tab (needed only when the server binds a non-loopback address). */
export function getToken() {
  return sessionStorage.getItem(TOKEN_KEY) || "";
}

export function setToken(token) {
  if (token) sessionStorage.setItem(TOKEN_KEY, token);
  else sessionStorage.removeItem(TOKEN_KEY);
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
  const init = { method, headers: { Accept: "application/json", ...headers }, signal };
  const token = getToken();
  if (token) init.headers.Authorization = `Bearer ${token}`;
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
  if (!response.ok) throw new ApiError(response.status, payload, `${method} ${path}`);
  return payload;
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
