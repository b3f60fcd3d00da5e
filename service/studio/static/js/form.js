// The upload panel: dropped files uploaded with progress, their sniff summaries, and the job
// form generated from the API's schema.

import { api, ProblemError, problemText, upload } from "./api.js";
import { fieldsOf, kindForFormat, kindsOf, parseField } from "./schema.js";

const MAIN = new Set(["method", "units", "fps", "stations", "left_foot", "right_foot", "offsets",
  "acceleration_units"]);

const $ = (sel) => document.querySelector(sel);
const uploads = []; // {file, recording, row}
let kinds = [];

function make(tag, attrs = {}, text) {
  const node = document.createElement(tag);
  Object.assign(node, attrs);
  if (text !== undefined) node.textContent = text;
  return node;
}

/** "sensor-csv · 240 frames · 15 sensors · 60 fps" for a recording. */
export function summaryText(rec) {
  const s = rec.summary || {};
  const parts = [rec.format];
  if (s.frames !== undefined && s.frames !== null) parts.push(`${s.frames} frames`);
  if (Array.isArray(s.sensors)) parts.push(`${s.sensors.length} sensors`);
  if (Array.isArray(s.joints)) parts.push(`${s.joints.length} joints`);
  if (s.fps) parts.push(`${Number(s.fps).toFixed(4).replace(/\.?0+$/, "")} fps`);
  if (s.units) parts.push(s.units);
  return parts.join(" · ");
}

function addUpload(file) {
  const row = make("tr");
  const use = make("input", { type: "checkbox", checked: false, disabled: true });
  use.setAttribute("aria-label", `Run a job on ${file.name}`);
  const bar = make("progress", { max: 1, value: 0 });
  bar.setAttribute("aria-label", `Upload of ${file.name}`);
  const info = make("td", { className: "info" }, "uploading…");
  const cells = [make("td"), make("td", {}, file.name), make("td"), info];
  cells[0].append(use);
  cells[2].append(bar);
  row.append(...cells);
  row.dataset.file = file.name;
  $("#uploads tbody").append(row);
  $("#uploads").hidden = false;
  const entry = { file, recording: null, row, use };
  uploads.push(entry);
  upload(file, (f) => { bar.value = f; }).then((rec) => {
    entry.recording = rec;
    info.textContent = summaryText(rec);
    info.dataset.state = "ok";
    use.disabled = false;
    use.checked = kindForFormat(rec.format) !== "input";
    if (use.checked) chooseKind(kindForFormat(rec.format));
    if (rec.format === "tracker") renderFields(); else refreshInputs();
  }, (error) => {
    info.textContent = error instanceof ProblemError ? problemText(error.problem) : String(error);
    info.className = "info problem";
    info.dataset.state = "error";
    info.setAttribute("role", "alert");
  });
}

function chooseKind(kind) {
  if (kinds.some((k) => k.kind === kind) && $("#kind").value !== kind) {
    $("#kind").value = kind;
    renderFields();
  }
}

function fieldControl(field) {
  const id = `param-${field.name}`;
  let control;
  if (field.widget === "select") {
    control = make("select", { id, name: field.name });
    control.append(make("option", { value: "" }, `default${field.default !== null ? ` (${field.default})` : ""}`));
    for (const o of field.options) control.append(make("option", { value: String(o) }, String(o)));
  } else if (field.widget === "calibration") {
    control = make("select", { id, name: field.name });
    control.append(make("option", { value: "" }, "none: fit every joint"));
    loadCalibrations(control);
  } else if (field.widget === "json" || field.widget === "json-or-enum") {
    control = make("input", { id, name: field.name, type: "text", placeholder:
      field.widget === "json-or-enum" ? `${field.options.join(" / ")} or {…}` : '{"1": "pelvis"}' });
  } else {
    control = make("input", { id, name: field.name, type: field.widget === "number" ? "number" : "text",
      placeholder: field.default === null ? "auto" : String(field.default) });
    if (field.widget === "number") control.step = field.integer ? "1" : "any";
  }
  return control;
}

async function loadCalibrations(select) {
  try {
    const page = await api("/v1/jobs?status=succeeded&kind=skeleton&limit=50");
    for (const job of page.items) {
      select.append(make("option", { value: job.id },
        `job ${job.id.slice(-8)} · ${new Date(job.created_at).toLocaleString()}`));
    }
  } catch { /* no calibrations to offer */ }
}

function renderField(field, formats) {
  if (field.name === "stations" && !formats.includes("tracker")) return null;
  const wrap = make("div", { className: "field" });
  const control = fieldControl(field);
  control.dataset.field = field.name;
  const label = make("label", { htmlFor: control.id }, field.label);
  const error = make("span", { className: "problem", id: `${control.id}-error` });
  control.setAttribute("aria-describedby", error.id);
  wrap.append(label, control);
  if (field.description) wrap.append(make("span", { className: "hint" }, field.description));
  wrap.append(error);
  wrap.field = field;
  return wrap;
}

function renderFields() {
  const kind = kinds.find((k) => k.kind === $("#kind").value);
  const formats = uploads.filter((u) => u.recording).map((u) => u.recording.format);
  for (const box of ["#main-fields", "#more-fields"]) $(box).replaceChildren();
  if (!kind) return;
  for (const field of fieldsOf(window.bonefitOpenapi, kind.params)) {
    const node = renderField(field, formats);
    if (node) $(MAIN.has(field.name) ? "#main-fields" : "#more-fields").append(node);
  }
  refreshInputs();
}

function refreshInputs() {
  const kind = kinds.find((k) => k.kind === $("#kind").value);
  const box = $("#inputs-fields");
  box.replaceChildren();
  for (const [name, prop] of Object.entries(kind?.inputs?.properties || {})) {
    const wrap = make("div", { className: "field" });
    const select = make("select", { id: `input-${name}`, name });
    select.dataset.input = name;
    select.append(make("option", { value: "" }, "none"));
    for (const u of uploads.filter((x) => x.recording)) {
      select.append(make("option", { value: u.recording.id }, u.file.name));
    }
    wrap.append(make("label", { htmlFor: select.id }, prop.title || name), select);
    if (prop.description) wrap.append(make("span", { className: "hint" }, prop.description));
    box.append(wrap);
  }
}

async function collectParams() {
  const params = {};
  let ok = true;
  for (const wrap of document.querySelectorAll("#main-fields .field, #more-fields .field")) {
    const { field } = wrap;
    const control = wrap.querySelector("[data-field]");
    const error = wrap.querySelector(".problem");
    error.textContent = "";
    if (field.widget === "calibration") {
      if (control.value) {
        const doc = await api(`/v1/jobs/${control.value}/result?format=json`);
        params[field.name] = doc.offsets;
      }
      continue;
    }
    const parsed = parseField(field, control.value);
    if (parsed.error) { error.textContent = parsed.error; ok = false; }
    else if (parsed.value !== undefined) params[field.name] = parsed.value;
  }
  return ok ? params : null;
}

function showServerProblem(problem) {
  const field = String(problem.field || "").replace(/^params\./, "");
  const control = field && document.querySelector(`[data-field="${field}"]`);
  if (control) control.parentElement.querySelector(".problem").textContent = problemText(problem);
  else $("#form-error").textContent = problemText(problem);
}

async function submitJobs(event, onSubmitted) {
  event.preventDefault();
  $("#form-error").textContent = "";
  const chosen = uploads.filter((u) => u.recording && u.use.checked);
  if (!chosen.length) { $("#form-error").textContent = "Upload a recording and tick it first."; return; }
  const params = await collectParams().catch((e) => { showServerProblem(e.problem || {}); return null; });
  if (!params) return;
  const inputs = {};
  for (const select of document.querySelectorAll("#inputs-fields select")) {
    if (select.value) inputs[select.dataset.input] = select.value;
  }
  for (const u of chosen) {
    try {
      await api("/v1/jobs", { method: "POST", extraHeaders: { "Idempotency-Key": crypto.randomUUID() },
        body: { kind: $("#kind").value, recording_id: u.recording.id, params, inputs } });
      u.use.checked = false;
    } catch (error) {
      if (error instanceof ProblemError) { showServerProblem(error.problem); return; }
      throw error;
    }
  }
  onSubmitted();
}

/** Wire the upload panel; `onSubmitted()` after jobs were queued. */
export function setupForm(openapi, onSubmitted) {
  window.bonefitOpenapi = openapi;
  kinds = kindsOf(openapi);
  $("#kind").replaceChildren(...kinds.map((k) => make("option", { value: k.kind }, k.kind)));
  $("#kind").addEventListener("change", renderFields);
  renderFields();
  const drop = $("#drop");
  $("#file-input").addEventListener("change", (e) => {
    for (const file of e.target.files) addUpload(file);
    e.target.value = "";
  });
  drop.addEventListener("dragover", (e) => { e.preventDefault(); drop.classList.add("over"); });
  drop.addEventListener("dragleave", () => drop.classList.remove("over"));
  drop.addEventListener("drop", (e) => {
    e.preventDefault();
    drop.classList.remove("over");
    for (const file of e.dataTransfer.files) addUpload(file);
  });
  $("#job-form").addEventListener("submit", (e) => submitJobs(e, onSubmitted));
}
