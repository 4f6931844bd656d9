// The two time charts (uPlot): the stacked context posterior of recent scenes, and K per scene.
import uPlot from "uplot";
import { contextName } from "./contexts.js";
import { contextColour } from "./kinds.js";

const HEIGHT = 220;

function width(element) {
  return Math.max(240, element.clientWidth - 8);
}

// Series k holds P(χ0) + … + P(χk); drawn from the top one down, each filled to zero, so the band
// between series k-1 and k shows context k (uPlot has no stacking of its own).
function stacked(scenes, contextCount) {
  const series = [];
  for (let k = contextCount - 1; k >= 0; k -= 1) {
    series.push(scenes.map((s) => s.context_posterior.slice(0, k + 1).reduce((a, b) => a + b, 0)));
  }
  return [scenes.map((s) => s.scene_id), ...series];
}

export class PosteriorChart {
  constructor(element, legend) {
    this.element = element;
    this.legend = legend;
    this.plot = null;
    this.contextCount = 0;
    this.names = [];
    window.addEventListener("resize", () => this.plot?.setSize({ width: width(element), height: HEIGHT }));
  }

  render(scenes) {
    const contextCount = Math.max(1, ...scenes.map((s) => s.context_posterior.length));
    const data = stacked(scenes, contextCount);
    if (this.plot && contextCount === this.contextCount) {
      this.plot.setData(data);
    } else {
      this.plot?.destroy();
      this.contextCount = contextCount;
      const series = [{ label: "scene" }];
      for (let k = contextCount - 1; k >= 0; k -= 1) {
        series.push({ label: `χ${k}`, stroke: contextColour(k), fill: contextColour(k), width: 1, points: { show: false } });
      }
      this.plot = new uPlot(
        {
          width: width(this.element),
          height: HEIGHT,
          legend: { show: false },
          cursor: { show: false },
          scales: { x: { time: false }, y: { range: [0, 1] } },
          axes: [{ label: "scene" }, { label: "P(χ | scene)" }],
          series,
        },
        data,
        this.element,
      );
      this.drawLegend();
    }
    this.element.dataset.points = String(scenes.length);
    this.element.dataset.contexts = String(contextCount);
  }

  // The contexts' names (labels, else "context k") for the legend; series labels only name the
  // plot's own (hidden) legend, so a new name redraws the legend alone.
  setNames(names) {
    if (names.join("\n") === this.names.join("\n")) return;
    this.names = names;
    this.drawLegend();
  }

  drawLegend() {
    this.legend.replaceChildren(
      ...Array.from({ length: this.contextCount }, (_, k) => {
        const item = document.createElement("span");
        item.style.setProperty("--swatch", contextColour(k));
        item.dataset.context = String(k);
        item.textContent = contextName(this.names, k);
        return item;
      }),
    );
  }
}

export class ContextCountChart {
  constructor(element) {
    this.element = element;
    this.plot = new uPlot(
      {
        width: width(element),
        height: HEIGHT,
        legend: { show: false },
        scales: { x: { time: false }, y: { range: (_u, _min, max) => [0, Math.max(3, max + 1)] } },
        axes: [{ label: "scene" }, { label: "K" }],
        series: [{}, { label: "K", stroke: "#333", width: 2, paths: uPlot.paths.stepped({ align: 1 }), points: { show: false } }],
      },
      [[], []],
      element,
    );
    window.addEventListener("resize", () => this.plot.setSize({ width: width(element), height: HEIGHT }));
  }

  render(scenes) {
    this.plot.setData([scenes.map((s) => s.scene_id), scenes.map((s) => s.context_count)]);
    this.element.dataset.points = String(scenes.length);
    this.element.dataset.k = String(scenes.length ? scenes[scenes.length - 1].context_count : 0);
  }
}
