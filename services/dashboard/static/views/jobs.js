// The job list, newest first: polled every few seconds, with the unfinished jobs' states and progress
// followed live over their event streams (a few at a time: a browser opens few connections per server).

import { getJson, paths } from "../api.js";
import { formatTime, fill, h } from "../dom.js";
import { follow } from "../events.js";
import { TERMINAL, problemBox, progressBar, sceneLabel, shortId, stateBadge } from "../components.js";

const POLL_MS = 3000;
const PAGE = 50, MAX_LIMIT = 200; // the API's largest page
const MAX_STREAMS = 3;
const STATES = ["", "QUEUED", "RUNNING", "SUCCEEDED", "FAILED", "CANCELLED"];

export function jobsView() {
  const rows = new Map(); // job id -> {job, element}
  const followed = new Map(); // job id -> stop following
  const body = h("tbody");
  const status = h("div", { class: "status" });
  const filter = h("select", { id: "state-filter", "aria-label": "state" },
    STATES.map((s) => h("option", { value: s }, s || "all states")));
  const older = h("button", { type: "button", id: "older", class: "link", hidden: true }, "Show older jobs");
  let limit = PAGE;
  let timer = null;
  let disposed = false;

  const row = (job) => h("tr", { "data-job": job.id, class: "job-row" },
    h("td", {}, h("a", { href: `#/jobs/${encodeURIComponent(job.id)}`, class: "job-link", title: job.id }, shortId(job.id))),
    h("td", {}, job.kind),
    h("td", { class: "scene" }, sceneLabel(job.scene)),
    h("td", {}, job.preset),
    h("td", {}, stateBadge(job.state), job.cancel_requested && !TERMINAL.has(job.state) ? " cancelling" : ""),
    h("td", {}, progressBar(job.progress, job.state)),
    h("td", {}, formatTime(job.created_at)));

  function show(job) {
    const element = row(job);
    const known = rows.get(job.id);
    if (known) known.element.replaceWith(element);
    rows.set(job.id, { job, element });
    return element;
  }

  function onEvent(jobId, event) {
    const known = rows.get(jobId);
    if (!known || !event) return;
    if (event.type === "progress") show({ ...known.job, progress: event.data });
    else if (event.type === "state") show({ ...known.job, state: event.data.state });
  }

  function followUnfinished(jobs) {
    const wanted = jobs.filter((j) => !TERMINAL.has(j.state)).slice(0, MAX_STREAMS).map((j) => j.id);
    for (const [id, stop] of followed) {
      if (!wanted.includes(id)) { stop(); followed.delete(id); }
    }
    for (const id of wanted) {
      if (!followed.has(id)) followed.set(id, follow(id, (event) => onEvent(id, event)));
    }
  }

  async function refresh() {
    try {
      const state = filter.value ? `&state=${encodeURIComponent(filter.value)}` : "";
      const page = await getJson(paths.jobs(`?limit=${limit}${state}`));
      if (disposed) return;
      rows.clear();
      fill(body, page.items.map(show));
      older.hidden = !page.next_cursor || limit >= MAX_LIMIT;
      fill(status, page.items.length ? null : h("p", { class: "empty" }, "No jobs yet: submit one."));
      followUnfinished(page.items);
    } catch (error) {
      if (!disposed) fill(status, problemBox(error));
    }
    if (!disposed) timer = setTimeout(refresh, POLL_MS);
  }

  const reload = () => { clearTimeout(timer); refresh(); };
  filter.addEventListener("change", reload);
  older.addEventListener("click", () => { limit = Math.min(limit + PAGE, MAX_LIMIT); reload(); });
  refresh();
  const element = h("section", { class: "jobs" },
    h("div", { class: "toolbar" }, h("h2", {}, "Jobs"), filter, h("a", { href: "#/submit", class: "button" }, "Submit a job")),
    h("table", { class: "table", id: "jobs-table" },
      h("thead", {}, h("tr", {}, ["Job", "Kind", "Scene", "Preset", "State", "Progress", "Created"].map((t) => h("th", {}, t)))),
      body),
    older, status);
  return {
    element,
    dispose() {
      disposed = true;
      clearTimeout(timer);
      for (const stop of followed.values()) stop();
    },
  };
}
