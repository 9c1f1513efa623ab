// Small DOM helpers shared by the pages.

import { num } from "./lib/format.js";

/** Create an element: el("td", {class: "x", dataset: {id: 1}}, "text", child, ...). */
export function el(tag, attrs = {}, ...children) {
  const node = document.createElement(tag);
  for (const [key, value] of Object.entries(attrs || {})) {
    if (value === undefined || value === null || value === false) continue;
    if (key === "class") node.className = value;
    else if (key === "dataset") Object.assign(node.dataset, value);
    else if (key.startsWith("on") && typeof value === "function") node.addEventListener(key.slice(2), value);
    else if (key === "text") node.textContent = value;
    else node.setAttribute(key, value === true ? "" : value);
  }
  for (const child of children.flat()) {
    if (child === null || child === undefined || child === false) continue;
    node.append(child instanceof Node ? child : document.createTextNode(String(child)));
  }
  return node;
}

export function $(id) {
  return document.getElementById(id);
}

/** Replace the children of `node`. */
export function fill(node, ...children) {
  node.replaceChildren(...children.flat().filter((c) => c !== null && c !== undefined));
}

/** A number with `digits` significant digits, or "—" (lib/format.js, shared with the pure helpers). */
export { num };

/** A vector as "[a, b, c]" with `digits` significant digits. */
export function vec(values, digits = 3) {
  if (!Array.isArray(values)) return "—";
  return `[${values.map((v) => num(v, digits)).join(", ")}]`;
}

export function badge(status, testid) {
  return el("span", { class: `badge ${status}`, "data-testid": testid }, status);
}

export function timeOf(iso) {
  if (!iso) return "—";
  const date = new Date(iso);
  if (Number.isNaN(date.getTime())) return iso;
  return date.toLocaleString([], { dateStyle: "short", timeStyle: "medium" });
}

/** A passing message at the bottom right; errors stay longer. */
export function toast(message, kind = "info") {
  const node = el("div", { class: `toast ${kind}` }, message);
  $("toasts").append(node);
  setTimeout(() => node.remove(), kind === "error" ? 9000 : 4000);
}

/** Run an async UI action; show its error as a toast; disable `button` meanwhile. */
export async function guarded(action, button) {
  if (button) button.disabled = true;
  try {
    return await action();
  } catch (error) {
    console.error(error);
    toast(error.message || String(error), "error");
    return undefined;
  } finally {
    if (button) button.disabled = false;
  }
}

/** Values of a form as an object (empty strings dropped). */
export function formValues(form) {
  const out = {};
  for (const [key, value] of new FormData(form).entries()) {
    if (value !== "") out[key] = value;
  }
  return out;
}

/** Select options from [{value, label}], keeping the current choice when still offered. */
export function setOptions(select, options, { keep = true, placeholder = null } = {}) {
  const current = select.value;
  const nodes = options.map((o) => el("option", { value: o.value }, o.label));
  if (placeholder !== null) nodes.unshift(el("option", { value: "" }, placeholder));
  select.replaceChildren(...nodes);
  if (keep && options.some((o) => String(o.value) === current)) select.value = current;
}

/** Calls `fn` at most once per `waitMs`, and once more after the last call. */
export function throttle(fn, waitMs) {
  let timer = null;
  let pending = false;
  let running = false;
  const run = async () => {
    if (running) {
      pending = true;
      return;
    }
    running = true;
    try {
      await fn();
    } finally {
      running = false;
      timer = setTimeout(() => {
        timer = null;
        if (pending) {
          pending = false;
          run();
        }
      }, waitMs);
    }
  };
  return () => {
    if (timer || running) pending = true;
    else run();
  };
}
