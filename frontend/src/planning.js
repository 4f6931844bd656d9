// A plan and its search tree as in Fig. 15: each level shows every behaviour, the pruned ones
// crossed out and never expanded, the plan's own step highlighted and expanded to the next level.
import { contextName } from "./contexts.js";
import { svg } from "./svg.js";

const ROW = 58;
const SPACING = 34;

// Fig. 15's labels: PX push, MX move (Left/Right/Forward/Backward), KD, SH, TH, DP, G.
export function abbreviation(behaviour) {
  const [verb, direction] = behaviour.split("_");
  const fixed = { knock_down: "KD", shake: "SH", throw: "TH", drop: "DP", grasp: "G" }[behaviour];
  if (fixed) return fixed;
  return (verb[0] + (direction ? direction[0] : verb[1] ?? "")).toUpperCase();
}

function tree(plan) {
  const behaviours = [...plan.kept, ...plan.pruned];
  const pruned = new Set(plan.pruned);
  const width = behaviours.length * SPACING;
  const depth = Math.max(1, plan.plan.length);
  const root = svg("svg", { viewBox: `0 0 ${width} ${ROW * depth + 40}`, class: "plan-tree" });
  let parentX = width / 2;
  root.append(svg("circle", { cx: parentX, cy: 14, r: 7, class: "tree-root" }));
  for (let level = 0; level < depth; level += 1) {
    const y = 14 + ROW * (level + 1);
    let nextParent = parentX;
    behaviours.forEach((behaviour, i) => {
      const x = SPACING / 2 + i * SPACING;
      const onPlan = plan.plan[level] === behaviour;
      const state = pruned.has(behaviour) ? "pruned" : onPlan ? "step" : "kept";
      root.append(svg("line", { x1: parentX, y1: y - ROW + 7, x2: x, y2: y - 9, class: `tree-edge ${state}` }));
      const node = svg("g", { class: `tree-node ${state}`, "data-behaviour": behaviour });
      node.append(svg("circle", { cx: x, cy: y, r: 9 }), svg("text", { x, y: y + 3.5, "text-anchor": "middle" }, abbreviation(behaviour)));
      node.append(svg("title", {}, `${behaviour}: ${state === "pruned" ? "pruned, not expanded" : state === "step" ? "the plan's step" : "kept"}`));
      if (state === "pruned") {
        node.append(svg("path", { d: `M${x - 7},${y - 7}L${x + 7},${y + 7}M${x + 7},${y - 7}L${x - 7},${y + 7}`, class: "cross" }));
      }
      root.append(node);
      if (onPlan) nextParent = x;
    });
    parentX = nextParent;
  }
  return root;
}

export function renderPlan(container, plan, contextNames) {
  const summary = document.createElement("p");
  const context =
    plan.context === null ? "no context (nothing pruned)" : `${contextName(contextNames, plan.context)} (χ${plan.context}, ${plan.context_source})`;
  summary.textContent =
    `${plan.status}: ${plan.plan.length} step(s) in ${context}; ${plan.nodes_generated} nodes generated ` +
    `instead of ${plan.unpruned.nodes_generated} unpruned; ${plan.pruned.length} of ${plan.kept.length + plan.pruned.length} behaviours pruned.`;
  const steps = document.createElement("p");
  steps.className = "plan-steps";
  steps.textContent = plan.positions.map((position, i) => (i === 0 ? `${position}` : ` → ${plan.plan[i - 1]} → ${position}`)).join("");
  container.replaceChildren(summary, steps, tree(plan));
  container.dataset.status = plan.status;
  container.dataset.pruned = String(plan.pruned.length);
}
