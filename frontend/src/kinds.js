// Concept kinds coloured as in the paper's Fig. 8: nouns red, adjectives blue, verbs green.
export const KIND_COLOURS = { noun: "#d62728", adjective: "#1f77b4", verb: "#2ca02c" };
export const UNKNOWN_COLOUR = "#888888";

export const kindColour = (kind) => KIND_COLOURS[kind] ?? UNKNOWN_COLOUR;

// One colour per context index (contexts are unnamed topics: χ0, χ1, ...).
const CONTEXT_PALETTE = ["#8c564b", "#e377c2", "#bcbd22", "#17becf", "#ff7f0e", "#9467bd", "#7f7f7f", "#aec7e8", "#ffbb78", "#98df8a"];
export const contextColour = (index) => CONTEXT_PALETTE[index % CONTEXT_PALETTE.length];

export function kindOf(name, vocabulary) {
  if (vocabulary.nouns.includes(name)) return "noun";
  if (vocabulary.adjective_pairs.some((pair) => pair.includes(name))) return "adjective";
  if (vocabulary.verbs.includes(name)) return "verb";
  return null;
}
