// The recent scenes, newest first, each in its place in the learning order: its context and
// P(χ | scene), or, for a scene whose stored answer cannot be read back (the stream's
// scene_unreadable, or a 500 stored_data_damaged), a marker with the service's reason.
import { contextName } from "./contexts.js";
import { element } from "./dom.js";
import { contextColour } from "./kinds.js";

function sceneItem(scene, names) {
  const p = scene.context_posterior[scene.map_context];
  const item = element(
    "li",
    "scene",
    `scene ${scene.scene_id}: ${contextName(names, scene.map_context)}, P(χ | scene) = ${p.toFixed(2)}`,
  );
  item.style.setProperty("--swatch", contextColour(scene.map_context));
  return item;
}

function unreadableItem(sceneId, detail) {
  const item = element("li", "scene unreadable", `scene ${sceneId}: stored answer unreadable — ${detail}`);
  item.title = "Learned, but its stored answer was damaged in the database: the panels show the last readable scene.";
  return item;
}

// `scenes` (summaries or scene events) and `unreadable` (scene id → reason) together, the last `shown` ids.
export function renderSceneList(list, note, { modelId, scenes, unreadable, names, shown }) {
  const byId = new Map(scenes.map((scene) => [scene.scene_id, scene]));
  const ids = [...new Set([...byId.keys(), ...unreadable.keys()])].sort((a, b) => b - a).slice(0, shown);
  list.replaceChildren(
    ...ids.map((sceneId) => {
      const item = unreadable.has(sceneId)
        ? unreadableItem(sceneId, unreadable.get(sceneId))
        : sceneItem(byId.get(sceneId), names);
      item.dataset.scene = String(sceneId);
      return item;
    }),
  );
  list.dataset.count = String(ids.length);
  list.dataset.unreadable = String(unreadable.size);
  note.textContent = unreadable.size
    ? `newest first; ${unreadable.size} stored answer(s) unreadable: \`contextweb models check ${modelId}\` names them`
    : "newest first";
}
