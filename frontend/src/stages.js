// The latest object at the three stages of Fig. 6(b) side by side: P(c) from perception (the
// prototypes, Eq. 1, or the robot's recogniser), after the concept web (Eqs. 2–4) and in context
// (Eq. 6), so that one sees whether the web and the context raised the right noun.
import { element } from "./dom.js";
import { kindColour, kindOf } from "./kinds.js";

const NOUN_ROWS = 3;
const OTHER_ROWS = 5;

export const STAGES = [
  { key: "perception", title: (level) => (level === "concepts" ? "recogniser" : "prototypes") },
  { key: "web", title: () => "concept web" },
  { key: "in_context", title: () => "in context" },
];

// The concepts worth a row, each by its largest P(c) at any stage: the leading nouns first, so that
// the runner-up a stage raised or lowered is in view, then the other concepts.
function rowConcepts(object, vocabulary) {
  const best = new Map();
  for (const { key } of STAGES) {
    for (const [name, p] of Object.entries(object[key] ?? {})) best.set(name, Math.max(best.get(name) ?? 0, p));
  }
  const ranked = [...best].sort((a, b) => b[1] - a[1]).map(([name]) => name);
  const nouns = ranked.filter((name) => vocabulary.nouns.includes(name));
  const others = ranked.filter((name) => !vocabulary.nouns.includes(name));
  return [...nouns.slice(0, NOUN_ROWS), ...others.slice(0, OTHER_ROWS)];
}

function mostProbableNoun(probabilities, vocabulary) {
  let noun = null;
  for (const name of vocabulary.nouns) {
    if (name in probabilities && (noun === null || probabilities[name] > probabilities[noun])) noun = name;
  }
  return noun;
}

function nounPath(object, vocabulary) {
  const path = element("p", "noun-path");
  path.append(element("span", "muted", "most probable noun: "));
  STAGES.forEach(({ key, title }, i) => {
    if (i > 0) path.append(element("span", "muted", " → "));
    const probabilities = object[key];
    const noun = probabilities && mostProbableNoun(probabilities, vocabulary);
    const step = element("span", "stage-noun", noun ? `${noun} ${probabilities[noun].toFixed(2)}` : "—");
    step.dataset.stage = key;
    step.dataset.noun = noun ?? "";
    step.title = title(object.level);
    path.append(step);
  });
  return path;
}

function cell(key, probabilities, name) {
  const td = element("td", "stage");
  td.dataset.stage = key;
  if (!probabilities) {
    td.textContent = "—";
    td.title = key === "web" ? "no concept web fitted" : "no context feedback yet";
    return td;
  }
  const p = probabilities[name] ?? 0;
  const track = element("span", "track");
  const fill = element("span", `fill ${key}`);
  fill.style.width = `${100 * p}%`;
  track.append(fill);
  td.append(track, element("span", "value", p.toFixed(2)));
  return td;
}

export function renderStages(table, caption, { object, vocabulary, sceneId, objectIndex }) {
  const head = element("tr");
  head.append(element("th", null, "concept"));
  for (const { key, title } of STAGES) {
    const th = element("th", `stage ${key}`, title(object.level));
    th.dataset.stage = key;
    head.append(th);
  }
  const rows = rowConcepts(object, vocabulary).map((name) => {
    const row = element("tr");
    row.dataset.concept = name;
    const label = element("td", "concept", name);
    label.style.color = kindColour(kindOf(name, vocabulary));
    row.append(label, ...STAGES.map(({ key }) => cell(key, object[key], name)));
    return row;
  });
  table.replaceChildren(element("thead"), element("tbody"));
  table.tHead.append(head);
  table.tBodies[0].append(...rows);
  caption.replaceChildren(nounPath(object, vocabulary));
  table.dataset.scene = String(sceneId);
  table.dataset.object = String(objectIndex);
  table.dataset.rows = String(rows.length);
}
