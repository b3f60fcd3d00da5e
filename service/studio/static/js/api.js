// The API from the browser: the tab's key as a bearer token, problems as errors, uploads with
// progress (XHR) and Server-Sent Events over fetch (EventSource cannot send a header).

const KEY = "bonefit.apiKey";

export function apiKey() { return sessionStorage.getItem(KEY) || ""; }
export function setApiKey(key) {
  if (key) sessionStorage.setItem(KEY, key); else sessionStorage.removeItem(KEY);
}

function headers(extra = {}) {
  const key = apiKey();
  return key ? { ...extra, Authorization: `Bearer ${key}` } : extra;
}

/** An RFC 9457 problem answered by the server. */
export class ProblemError extends Error {
  constructor(problem) {
    super(problemText(problem));
    this.problem = problem;
    this.status = problem.status || 0;
  }
}

/** "detail (field x, line 3)" for a problem document. */
export function problemText(problem) {
  const where = ["field", "sensor", "line", "column"]
    .filter((k) => problem[k] !== undefined && problem[k] !== null)
    .map((k) => `${k} ${problem[k]}`).join(", ");
  const text = problem.detail || problem.title || `HTTP ${problem.status}`;
  return where ? `${text} (${where})` : text;
}

async function problemOf(response) {
  const text = await response.text();
  try {
    const doc = JSON.parse(text);
    if (doc && typeof doc === "object") return { status: response.status, ...doc };
  } catch { /* not JSON */ }
  return { status: response.status, title: `HTTP ${response.status}`, detail: text.slice(0, 300) };
}

/** fetch with the key; the parsed JSON, or ProblemError. Notifies 401s to `onUnauthorized`. */
export async function api(path, { method = "GET", body, raw = false, extraHeaders = {} } = {}) {
  const init = { method, headers: headers(extraHeaders) };
  if (body !== undefined) {
    init.body = JSON.stringify(body);
    init.headers["Content-Type"] = "application/json";
  }
  const response = await fetch(path, init);
  if (!response.ok) {
    const problem = await problemOf(response);
    if (response.status === 401) api.onUnauthorized?.(problem);
    throw new ProblemError(problem);
  }
  return raw ? response : response.json();
}

/** Upload a File; `progress(fraction)` while it goes. Resolves to the recording. */
export function upload(file, progress) {
  return new Promise((resolve, reject) => {
    const xhr = new XMLHttpRequest();
    const query = new URLSearchParams({ filename: file.name, format: "auto" });
    xhr.open("POST", `/v1/recordings?${query}`);
    for (const [k, v] of Object.entries(headers({ "Content-Type": "application/octet-stream" }))) {
      xhr.setRequestHeader(k, v);
    }
    xhr.upload.onprogress = (e) => { if (e.lengthComputable) progress(e.loaded / e.total); };
    xhr.onload = () => {
      let doc = null;
      try { doc = JSON.parse(xhr.responseText); } catch { /* not JSON */ }
      if (xhr.status === 201) { progress(1); resolve(doc); return; }
      const problem = doc && typeof doc === "object" ? { status: xhr.status, ...doc }
        : { status: xhr.status, title: `HTTP ${xhr.status}`, detail: xhr.responseText.slice(0, 300) };
      if (xhr.status === 401) api.onUnauthorized?.(problem);
      reject(new ProblemError(problem));
    };
    xhr.onerror = () => reject(new ProblemError({ status: 0, detail: "the upload was interrupted" }));
    xhr.send(file);
  });
}

/** Parse an event stream's text; returns [events, rest] (rest: an unfinished event). */
export function parseEvents(text) {
  const events = [];
  const blocks = text.replace(/\r\n?/g, "\n").split("\n\n");
  const rest = blocks.pop();
  for (const block of blocks) {
    const event = { event: "message", data: [], id: null };
    for (const line of block.split("\n")) {
      if (!line || line.startsWith(":")) continue;
      const at = line.indexOf(":");
      const name = at < 0 ? line : line.slice(0, at);
      const value = at < 0 ? "" : line.slice(at + 1).replace(/^ /, "");
      if (name === "event") event.event = value;
      else if (name === "data") event.data.push(value);
      else if (name === "id") event.id = value;
    }
    if (event.data.length) events.push({ ...event, data: event.data.join("\n") });
  }
  return [events, rest];
}

/** Follow a job's events until it ends: `onJob(job)` per state; reconnects with Last-Event-ID.
 *  Returns a function that stops following. */
export function follow(jobId, onJob, onEnd) {
  const controller = new AbortController();
  let lastId = null;
  let stopped = false;
  (async () => {
    for (let failures = 0; !stopped && failures < 20;) {
      try {
        const extra = lastId ? { "Last-Event-ID": lastId } : {};
        const response = await fetch(`/v1/jobs/${jobId}/events`,
          { headers: headers(extra), signal: controller.signal });
        if (!response.ok) throw new ProblemError(await problemOf(response));
        const reader = response.body.pipeThrough(new TextDecoderStream()).getReader();
        let buffer = "";
        for (;;) {
          const { value, done } = await reader.read();
          if (done) break;
          const [events, rest] = parseEvents(buffer + value);
          buffer = rest;
          failures = 0;
          for (const event of events) {
            if (event.id) lastId = event.id;
            if (event.event === "end") { stopped = true; onEnd?.(); return; }
            onJob(JSON.parse(event.data));
          }
        }
      } catch (error) {
        if (stopped || error.name === "AbortError") return;
        if (error instanceof ProblemError && error.status < 500 && error.status !== 429) {
          onEnd?.(error); return;
        }
        failures += 1;
      }
      await new Promise((r) => setTimeout(r, Math.min(500 * 2 ** failures, 8000)));
    }
  })();
  return () => { stopped = true; controller.abort(); };
}

/** Save a result file (fetched with the key) under its server-given name. */
export async function download(jobId, format) {
  const response = await api(`/v1/jobs/${jobId}/result?format=${format}`, { raw: true });
  const blob = await response.blob();
  const match = /filename="([^"]+)"/.exec(response.headers.get("content-disposition") || "");
  const a = document.createElement("a");
  a.href = URL.createObjectURL(blob);
  a.download = match ? match[1] : `${jobId}.${format}`;
  document.body.append(a);
  a.click();
  a.remove();
  setTimeout(() => URL.revokeObjectURL(a.href), 10000);
}
