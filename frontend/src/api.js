// The service's REST routes and stream, with the read key from ?key= (kept for the tab's session).

const KEY_STORAGE = "contextweb.key";

export class ApiError extends Error {
  constructor(status, body) {
    super(`${status} ${body.error ?? "error"}: ${body.detail ?? ""}`);
    this.status = status;
    this.error = body.error;
    this.detail = body.detail;
  }
}

// A key given in the page's URL is kept for the tab's session and taken out of the address bar.
export function readKey() {
  const params = new URLSearchParams(location.search);
  const fromUrl = params.get("key");
  if (fromUrl) {
    sessionStorage.setItem(KEY_STORAGE, fromUrl);
    params.delete("key");
    const query = params.toString();
    history.replaceState(null, "", `${location.pathname}${query ? `?${query}` : ""}${location.hash}`);
  }
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
  contexts: (id, top = 8) => call("GET", `/v1/models/${id}/contexts?top=${top}`),
  scenes: (id, offset, limit) => call("GET", `/v1/models/${id}/scenes?offset=${offset}&limit=${limit}`),
  scene: (id, sceneId) => call("GET", `/v1/models/${id}/scenes/${sceneId}`),
  conceptWeb: (id) => call("GET", `/v1/models/${id}/concept-web`),
  plan: (id, request) => call("POST", `/v1/models/${id}/plans`, request),
};

// The key travels in a subprotocol ("key.<key>", beside "contextweb", which the server answers
// with): a key in the URL would end up in proxies' logs and the browser's history. A key that is
// not a valid subprotocol token (RFC 6455 §4.1) falls back to the legacy ?api_key= query.
const TOKEN = /^[!#$%&'*+\-.^_`|~0-9A-Za-z]+$/;

export function openStream(modelId) {
  const scheme = location.protocol === "https:" ? "wss" : "ws";
  const url = `${scheme}://${location.host}/v1/models/${modelId}/stream`;
  const key = readKey();
  if (!key) return new WebSocket(url);
  if (TOKEN.test(key)) return new WebSocket(url, ["contextweb", `key.${key}`]);
  return new WebSocket(`${url}?api_key=${encodeURIComponent(key)}`);
}
