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

function actionsCell(job, name) {
  const actions = make("td", { className: "row actions" });
  const open = make("a", { href: `/jobs/${job.id}` }, "open");
  open.setAttribute("aria-label", `Open job of ${name}`);
  open.addEventListener("click", (e) => { e.preventDefault(); navigate(`/jobs/${job.id}`); });
  actions.append(open);
  if (ACTIVE.has(job.status)) {
    actions.append(button("cancel", `Cancel job of ${name}`, () => cancel(job.id)));
  } else if (job.status !== "succeeded") {
    actions.append(button("retry", `Retry job of ${name}`, () => retry(job)));
  }
  return actions;
}

function statusCell(job) {
  const status = make("td", { className: `status status-${job.status}` }, job.status);
  if (job.error) status.title = problemText(job.error);
  return status;
}

function progressCell(job, name) {
  const bar = make("progress", { max: 1, value: job.progress.fraction });
  bar.setAttribute("aria-label", `Progress of ${name}`);
  const cell = make("td", { className: "progress" });
  cell.append(bar, make("span", { className: "pct" }, ` ${percent(job)}`));
  return cell;
}

function renderRow(job) {
  const row = make("tr");
  const name = names.get(job.recording_id) || job.recording_id;
  row.dataset.job = job.id;
  row.dataset.status = job.status;
  row.append(make("td", {}, new Date(job.created_at).toLocaleTimeString()),
    make("td", {}, job.kind), make("td", {}, name), statusCell(job), progressCell(job, name),
    actionsCell(job, name));
  return row;
}

/** A new state of a listed job, changed in place: the buttons (and the keyboard focus on
 *  them) stay unless the actions themselves change. */
function update(job) {
  const row = document.querySelector(`#jobs tr[data-job="${job.id}"]`);
  if (!row) return;
  const name = names.get(job.recording_id) || job.recording_id;
  const before = row.dataset.status;
  row.dataset.status = job.status;
  row.querySelector("td.status").replaceWith(statusCell(job));
  row.querySelector("progress").value = job.progress.fraction;
  row.querySelector(".pct").textContent = ` ${percent(job)}`;
  if (ACTIVE.has(before) !== ACTIVE.has(job.status)) {
    row.querySelector("td.actions").replaceWith(actionsCell(job, name));
  }
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
