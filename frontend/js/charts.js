// Chart.js helpers (window.Chart from node_modules/chart.js/dist/chart.umd.min.js).

import { ellipsePoints } from "./lib/analysis.js";
import { labelAnchor } from "./lib/label_anchor.js";

export const PALETTE = [
  "#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd",
  "#8c564b", "#e377c2", "#7f7f7f", "#bcbd22", "#17becf",
];

export function colorOf(index) {
  return PALETTE[index % PALETTE.length];
}

/** Draws `point.label` next to each point of datasets that set `showLabels`. */
const pointLabels = {
  id: "pointLabels",
  afterDatasetsDraw(chart) {
    const { ctx } = chart;
    ctx.save();
    ctx.font = "600 12px system-ui, 'DejaVu Sans', sans-serif";
    ctx.textBaseline = "bottom";
    chart.data.datasets.forEach((dataset, i) => {
      if (!dataset.showLabels || !chart.isDatasetVisible(i)) return;
      const meta = chart.getDatasetMeta(i);
      meta.data.forEach((element, j) => {
        const label = dataset.data[j] && dataset.data[j].label;
        if (!label) return;
        ctx.fillStyle = dataset.labelColor || "#1c2430";
        const anchor = labelAnchor(element.x, ctx.measureText(label).width, chart.width);
        ctx.textAlign = anchor.align;
        ctx.fillText(label, anchor.x, element.y - 4);
      });
    });
    ctx.restore();
  },
};

/** Tick labels: 3 significant digits, exponents only for very small or large numbers. */
export function compactNumber(value) {
  const n = Number(value);
  if (n === 0) return "0";
  if (Math.abs(n) < 1e-3 || Math.abs(n) >= 1e5) return n.toExponential(1);
  return String(Number(n.toPrecision(3)));
}

let registered = false;
function ChartJS() {
  if (!window.Chart) throw new Error("Chart.js did not load (run scripts/install_frontend.sh)");
  if (!registered) {
    window.Chart.register(pointLabels);
    window.Chart.defaults.font.family = "system-ui, 'DejaVu Sans', sans-serif";
    window.Chart.defaults.color = "#3b4654";
    window.Chart.defaults.animation = false;
    window.Chart.defaults.maintainAspectRatio = false;
    registered = true;
  }
  return window.Chart;
}

const charts = new Map();

/** Create the chart on canvas `id` once, then update its data/options in place. */
export function renderChart(id, config) {
  const existing = charts.get(id);
  if (existing && existing.config.type === config.type) {
    existing.data = config.data;
    existing.options = config.options;
    existing.update("none");
    return existing;
  }
  if (existing) existing.destroy();
  const canvas = document.getElementById(id);
  const chart = new (ChartJS())(canvas, config);
  charts.set(id, chart);
  return chart;
}

/** 2D coordinates of latent points: ds = 1 on a line (y = 0), ds ≥ 2 the first two dims. */
/** The legend under a chart (small colour boxes), a fresh object for each chart. */
export function bottomLegend() {
  return { position: "bottom", labels: { boxWidth: 12 } };
}

/** Plugins of a scatter chart: the legend under it, and a tooltip saying `labelOf(point, item)`. */
export function scatterPlugins(labelOf) {
  return { legend: bottomLegend(), tooltip: { callbacks: { label: (item) => labelOf(item.raw, item) } } };
}

export function latentXY(latent) {
  return { x: latent[0], y: latent.length > 1 ? latent[1] : 0 };
}

function axisTitles(ds) {
  return {
    x: { type: "linear", title: { display: true, text: "s₁" }, grid: { color: "#eef0f3" } },
    y: {
      type: "linear",
      title: { display: true, text: ds > 1 ? "s₂" : "" },
      grid: { color: "#eef0f3" },
      ...(ds === 1 ? { min: -1, max: 1, ticks: { display: false } } : {}),
    },
  };
}

/**
 * The object manifold: one labelled point per object; optionally the belief (ellipse or
 * interval), the path of its mean and the highlighted nearest object.
 */
export function manifoldChart(id, objects, { belief = null, path = [], nearest = null } = {}) {
  const ds = objects.length ? objects[0].latent.length : 2;
  const datasets = [
    {
      label: "objects",
      type: "scatter",
      data: objects.map((o) => ({ ...latentXY(o.latent), label: o.name })),
      pointBackgroundColor: objects.map((_, i) => colorOf(i)),
      pointBorderColor: objects.map((o) => (o.name === nearest ? "#f2b600" : "#ffffff")),
      pointBorderWidth: objects.map((o) => (o.name === nearest ? 4 : 1)),
      pointRadius: objects.map((o) => (o.name === nearest ? 9 : 6)),
      showLabels: true,
      order: 1,
    },
  ];
  if (belief) {
    let outline;
    if (ds >= 2) {
      const cov2 = [belief.cov[0].slice(0, 2), belief.cov[1].slice(0, 2)];
      outline = ellipsePoints(belief.mean.slice(0, 2), cov2, 2, 72);
    } else {
      const half = 2 * Math.sqrt(Math.max(0, belief.cov[0][0]));
      outline = [{ x: belief.mean[0] - half, y: 0 }, { x: belief.mean[0] + half, y: 0 }];
    }
    datasets.push({
      label: ds >= 2 ? "belief (2σ ellipse)" : "belief (2σ interval)",
      type: "scatter",
      data: outline,
      showLine: true,
      pointRadius: 0,
      borderColor: "#1c2430",
      borderWidth: ds >= 2 ? 1.5 : 4,
      backgroundColor: "rgba(28,36,48,0.06)",
      fill: ds >= 2,
      order: 3,
    });
    datasets.push({
      label: "belief mean path",
      type: "scatter",
      data: path.map((m) => latentXY(m)),
      showLine: true,
      borderColor: "#5d6978",
      borderDash: [4, 3],
      borderWidth: 1.5,
      pointRadius: path.map((_, i) => (i === path.length - 1 ? 5 : 2.5)),
      pointBackgroundColor: "#1c2430",
      order: 2,
    });
  }
  return renderChart(id, {
    type: "scatter",
    data: { datasets },
    options: {
      scales: axisTitles(ds),
      plugins: scatterPlugins((p) => `${p.label ? `${p.label}: ` : ""}(${p.x.toFixed(3)}, ${p.y.toFixed(3)})`),
    },
  });
}

/** Horizontal bars of the posterior over objects, the nearest object highlighted. */
export function posteriorChart(id, objectNames, probabilities, nearest) {
  return renderChart(id, {
    type: "bar",
    data: {
      labels: objectNames,
      datasets: [
        {
          label: "p(object | touches)",
          data: objectNames.map((n) => probabilities[n] ?? 0),
          backgroundColor: objectNames.map((n, i) => (n === nearest ? colorOf(i) : `${colorOf(i)}66`)),
          borderColor: objectNames.map((_, i) => colorOf(i)),
          borderWidth: 1,
        },
      ],
    },
    options: {
      indexAxis: "y",
      scales: { x: { min: 0, max: 1, title: { display: true, text: "probability" } } },
      plugins: { legend: { display: false } },
    },
  });
}

/** A line chart of y against x for several named series. */
export function lineChart(id, series, { xTitle = "", yTitle = "", yMin, yMax, stepped = false } = {}) {
  return renderChart(id, {
    type: "line",
    data: {
      datasets: series.map((s, i) => ({
        label: s.label,
        data: s.x.map((x, j) => ({ x, y: s.y[j] })),
        borderColor: s.color || colorOf(i),
        backgroundColor: s.color || colorOf(i),
        pointRadius: s.x.length > 40 ? 0 : 3,
        borderWidth: 2,
        stepped,
        tension: 0,
      })),
    },
    options: {
      parsing: false,
      scales: {
        x: { type: "linear", title: { display: !!xTitle, text: xTitle } },
        y: {
          title: { display: !!yTitle, text: yTitle },
          min: yMin,
          max: yMax,
          ticks: { callback: (value) => compactNumber(value) },
        },
      },
      plugins: { legend: { ...bottomLegend(), display: series.length > 1 } },
    },
  });
}
