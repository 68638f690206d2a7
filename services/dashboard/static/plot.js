// The report's speed-against-error plot drawn as SVG (as the report's own speed_error.png): seconds per
// frame against an error metric on log-log axes, path tracing's curve, its equal-time point and the model.

import { formatNumber, formatSeconds, h } from "./dom.js";

const WIDTH = 420, HEIGHT = 300;
const MARGIN = { left: 58, right: 14, top: 26, bottom: 44 };

const finitePositive = (v) => typeof v === "number" && Number.isFinite(v) && v > 0;

/** Log-scale ticks at 1, 2 and 5 times each power of ten inside [low, high], or at every integer
 *  multiple when that leaves fewer than three (a range inside one decade). */
function ticks(low, high) {
  const at = (multiples) => {
    const out = [];
    for (let e = Math.floor(Math.log10(low)); e <= Math.ceil(Math.log10(high)); e += 1) {
      for (const m of multiples) {
        const v = m * 10 ** e;
        if (v >= low && v <= high) out.push(v);
      }
    }
    return out;
  };
  const coarse = at([1, 2, 5]);
  return coarse.length >= 3 ? coarse : at([1, 2, 3, 4, 5, 6, 7, 8, 9]);
}

function logScale(values, from, to) {
  let low = Math.min(...values), high = Math.max(...values);
  if (low === high) { low /= 2; high *= 2; }
  const pad = (Math.log10(high) - Math.log10(low)) * 0.08;
  const a = Math.log10(low) - pad, b = Math.log10(high) + pad;
  const scale = (v) => from + ((Math.log10(v) - a) / (b - a)) * (to - from);
  scale.domain = [10 ** a, 10 ** b];
  return scale;
}

const tickLabel = (v) => (v >= 1e4 || v < 1e-3 ? v.toExponential(0) : String(+v.toPrecision(3)));

/** One panel: `metric` ("flip" or "relative_mse") of every point of `report` against its time. */
export function speedErrorPlot(report, metric, title) {
  const traced = [...report.path_tracing].sort((p, q) => p.seconds_per_frame - q.seconds_per_frame);
  const series = [
    ...traced.map((p) => ({ point: p, role: "traced" })),
    { point: report.path_tracing_equal_time, role: "equal" },
    { point: report.model, role: "model" },
  ].filter(({ point }) => finitePositive(point.seconds_per_frame) && finitePositive(point.error[metric]));
  const svg = h("svg:svg", {
    viewBox: `0 0 ${WIDTH} ${HEIGHT}`, class: "plot", role: "img", "aria-label": `${title} against seconds per frame`,
  });
  svg.append(h("svg:text", { x: WIDTH / 2, y: 16, class: "plot-title", "text-anchor": "middle" }, title));
  if (!series.length) {
    svg.append(h("svg:text", { x: WIDTH / 2, y: HEIGHT / 2, "text-anchor": "middle" }, "no finite values to plot"));
    return svg;
  }
  const x = logScale(series.map((s) => s.point.seconds_per_frame), MARGIN.left, WIDTH - MARGIN.right);
  const y = logScale(series.map((s) => s.point.error[metric]), HEIGHT - MARGIN.bottom, MARGIN.top);
  const [x0, x1] = [MARGIN.left, WIDTH - MARGIN.right], [y0, y1] = [HEIGHT - MARGIN.bottom, MARGIN.top];
  for (const v of ticks(...x.domain)) {
    svg.append(h("svg:line", { x1: x(v), x2: x(v), y1: y0, y2: y1, class: "grid" }));
    svg.append(h("svg:text", { x: x(v), y: y0 + 14, "text-anchor": "middle", class: "tick" }, tickLabel(v)));
  }
  for (const v of ticks(...y.domain)) {
    svg.append(h("svg:line", { x1: x0, x2: x1, y1: y(v), y2: y(v), class: "grid" }));
    svg.append(h("svg:text", { x: x0 - 5, y: y(v) + 4, "text-anchor": "end", class: "tick" }, tickLabel(v)));
  }
  svg.append(h("svg:rect", { x: x0, y: y1, width: x1 - x0, height: y0 - y1, class: "frame" }));
  svg.append(h("svg:text", { x: (x0 + x1) / 2, y: HEIGHT - 8, "text-anchor": "middle", class: "axis" }, "seconds per frame"));
  svg.append(h("svg:text", {
    x: 14, y: (y0 + y1) / 2, "text-anchor": "middle", class: "axis", transform: `rotate(-90 14 ${(y0 + y1) / 2})`,
  }, title));

  const curve = series.filter((s) => s.role === "traced");
  svg.append(h("svg:polyline", {
    points: curve.map((s) => `${x(s.point.seconds_per_frame)},${y(s.point.error[metric])}`).join(" "),
    class: "curve",
  }));
  for (const { point, role } of series) {
    const cx = x(point.seconds_per_frame), cy = y(point.error[metric]);
    const tip = h("svg:title", {}, `${point.label}: ${formatSeconds(point.seconds_per_frame)}, ${title} ${formatNumber(point.error[metric])}`);
    if (role === "traced") {
      svg.append(h("svg:circle", { cx, cy, r: 3.5, class: "traced", "data-point": point.label }, tip));
      svg.append(h("svg:text", { x: cx + 5, y: cy - 5, class: "point-label" }, point.label));
    } else if (role === "equal") {
      svg.append(h("svg:rect", { x: cx - 5, y: cy - 5, width: 10, height: 10, class: "equal", "data-point": point.label }, tip));
    } else {
      const star = Array.from({ length: 10 }, (_, i) => {
        const r = i % 2 ? 3.5 : 9, a = (Math.PI * i) / 5 - Math.PI / 2;
        return `${cx + r * Math.cos(a)},${cy + r * Math.sin(a)}`;
      }).join(" ");
      svg.append(h("svg:polygon", { points: star, class: "model", "data-point": point.label }, tip));
    }
  }
  const legend = [
    ["traced", "path tracing"],
    ["equal", `path tracing at equal time (${report.path_tracing_equal_time.label})`],
    ["model", `${report.kind} (${report.model.label})`],
  ];
  legend.forEach(([role, text], i) => {
    const ly = MARGIN.top + 12 + i * 14;
    svg.append(h("svg:circle", { cx: x1 - 8, cy: ly - 4, r: 4, class: `legend-mark ${role}` }));
    svg.append(h("svg:text", { x: x1 - 16, y: ly, "text-anchor": "end", class: "legend" }, text));
  });
  return svg;
}
