// The result view (/jobs/{id}): live status, downloads, the 3D skeleton or the translation charts.

import { api, download, follow, problemText } from "./api.js";
import { lineChart, timeline, topView } from "./charts.js";
import { draw, prepare, RELIABILITY_COLOURS } from "./skeleton3d.js";

const $ = (sel) => document.querySelector(sel);
let cleanup = [];

function make(tag, attrs = {}, text) {
  const node = document.createElement(tag);
  Object.assign(node, attrs);
  if (text !== undefined) node.textContent = text;
  return node;
}

function labelled(text, control) {
  const label = make("label", { htmlFor: control.id }, text);
  const span = make("span", { className: "row" });
  span.append(label, control);
  return span;
}

const mm = (v) => (v === null || v === undefined ? "–" : (v * 1000).toFixed(1));

function jointTable(doc) {
  const table = make("table", { className: "grid", id: "joint-table" });
  table.append(make("caption", {}, "Joints"));
  const head = make("tr");
  for (const h of ["joint", "reliability", "data sd (mm)", "rms residual (mm)", "range of motion (°)"]) {
    head.append(make("th", { scope: "col" }, h));
  }
  table.appendChild(make("thead")).append(head);
  const body = table.appendChild(make("tbody"));
  for (const [name, q] of Object.entries(doc.quality || {})) {
    const row = body.appendChild(make("tr"));
    row.append(make("th", { scope: "row" }, name), make("td", {}, q.reliability || "–"),
      make("td", { className: "num" }, mm(q.data_sd_m)), make("td", { className: "num" }, mm(q.rms_residual_m)),
      make("td", { className: "num" }, q.range_of_motion_deg == null ? "–" : q.range_of_motion_deg.toFixed(1)));
  }
  return table;
}

function boneTable(doc) {
  const table = make("table", { className: "grid", id: "bone-table" });
  table.append(make("caption", {}, "Bone lengths"));
  const body = table.appendChild(make("tbody"));
  for (const [segment, length] of Object.entries(doc.bone_lengths || {})) {
    const row = body.appendChild(make("tr"));
    row.append(make("th", { scope: "row" }, segment), make("td", { className: "num" }, `${(length * 100).toFixed(1)} cm`));
  }
  return table;
}

function warningList(doc) {
  const list = make("ul", { className: "warnings" });
  for (const w of doc.warnings || []) list.append(make("li", {}, w));
  return list;
}

function controls() {
  const play = make("button", { type: "button", id: "play" }, "Play");
  const scrub = make("input", { type: "range", id: "frame", min: 0, value: 0, step: 1 });
  const speed = make("select", { id: "speed" });
  for (const s of [0.25, 0.5, 1, 2, 4]) speed.append(make("option", { value: s, selected: s === 1 }, `${s}×`));
  const trails = make("input", { type: "checkbox", id: "trails" });
  const reset = make("button", { type: "button", className: "quiet", id: "reset-view" }, "Reset view");
  const time = make("output", { id: "time" }, "0.00 s");
  return { play, scrub, speed, trails, reset, time };
}

function legend() {
  const box = make("p", { className: "legend" });
  for (const [name, colour] of Object.entries(RELIABILITY_COLOURS)) {
    const item = make("span");
    item.append(make("i", { style: `background:${colour}` }), name);
    box.append(item);
  }
  return box;
}

function skeletonView(doc, job) {
  const scene = prepare(doc, job.params.up || [0, 1, 0]);
  const colours = Object.fromEntries(Object.entries(doc.quality || {})
    .map(([j, q]) => [j, RELIABILITY_COLOURS[q.reliability] || RELIABILITY_COLOURS.unknown]));
  const start = { yaw: -0.6, pitch: 0.35, zoom: 1 };
  const camera = { ...start, center: scene.center, radius: scene.radius };
  const canvas = make("canvas", { className: "stage", id: "stage", width: 800, height: 600, tabIndex: 0 });
  canvas.setAttribute("role", "img");
  canvas.setAttribute("aria-label", "Skeleton over time. Drag or arrow keys to orbit, wheel or +/- to zoom.");
  const c = controls();
  c.scrub.max = scene.frames - 1;
  c.scrub.setAttribute("aria-label", "Frame");
  let frame = 0; let playing = false; let last = 0; let clock = 0;
  const render = () => {
    draw(canvas, scene, camera, frame, { trails: c.trails.checked, colours });
    c.scrub.value = frame;
    c.time.value = `${(frame / scene.fps).toFixed(2)} s`;
  };
  const tick = (now) => {
    if (!playing) return;
    clock += ((now - last) / 1000) * Number(c.speed.value);
    last = now;
    frame = Math.floor(clock * scene.fps) % scene.frames;
    render();
    requestAnimationFrame(tick);
  };
  c.play.addEventListener("click", () => {
    playing = !playing;
    c.play.textContent = playing ? "Pause" : "Play";
    clock = frame / scene.fps; last = performance.now();
    if (playing) requestAnimationFrame(tick);
  });
  c.scrub.addEventListener("input", () => { frame = Number(c.scrub.value); clock = frame / scene.fps; render(); });
  c.trails.addEventListener("change", render);
  c.reset.addEventListener("click", () => { Object.assign(camera, start); render(); });
  orbit(canvas, camera, render);
  const stage = make("div");
  const bar = make("div", { className: "row" });
  bar.append(c.play, labelled("Frame", c.scrub), c.time, labelled("Speed", c.speed),
    labelled("Trails", c.trails), c.reset);
  stage.append(canvas, bar, legend());
  const side = make("div");
  side.append(jointTable(doc), boneTable(doc), warningList(doc));
  const view = make("div", { className: "viewer" });
  view.append(stage, side);
  cleanup.push(() => { playing = false; });
  requestAnimationFrame(render);
  return view;
}

function orbit(canvas, camera, render) {
  let drag = null;
  canvas.addEventListener("pointerdown", (e) => { drag = [e.clientX, e.clientY]; canvas.setPointerCapture(e.pointerId); });
  canvas.addEventListener("pointerup", () => { drag = null; });
  canvas.addEventListener("pointermove", (e) => {
    if (!drag) return;
    camera.yaw += (e.clientX - drag[0]) * 0.01;
    camera.pitch = Math.max(-1.5, Math.min(1.5, camera.pitch + (e.clientY - drag[1]) * 0.01));
    drag = [e.clientX, e.clientY];
    render();
  });
  canvas.addEventListener("wheel", (e) => {
    e.preventDefault();
    camera.zoom = Math.max(0.2, Math.min(8, camera.zoom * (e.deltaY < 0 ? 1.1 : 0.9)));
    render();
  }, { passive: false });
  canvas.addEventListener("keydown", (e) => {
    const keys = { ArrowLeft: () => { camera.yaw -= 0.1; }, ArrowRight: () => { camera.yaw += 0.1; },
      ArrowUp: () => { camera.pitch = Math.min(1.5, camera.pitch + 0.1); },
      ArrowDown: () => { camera.pitch = Math.max(-1.5, camera.pitch - 0.1); },
      "+": () => { camera.zoom *= 1.1; }, "=": () => { camera.zoom *= 1.1; }, "-": () => { camera.zoom /= 1.1; } };
    if (keys[e.key]) { e.preventDefault(); keys[e.key](); render(); }
  });
}

/** Feet heights (m) from the result's `foot_heights` (every input format has them). */
function feetHeights(doc) {
  if (!doc.foot_heights || !doc.feet) return [];
  return ["left", "right"].map((side) => ({ foot: doc.feet[side], values: doc.foot_heights[side] }));
}

async function translationView(doc, job) {
  const time = doc.time || doc.root.map((_, i) => i / doc.fps);
  const view = make("div", { className: "viewer" });
  const left = make("div");
  left.append(topView("Root path seen from above", doc.root),
    timeline("Contact phases", doc.contacts, doc.fps));
  const series = [{ label: "hips", values: doc.root.map((p) => p[1]), colour: "#2457c5" },
    { label: "floor", values: doc.floor, colour: "#5b6275" }];
  for (const [k, f] of feetHeights(doc).entries()) {
    series.push({ label: f.foot, values: f.values, colour: k ? "#e07b00" : "#1b7a3a" });
  }
  left.append(lineChart("Heights over time (m)", time, series, "height m"));
  const side = make("table", { className: "grid" });
  side.append(make("caption", {}, "Quality"));
  for (const [k, v] of Object.entries(doc.quality || {})) {
    const row = side.appendChild(make("tr"));
    row.append(make("th", { scope: "row" }, k), make("td", { className: "num" },
      typeof v === "number" ? v.toFixed(3) : JSON.stringify(v)));
  }
  view.append(left, side);
  return view;
}

async function showDone(job) {
  const links = $("#downloads");
  links.replaceChildren(make("span", {}, "Download:"));
  for (const format of Object.keys(job.results)) {
    const b = make("button", { type: "button", className: "quiet" }, format.toUpperCase());
    b.dataset.format = format;
    b.setAttribute("aria-label", `Download ${format.toUpperCase()}`);
    b.addEventListener("click", () => download(job.id, format).catch((e) => { $("#result-error").textContent = e.message; }));
    links.append(b);
  }
  const doc = await api(`/v1/jobs/${job.id}/result?format=json`);
  const view = doc.kind === "skeleton" ? skeletonView(doc, job) : await translationView(doc, job);
  $("#result-body").replaceChildren(view);
}

function showStatus(job) {
  const pct = Math.round(job.progress.fraction * 100);
  $("#result-status").textContent = `${job.status} · ${pct} % · ${job.progress.stage}`;
  $("#result-status").className = `status-${job.status}`;
  $("#result-error").textContent = job.error ? problemText(job.error) : "";
}

/** Show job `id`: follow it while it runs, then its result. */
export async function showResult(id) {
  stopResult();
  $("#result-body").replaceChildren();
  $("#downloads").replaceChildren();
  $("#result-error").textContent = "";
  let job;
  try { job = await api(`/v1/jobs/${id}`); }
  catch (error) { $("#result-title").textContent = "Job"; $("#result-error").textContent = error.message; return; }
  $("#result-title").textContent = `${job.kind} job ${job.id}`;
  showStatus(job);
  if (job.status === "succeeded") { await showDone(job); return; }
  if (job.status !== "queued" && job.status !== "running") return;
  cleanup.push(follow(id, showStatus, async () => {
    const final = await api(`/v1/jobs/${id}`);
    showStatus(final);
    if (final.status === "succeeded") await showDone(final);
  }));
}

export function stopResult() {
  for (const stop of cleanup) stop();
  cleanup = [];
}
