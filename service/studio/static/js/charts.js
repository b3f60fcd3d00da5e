// Small SVG charts: lines over time, a path seen from above, a timeline of phases.

const NS = "http://www.w3.org/2000/svg";

function el(name, attrs = {}, text) {
  const node = document.createElementNS(NS, name);
  for (const [k, v] of Object.entries(attrs)) node.setAttribute(k, v);
  if (text !== undefined) node.textContent = text;
  return node;
}

/** A linear map from [d0, d1] to [r0, r1] (a flat domain maps to the middle). */
export function scale(d0, d1, r0, r1) {
  const span = d1 - d0;
  return (v) => (span === 0 ? (r0 + r1) / 2 : r0 + ((v - d0) / span) * (r1 - r0));
}

/** [min, max] of numbers, ignoring null and NaN. */
export function extent(values) {
  let lo = Infinity; let hi = -Infinity;
  for (const v of values) if (Number.isFinite(v)) { lo = Math.min(lo, v); hi = Math.max(hi, v); }
  return lo <= hi ? [lo, hi] : [0, 1];
}

function chart(title, width, height) {
  const square = width === height ? " square" : "";
  const svg = el("svg", { viewBox: `0 0 ${width} ${height}`, class: `chart${square}`, role: "img",
    "aria-label": title });
  svg.append(el("title", {}, title));
  return svg;
}

/** Lines of `series` ([{label, values, colour}]) against `time`, with a y label. */
export function lineChart(title, time, series, yLabel, { width = 480, height = 180 } = {}) {
  const svg = chart(title, width, height);
  const pad = 34;
  const x = scale(time[0], time[time.length - 1], pad, width - 8);
  const [lo, hi] = extent(series.flatMap((s) => s.values));
  const y = scale(lo, hi, height - 20, 18);
  svg.append(el("text", { x: 2, y: 12 }, `${yLabel}: ${hi.toFixed(2)}`));
  svg.append(el("text", { x: 2, y: height - 4 }, `${lo.toFixed(2)} · ${time[time.length - 1].toFixed(1)} s`));
  series.forEach((s, k) => {
    const points = s.values.map((v, i) => `${x(time[i]).toFixed(1)},${y(v).toFixed(1)}`).join(" ");
    svg.append(el("polyline", { points, fill: "none", stroke: s.colour, "stroke-width": 1.5 }));
    svg.append(el("text", { x: 120 + 90 * k, y: 12, style: `fill:${s.colour}` }, s.label));
  });
  return svg;
}

/** The root path seen from above (x right, z down the page), start and end marked. */
export function topView(title, points, { size = 320 } = {}) {
  const svg = chart(title, size, size);
  const [x0, x1] = extent(points.map((p) => p[0]));
  const [z0, z1] = extent(points.map((p) => p[2]));
  const half = Math.max(x1 - x0, z1 - z0, 0.5) / 2 * 1.1;
  const cx = (x0 + x1) / 2; const cz = (z0 + z1) / 2;
  const sx = scale(cx - half, cx + half, 10, size - 10);
  const sz = scale(cz - half, cz + half, 10, size - 10);
  const line = points.map((p) => `${sx(p[0]).toFixed(1)},${sz(p[2]).toFixed(1)}`).join(" ");
  svg.append(el("polyline", { points: line, fill: "none", stroke: "#2457c5", "stroke-width": 2 }));
  const [first, last] = [points[0], points[points.length - 1]];
  svg.append(el("circle", { cx: sx(first[0]), cy: sz(first[2]), r: 5, fill: "#1b7a3a" }));
  svg.append(el("circle", { cx: sx(last[0]), cy: sz(last[2]), r: 5, fill: "#b3261e" }));
  svg.append(el("text", { x: 4, y: size - 4 }, `${(2 * half).toFixed(2)} m across · start ● green, end ● red`));
  return svg;
}

export const PHASE_COLOURS = { left: "#2457c5", right: "#e07b00", both: "#1b7a3a", none: "#d0d4dc" };

/** Runs of equal labels: [{label, start, end}] (end exclusive). */
export function runs(labels) {
  const out = [];
  labels.forEach((label, i) => {
    const last = out[out.length - 1];
    if (last && last.label === label) last.end = i + 1; else out.push({ label, start: i, end: i + 1 });
  });
  return out;
}

/** Contact phases as coloured bands over the frames, with a legend. */
export function timeline(title, labels, fps, { width = 480, height = 46 } = {}) {
  const svg = chart(title, width, height);
  const x = scale(0, labels.length, 4, width - 4);
  for (const run of runs(labels)) {
    const band = el("rect", { x: x(run.start), y: 4, width: Math.max(x(run.end) - x(run.start), 0.5),
      height: 18, fill: PHASE_COLOURS[run.label] || "#999" });
    band.append(el("title", {}, `${run.label}: ${(run.start / fps).toFixed(2)}–${(run.end / fps).toFixed(2)} s`));
    svg.append(band);
  }
  Object.entries(PHASE_COLOURS).forEach(([label, colour], k) => {
    svg.append(el("rect", { x: 4 + k * 80, y: 30, width: 10, height: 10, fill: colour }));
    svg.append(el("text", { x: 18 + k * 80, y: 39 }, label));
  });
  return svg;
}
