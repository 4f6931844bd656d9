// The contexts discovered so far: each under its operator's label, listed by its distinctive concepts
// (LDAvis relevance) with P(c | χ) as bars coloured by kind; the most probable concepts, which every
// context shares, on a small line below.
import { element } from "./dom.js";
import { contextColour, kindColour } from "./kinds.js";

const TOP_CONCEPTS_SHOWN = 5;

// How the dashboard names context k everywhere: its label, else "context k".
export function contextName(names, k) {
  return names[k] ?? `context ${k}`;
}

export function contextNames(listing) {
  return listing.contexts.map((context) => context.label ?? `context ${context.context}`);
}

function conceptBar(concept, largest) {
  const row = element("div", "bar");
  row.dataset.concept = concept.name;
  row.title =
    `${concept.name} (${concept.kind ?? "unknown kind"}): P(c | χ) = ${concept.probability.toFixed(3)}, ` +
    `relevance ${concept.relevance.toFixed(2)}`;
  const track = element("span", "track");
  const fill = element("span", "fill");
  fill.style.width = `${(100 * concept.probability) / largest}%`;
  fill.style.background = kindColour(concept.kind);
  track.append(fill);
  row.append(element("span", "name", concept.name), track, element("span", "value", concept.probability.toFixed(3)));
  return row;
}

export function renderContexts(container, listing, note) {
  note.textContent = `distinctive concepts (relevance, λ = ${listing.relevance_weight}) with P(c | χ)`;
  const names = contextNames(listing);
  const cards = listing.contexts.map((context) => {
    const card = element("div", context.label === null ? "context unlabelled" : "context");
    card.dataset.context = String(context.context);
    const title = element("h3", "context-name", names[context.context]);
    title.style.setProperty("--swatch", contextColour(context.context));
    const facts = element("small", "muted", ` χ${context.context}, ${context.scene_count} scene(s)`);
    const distinctive = element("div", "distinctive");
    const largest = Math.max(...context.distinctive_concepts.map((c) => c.probability), 1e-9);
    distinctive.append(...context.distinctive_concepts.map((concept) => conceptBar(concept, largest)));
    const top = context.top_concepts.slice(0, TOP_CONCEPTS_SHOWN);
    const common = element("p", "top-concepts muted", `most probable: ${top.map((c) => `${c.name} ${c.probability.toFixed(2)}`).join(", ")}`);
    card.append(title, facts, distinctive, common);
    return card;
  });
  container.replaceChildren(...cards);
  container.dataset.count = String(listing.contexts.length);
  container.dataset.scenes = String(listing.scene_count);
  container.dataset.labels = String(listing.contexts.filter((c) => c.label !== null).length);
}
