// The read-only dashboard: models; for one model its contexts (named by their labels), the posterior
// of recent scenes, K over time, the recent scenes (those whose stored answer cannot be read marked),
// the latest object's concept web and its three stages, and a plan.
// Live over the websocket; polling when it is down.
import "uplot/dist/uPlot.min.css";
import "./style.css";
import { ApiError, api, openStream, saveKey } from "./api.js";
import { ContextCountChart, PosteriorChart } from "./charts.js";
import { CooccurrenceCounter, renderConceptWeb } from "./conceptWeb.js";
import { contextName, contextNames, renderContexts } from "./contexts.js";
import { renderPlan } from "./planning.js";
import { renderSceneList } from "./sceneList.js";
import { renderStages } from "./stages.js";

const RECENT_SCENES = 200;
const SCENES_FOR_EDGES = 10;
const SCENES_LISTED = 12;
const POLL_MS = 3000;
const RECONNECT_MS = 10000;
const REFRESH_DEBOUNCE_MS = 800;
// Labels change without a scene (an operator's PATCH, no stream event): re-read that often anyway.
const LABELS_MS = 15000;
// ?transport=polling: for networks whose proxies drop websockets.
const POLLING_ONLY = new URLSearchParams(location.search).get("transport") === "polling";

const $ = (id) => document.getElementById(id);
const charts = {
  posterior: new PosteriorChart($("posterior-chart"), document.createElement("div")),
  contextCount: new ContextCountChart($("k-chart")),
};
$("posterior-chart").before(charts.posterior.legend);
charts.posterior.legend.className = "legend";

let session = null; // everything about the selected model; replaced when another model is chosen

const sameItems = (a, b) => b !== null && a.length === b.length && a.every((item, i) => item === b[i]);

function setConnection(mode) {
  const badge = $("connection");
  badge.dataset.mode = mode;
  badge.textContent = { live: "live (websocket)", polling: "polling", offline: "offline" }[mode];
}

function showMessage(text) {
  $("message").textContent = text;
}

function handleError(error) {
  if (error instanceof ApiError && (error.status === 401 || error.status === 403)) {
    $("key-form").hidden = false;
    showMessage("This service needs its read key: enter it above (or open /?key=…).");
  } else {
    showMessage(`Could not reach the service: ${error.message}`);
  }
  setConnection("offline");
}

async function loadModels() {
  const models = await api.models();
  const list = $("model-list");
  list.replaceChildren(
    ...models.map((model) => {
      const item = document.createElement("li");
      const link = document.createElement("a");
      link.href = `?model=${model.id}`;
      link.textContent = model.name;
      link.addEventListener("click", (event) => {
        event.preventDefault();
        history.replaceState(null, "", `?model=${model.id}`);
        select(model.id);
      });
      const facts = document.createElement("small");
      facts.className = "muted";
      facts.textContent = ` K=${model.context_count}, ${model.scene_count} scenes`;
      item.dataset.modelId = model.id;
      item.append(link, facts);
      return item;
    }),
  );
  return models;
}

function markSelected(modelId) {
  for (const item of $("model-list").children) item.classList.toggle("selected", item.dataset.modelId === modelId);
}

async function select(modelId) {
  session?.close();
  session = new ModelSession(modelId);
  markSelected(modelId);
  await session.start();
}

class ModelSession {
  constructor(modelId) {
    this.modelId = modelId;
    this.model = null;
    this.scenes = [];
    // Scene id → why its stored answer cannot be read back (the stream's scene_unreadable, or a 500
    // stored_data_damaged): listed in its place, never read again. A streamed one has no summary, so
    // it is not in this.scenes (nor in the charts); one met in the history is, with its summary.
    this.unreadable = new Map();
    this.counter = new CooccurrenceCounter();
    this.fittedEdges = null;
    this.latest = null;
    this.latestShown = null;
    this.listingShown = null;
    this.contextNames = [];
    this.plannedContext = undefined;
    this.lastPlan = null;
    this.socket = null;
    this.timers = new Set();
    this.refreshTimer = null;
    this.closed = false;
  }

  close() {
    this.closed = true;
    this.socket?.close();
    for (const timer of this.timers) clearTimeout(timer);
  }

  later(callback, ms) {
    const timer = setTimeout(() => {
      this.timers.delete(timer);
      if (!this.closed) callback();
    }, ms);
    this.timers.add(timer);
  }

  async start() {
    try {
      this.model = await api.model(this.modelId);
      $("model-title").textContent = `${this.model.name} (${this.model.id})`;
      await this.fetchFittedEdges();
      const offset = Math.max(0, this.model.scene_count - RECENT_SCENES);
      await this.fetchScenes(offset);
      await this.seedCooccurrence();
      await this.refresh();
      showMessage(this.scenes.length ? "" : "No scene learned yet: post scenes (e.g. `contextweb bridge simulate`).");
    } catch (error) {
      handleError(error);
      return;
    }
    this.connect();
    this.rereadLabels();
  }

  rereadLabels() {
    this.later(() => {
      this.scheduleRefresh();
      this.rereadLabels();
    }, LABELS_MS);
  }

  async fetchFittedEdges() {
    try {
      this.fittedEdges = (await api.conceptWeb(this.modelId)).edges;
    } catch (error) {
      if (!(error instanceof ApiError) || error.status >= 500 || error.status === 401) throw error;
      this.fittedEdges = null; // not fitted, or a service without the route: count co-occurrences here
    }
  }

  async fetchScenes(offset) {
    for (;;) {
      const page = await api.scenes(this.modelId, offset, 500);
      const known = new Set(this.scenes.map((s) => s.scene_id));
      this.scenes.push(...page.items.filter((s) => !known.has(s.scene_id)));
      offset += page.items.length;
      if (!page.items.length || offset >= page.total) break;
    }
    this.scenes = this.scenes.slice(-RECENT_SCENES);
    this.drawCharts();
  }

  async seedCooccurrence() {
    const recent = this.readableScenes().slice(-SCENES_FOR_EDGES);
    const answers = await Promise.all(recent.map((s) => this.readAnswer(s.scene_id)));
    for (const answer of answers) {
      if (answer) for (const object of answer.objects) this.counter.add(object.active_concepts);
    }
  }

  // A scene's stored answer, or null when the service says it is damaged: the scene is then marked
  // unreadable, as the stream's scene_unreadable would have (the history's summaries do not say).
  async readAnswer(sceneId) {
    try {
      return await api.scene(this.modelId, sceneId);
    } catch (error) {
      if (!(error instanceof ApiError) || error.error !== "stored_data_damaged") throw error;
      this.markUnreadable(sceneId, error.detail ?? error.message);
      return null;
    }
  }

  markUnreadable(sceneId, detail) {
    this.unreadable.set(sceneId, detail);
    if (this.unreadable.size > RECENT_SCENES) this.unreadable.delete(this.unreadable.keys().next().value);
    this.drawSceneList();
  }

  readableScenes() {
    return this.scenes.filter((s) => !this.unreadable.has(s.scene_id));
  }

  // The panels that read a scene's answer (concept web, stages, plan) show the newest readable one.
  latestReadable() {
    const readable = this.readableScenes();
    return readable[readable.length - 1];
  }

  // The id after the last scene seen, readable or not: where the history is read on from, so that a
  // scene announced unreadable is not asked for again.
  nextSceneId() {
    const last = this.scenes[this.scenes.length - 1];
    return Math.max(last ? last.scene_id + 1 : 0, ...[...this.unreadable.keys()].map((id) => id + 1));
  }

  drawCharts() {
    charts.posterior.render(this.scenes);
    charts.contextCount.render(this.scenes);
    this.drawSceneList();
  }

  drawSceneList() {
    renderSceneList($("scene-list"), $("scene-list-note"), {
      modelId: this.modelId,
      scenes: this.scenes,
      unreadable: this.unreadable,
      names: this.contextNames,
      shown: SCENES_LISTED,
    });
  }

  // Contexts, the latest object's web and the plan: re-read after scenes arrive (debounced).
  scheduleRefresh() {
    if (this.refreshTimer) return;
    this.refreshTimer = true;
    this.later(async () => {
      this.refreshTimer = null;
      try {
        await this.refresh();
      } catch (error) {
        handleError(error);
      }
    }, REFRESH_DEBOUNCE_MS);
  }

  // Panels are redrawn only when what they show changed: the periodic re-read would otherwise
  // reset a reader's scroll and tooltips every few seconds.
  async refresh() {
    const [listing] = await Promise.all([api.contexts(this.modelId), loadModels()]);
    markSelected(this.modelId);
    const listingShown = JSON.stringify(listing);
    if (listingShown !== this.listingShown) {
      this.listingShown = listingShown;
      this.contextNames = contextNames(listing);
      renderContexts($("contexts"), listing, $("relevance"));
      charts.posterior.setNames(this.contextNames);
      this.drawSceneList();
      if (this.lastPlan) renderPlan($("plan"), this.lastPlan, this.contextNames);
    }
    let last;
    for (;;) {
      last = this.latestReadable();
      if (!last) return;
      const latestShown = [last.scene_id, this.fittedEdges, ...this.contextNames];
      if (sameItems(latestShown, this.latestShown)) break;
      const answer = await this.readAnswer(last.scene_id);
      if (!answer) continue; // damaged (now marked): the scene before it is the latest readable one
      this.latest = answer;
      this.latestShown = latestShown;
      this.renderLatestObject();
      break;
    }
    if (this.plannedContext !== last.map_context) await this.plan();
  }

  // The latest scene's last object: its concept web, and its P(c) at the three stages.
  renderLatestObject() {
    const scene = this.latest;
    const index = scene.objects.length - 1;
    const object = scene.objects[index];
    const vocabulary = this.model.vocabulary;
    renderConceptWeb($("concept-web"), { vocabulary, object, edges: this.fittedEdges ?? this.counter.edges() });
    const context = contextName(this.contextNames, scene.map_context);
    const where =
      `Scene ${scene.scene_id} in ${context} (P(χ | scene) = ${scene.context_posterior[scene.map_context].toFixed(2)}), ` +
      `object ${index + 1} of ${scene.objects.length} (${object.level} level)`;
    $("web-caption").textContent =
      `${where}; edges: ${this.fittedEdges ? "co-occurrence in training" : "co-occurrence in the scenes seen here"}.`;
    $("stages-scene").textContent = `${where}.`;
    $("stages-scene").dataset.context = String(scene.map_context);
    renderStages($("stages"), $("stages-nouns"), { object, vocabulary, sceneId: scene.scene_id, objectIndex: index });
  }

  async plan() {
    const form = new FormData($("plan-form"));
    const last = this.latestReadable();
    const request = { object: form.get("object"), start: Number(form.get("start")), goal: Number(form.get("goal")), mode: "paper" };
    if (last) request.scene_id = last.scene_id;
    try {
      const plan = await api.plan(this.modelId, request);
      this.plannedContext = last?.map_context;
      this.lastPlan = plan;
      renderPlan($("plan"), plan, this.contextNames);
    } catch (error) {
      if (!(error instanceof ApiError) || error.status === 401) throw error;
      this.plannedContext = last?.map_context;
      this.lastPlan = null;
      $("plan").textContent = `No plan: ${error.message}`;
    }
  }

  onEvent(event) {
    if (event.type === "hello") {
      if (event.scene_count > this.nextSceneId()) this.catchUp();
    } else if (event.type === "scene") {
      if (this.scenes.some((s) => s.scene_id === event.scene_id)) return;
      this.scenes.push(event);
      this.scenes = this.scenes.slice(-RECENT_SCENES);
      for (const concepts of event.active_concepts) this.counter.add(concepts);
      this.drawCharts();
      this.scheduleRefresh();
    } else if (event.type === "scene_unreadable") {
      // A learned scene whose stored answer was damaged: listed in its place; the charts and the
      // panels keep the last readable scene, and the contexts (which it changed) are read again.
      if (this.unreadable.has(event.scene_id)) return;
      this.markUnreadable(event.scene_id, event.detail);
      this.scheduleRefresh();
    } else if (event.type === "context_discovered") {
      showMessage(`A new context was discovered at scene ${event.scene_id}: K = ${event.context_count}.`);
    } else if (event.type === "model_fitted") {
      this.fetchFittedEdges().then(() => this.scheduleRefresh(), handleError);
    }
  }

  async catchUp() {
    try {
      await this.fetchScenes(this.nextSceneId());
      this.scheduleRefresh();
    } catch (error) {
      handleError(error);
    }
  }

  connect() {
    if (this.closed) return;
    if (POLLING_ONLY) {
      setConnection("polling");
      this.later(() => this.poll(), POLL_MS);
      return;
    }
    const socket = openStream(this.modelId);
    this.socket = socket;
    socket.addEventListener("open", () => {
      $("connection").dataset.protocol = socket.protocol;
      setConnection("live");
    });
    socket.addEventListener("message", (message) => this.onEvent(JSON.parse(message.data)));
    socket.addEventListener("close", () => {
      if (this.closed || this.socket !== socket) return;
      this.socket = null;
      setConnection("polling");
      this.poll();
      this.later(() => this.connect(), RECONNECT_MS);
    });
  }

  // The fallback while the websocket is down: read the model's scene count and fetch what is new.
  async poll() {
    if (this.closed || this.socket?.readyState === WebSocket.OPEN) return;
    try {
      await this.catchUp();
      setConnection(this.socket?.readyState === WebSocket.OPEN ? "live" : "polling");
    } catch (error) {
      handleError(error);
    }
    this.later(() => this.poll(), POLL_MS);
  }
}

$("key-form").addEventListener("submit", (event) => {
  event.preventDefault();
  saveKey($("key-input").value);
  $("key-form").hidden = true;
  main();
});

$("plan-form").addEventListener("submit", (event) => {
  event.preventDefault();
  session?.plan().catch(handleError);
});

async function main() {
  try {
    const models = await loadModels();
    if (!models.length) {
      showMessage("No model yet: create one with the bridge client or `contextweb bridge simulate`.");
      setConnection("polling");
      setTimeout(main, POLL_MS);
      return;
    }
    const wanted = new URLSearchParams(location.search).get("model");
    const chosen = models.find((m) => m.id === wanted) ?? models.reduce((a, b) => (b.scene_count > a.scene_count ? b : a));
    await select(chosen.id);
  } catch (error) {
    handleError(error);
  }
}

main();
