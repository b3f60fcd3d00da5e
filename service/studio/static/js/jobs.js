// The jobs panel: the tenant's jobs, filtered by status, live over SSE; cancel and retry.

import { api, follow, problemText } from "./api.js";

const LIVE_STREAMS = 4; // browsers allow ~6 connections per host: keep some for the rest
const ACTIVE = new Set(["queued", "running"]);
const $ = (sel) => document.querySelector(sel);
const streams = new Map(); // job id -> stop()
const names = new Map(); // recording id -> file name
let navigate = () => {};
let pollTimer = null;

function make(tag, attrs = {}, text) {
  const node = document.createElement(tag);
  Object.assign(node, attrs);
  if (text !== undefined) node.textContent = text;
  return node;
}

function percent(job) { return `${Math.round(job.progress.fraction * 100)} %`; }

function button(text, label, onClick) {
  const b = make("button", { type: "button", className: "quiet" }, text);
  b.setAttribute("aria-label", label);
  b.addEventListener("click", onClick);
  return b;
}

function renderRow(job, row = make("tr")) {
  row.dataset.job = job.id;
  row.dataset.status = job.status;
  const name = names.get(job.recording_id) || job.recording_id;
  const bar = make("progress", { max: 1, value: job.progress.fraction });
  bar.setAttribute("aria-label", `Progress of ${name}`);
  const status = make("td", { className: `status-${job.status}` }, job.status);
  if (job.error) status.title = problemText(job.error);
  const progress = make("td");
  progress.append(bar, make("span", { className: "pct" }, ` ${percent(job)}`));
  const actions = make("td", { className: "row" });
  const open = make("a", { href: `/jobs/${job.id}` }, "open");
  open.setAttribute("aria-label", `Open job of ${name}`);
  open.addEventListener("click", (e) => { e.preventDefault(); navigate(`/jobs/${job.id}`); });
  actions.append(open);
  if (ACTIVE.has(job.status)) {
    actions.append(button("cancel", `Cancel job of ${name}`, () => cancel(job.id)));
  } else if (job.status !== "succeeded") {
    actions.append(button("retry", `Retry job of ${name}`, () => retry(job)));
  }
  row.replaceChildren(make("td", {}, new Date(job.created_at).toLocaleTimeString()),
    make("td", {}, job.kind), make("td", {}, name), status, progress, actions);
  return row;
}

function update(job) {
  const row = document.querySelector(`#jobs tr[data-job="${job.id}"]`);
  if (row) renderRow(job, row);
}

async function cancel(id) {
  try { update(await api(`/v1/jobs/${id}/cancel`, { method: "POST" })); }
  catch (error) { alert(error.message); }
}

async function retry(job) {
  await api("/v1/jobs", { method: "POST", extraHeaders: { "Idempotency-Key": crypto.randomUUID() },
    body: { kind: job.kind, recording_id: job.recording_id, params: job.params, inputs: job.inputs } });
  await loadJobs();
}

function watch(jobs) {
  for (const [id, stop] of streams) {
    if (!jobs.some((j) => j.id === id && ACTIVE.has(j.status))) { stop(); streams.delete(id); }
  }
  let polled = false;
  for (const job of jobs.filter((j) => ACTIVE.has(j.status))) {
    if (streams.has(job.id)) continue;
    if (streams.size >= LIVE_STREAMS) { polled = true; continue; }
    streams.set(job.id, follow(job.id, update, () => { streams.delete(job.id); loadJobs(); }));
  }
  clearTimeout(pollTimer);
  if (polled) pollTimer = setTimeout(loadJobs, 2000);
}

async function loadNames() {
  const page = await api("/v1/recordings?limit=200");
  for (const rec of page.items) names.set(rec.id, rec.filename || rec.id);
}

/** Reload the list (with the status filter) and follow the active jobs. */
export async function loadJobs() {
  const status = $("#status-filter").value;
  const query = new URLSearchParams({ limit: "50", ...(status ? { status } : {}) });
  const [page] = await Promise.all([api(`/v1/jobs?${query}`), loadNames()]);
  $("#jobs tbody").replaceChildren(...page.items.map((job) => renderRow(job)));
  $("#jobs-empty").hidden = page.items.length > 0;
  watch(page.items);
}

/** Stop every live stream (leaving the page section). */
export function stopJobs() {
  for (const stop of streams.values()) stop();
  streams.clear();
  clearTimeout(pollTimer);
}

export function setupJobs(go) {
  navigate = go;
  $("#status-filter").addEventListener("change", loadJobs);
  $("#refresh-jobs").addEventListener("click", loadJobs);
}
