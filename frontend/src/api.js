// The service's REST routes and stream, with the read key from ?key= (kept for the tab's session).

const KEY_STORAGE = "contextweb.key";

export class ApiError extends Error {
  constructor(status, body) {
    super(`${status} ${body.error ?? "error"}: ${body.detail ?? ""}`);
    this.status = status;
    this.error = body.error;
  }
}

export function readKey() {
  const fromUrl = new URLSearchParams(location.search).get("key");
  if (fromUrl) sessionStorage.setItem(KEY_STORAGE, fromUrl);
  return sessionStorage.getItem(KEY_STORAGE);
}

export function saveKey(key) {
  sessionStorage.setItem(KEY_STORAGE, key);
}

async function call(method, path, body) {
  const headers = { Accept: "application/json" };
  const key = readKey();
  if (key) headers["X-API-Key"] = key;
  if (body !== undefined) headers["Content-Type"] = "application/json";
  const response = await fetch(path, { method, headers, body: body === undefined ? undefined : JSON.stringify(body) });
  const payload = response.status === 204 ? null : await response.json().catch(() => ({}));
  if (!response.ok) throw new ApiError(response.status, payload ?? {});
  return payload;
}

export const api = {
  models: () => call("GET", "/v1/models"),
  model: (id) => call("GET", `/v1/models/${id}`),
  contexts: (id, top = 10) => call("GET", `/v1/models/${id}/contexts?top=${top}`),
  scenes: (id, offset, limit) => call("GET", `/v1/models/${id}/scenes?offset=${offset}&limit=${limit}`),
  scene: (id, sceneId) => call("GET", `/v1/models/${id}/scenes/${sceneId}`),
  conceptWeb: (id) => call("GET", `/v1/models/${id}/concept-web`),
  plan: (id, request) => call("POST", `/v1/models/${id}/plans`, request),
};

export function streamUrl(modelId) {
  const scheme = location.protocol === "https:" ? "wss" : "ws";
  const key = readKey();
  const query = key ? `?api_key=${encodeURIComponent(key)}` : "";
  return `${scheme}://${location.host}/v1/models/${modelId}/stream${query}`;
}
