// The latest object's concept web as a graph: nodes on a circle grouped by kind (Fig. 8 colours),
// size and opacity by P(c), active concepts outlined; grey edges weighted by co-occurrence.
import { kindColour, kindOf } from "./kinds.js";
import { svg } from "./svg.js";

const RADIUS = 165;

// The most refined probability the service gave: P(c)* in context (Eq. 6), else the web's, else perception's.
export function conceptProbabilities(object) {
  return object.in_context ?? object.web ?? object.perception ?? {};
}

export function renderConceptWeb(element, { vocabulary, object, edges }) {
  const probabilities = conceptProbabilities(object);
  const known = [...vocabulary.nouns, ...vocabulary.adjective_pairs.flat(), ...vocabulary.verbs];
  const names = [...known, ...Object.keys(probabilities).filter((name) => !known.includes(name))];
  const active = new Set(object.active_concepts);
  const position = new Map(
    names.map((name, i) => {
      const angle = (2 * Math.PI * i) / names.length - Math.PI / 2;
      return [name, { x: RADIUS * Math.cos(angle), y: RADIUS * Math.sin(angle), angle }];
    }),
  );
  const heaviest = Math.max(1, ...edges.map((e) => e.weight));
  const lines = edges
    .filter((e) => position.has(e.source) && position.has(e.target))
    .map((e) => {
      const a = position.get(e.source);
      const b = position.get(e.target);
      const share = e.weight / heaviest;
      const lit = active.has(e.source) && active.has(e.target);
      return svg("line", {
        x1: a.x, y1: a.y, x2: b.x, y2: b.y,
        class: lit ? "edge lit" : "edge",
        "stroke-width": (0.4 + 3 * share).toFixed(2),
        "stroke-opacity": (lit ? 0.35 + 0.6 * share : 0.08 + 0.35 * share).toFixed(2),
      });
    });
  const nodes = names.map((name) => {
    const { x, y, angle } = position.get(name);
    const p = probabilities[name] ?? 0;
    const kind = kindOf(name, vocabulary);
    const group = svg("g", { class: active.has(name) ? "node active" : "node", "data-kind": kind ?? "unknown" });
    group.append(
      svg("circle", { cx: x, cy: y, r: (4 + 9 * p).toFixed(1), fill: kindColour(kind), "fill-opacity": (0.25 + 0.75 * p).toFixed(2) }),
      svg("title", {}, `${name} (${kind ?? "unknown kind"}): P(c) = ${p.toFixed(3)}`),
    );
    const outward = Math.cos(angle) >= 0;
    group.append(
      svg("text", {
        x: x + 22 * Math.cos(angle),
        y: y + 22 * Math.sin(angle) + 4,
        "text-anchor": Math.abs(Math.cos(angle)) < 0.2 ? "middle" : outward ? "start" : "end",
      }, name),
    );
    return group;
  });
  element.replaceChildren(...lines, ...nodes);
  element.dataset.nodes = String(names.length);
  element.dataset.edges = String(lines.length);
}

// Co-occurrence of concepts within objects, counted from what the dashboard has seen; used when the
// service does not expose the fitted web's edges.
export class CooccurrenceCounter {
  constructor() {
    this.counts = new Map();
  }

  add(activeConcepts) {
    const names = [...new Set(activeConcepts)].sort();
    for (let i = 0; i < names.length; i += 1) {
      for (let j = i + 1; j < names.length; j += 1) {
        const key = `${names[i]}\u0000${names[j]}`;
        this.counts.set(key, (this.counts.get(key) ?? 0) + 1);
      }
    }
  }

  edges() {
    return [...this.counts].map(([key, weight]) => {
      const [source, target] = key.split("\u0000");
      return { source, target, weight };
    });
  }
}
