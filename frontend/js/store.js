// Records several pages share (models, datasets), cached and refreshed on events.

import { api, apiList } from "./api.js";

const cache = { models: null, datasets: null };
const details = new Map();

export async function models(refresh = false) {
  if (refresh || !cache.models) cache.models = await apiList("/models");
  return cache.models;
}

export async function datasets(refresh = false) {
  if (refresh || !cache.datasets) cache.datasets = await apiList("/datasets");
  return cache.datasets;
}

/** GET /models/{id}, cached once the model is ready (a ready model never changes). */
export async function model(id) {
  const key = String(id);
  if (details.has(key)) return details.get(key);
  const record = await api(`/models/${id}`);
  if (record.status === "ready") details.set(key, record);
  return record;
}

export function invalidate(kind) {
  if (kind === "model") cache.models = null;
  if (kind === "dataset" || kind === "collection") cache.datasets = null;
}
