// The contexts discovered so far, each with its top concepts P(c | χ) as bars coloured by kind.
import { contextColour, kindColour } from "./kinds.js";

function element(tag, className, text) {
  const node = document.createElement(tag);
  if (className) node.className = className;
  if (text !== undefined) node.textContent = text;
  return node;
}

export function renderContexts(container, listing) {
  const cards = listing.contexts.map((context) => {
    const card = element("div", "context");
    const title = element("h3", null, `χ${context.context}`);
    title.style.setProperty("--swatch", contextColour(context.context));
    title.append(element("small", "muted", ` ${context.scene_count} scene(s)`));
    card.append(title);
    const top = Math.max(...context.top_concepts.map((c) => c.probability), 1e-9);
    for (const concept of context.top_concepts) {
      const row = element("div", "bar");
      row.title = `${concept.name} (${concept.kind ?? "unknown kind"}): P(c | χ) = ${concept.probability.toFixed(3)}`;
      const fill = element("span", "fill");
      fill.style.width = `${(100 * concept.probability) / top}%`;
      fill.style.background = kindColour(concept.kind);
      row.append(element("span", "name", concept.name), element("span", "track"), element("span", "value", concept.probability.toFixed(2)));
      row.querySelector(".track").append(fill);
      card.append(row);
    }
    return card;
  });
  container.replaceChildren(...cards);
  container.dataset.count = String(listing.contexts.length);
  container.dataset.scenes = String(listing.scene_count);
}
