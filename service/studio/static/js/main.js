// The studio's entry: the API key (per tab), routing between the home page and /jobs/{id}.

import { api, apiKey, setApiKey } from "./api.js";
import { setupForm } from "./form.js";
import { loadJobs, setupJobs, stopJobs } from "./jobs.js";
import { showResult, stopResult } from "./result.js";

const $ = (sel) => document.querySelector(sel);

function askKey(message = "") {
  return new Promise((resolve) => {
    const dialog = $("#key-dialog");
    $("#key-error").textContent = message;
    $("#key-input").value = "";
    dialog.addEventListener("close", () => {
      setApiKey($("#key-input").value.trim());
      resolve();
    }, { once: true });
    dialog.showModal();
  });
}

/** Make sure the API answers this tab: ask for a key until it does (none in loopback mode). */
async function authenticate() {
  for (let message = "";;) {
    try {
      await api("/v1/jobs?limit=1");
      const key = apiKey();
      $("#who").textContent = key ? "API key set for this tab" : "local mode (no key needed)";
      $("#key-button").hidden = !key;
      return;
    } catch (error) {
      if (error.status !== 401) { $("#who").textContent = error.message; return; }
      await askKey(apiKey() ? "That key was refused." : message);
      message = "";
    }
  }
}

async function route() {
  const match = /^\/jobs\/([0-9a-z]+)$/.exec(location.pathname);
  stopResult();
  stopJobs();
  $("#home").hidden = Boolean(match);
  $("#result").hidden = !match;
  if (match) await showResult(match[1]); else await loadJobs();
}

export function go(path) {
  history.pushState({}, "", path);
  route();
}

async function main() {
  await authenticate();
  api.onUnauthorized = () => { setApiKey(""); authenticate().then(route); };
  $("#key-button").addEventListener("click", () => { askKey().then(authenticate).then(route); });
  const openapi = await api("/openapi.json");
  setupForm(openapi, () => loadJobs());
  setupJobs(go);
  for (const link of document.querySelectorAll("[data-nav]")) {
    link.addEventListener("click", (e) => { e.preventDefault(); go(link.getAttribute("href")); });
  }
  window.addEventListener("popstate", route);
  await route();
  document.body.dataset.ready = "true";
}

main();
