// The job list, newest first: polled every few seconds, with the unfinished jobs' states and progress
// followed live over their event streams (a few at a time: a browser opens few connections per server).
// Its filters (kind, state) are kept in the address (#/jobs?kind=lsnif&state=FAILED), so a filtered view
// is a link; two jobs picked in it open their comparison (#/jobs?pick=<id> starts with one picked).

import { getJson, paths } from "../api.js";
import { fill, formatAge, formatSeconds, formatTime, h } from "../dom.js";
import { follow } from "../events.js";
import { TERMINAL, problemBox, progressBar, sceneLabel, shortId, stateBadge } from "../components.js";

const POLL_MS = 3000;
const PAGE = 50, MAX_LIMIT = 200; // the API's largest page
const MAX_STREAMS = 3;
const STATES = ["", "QUEUED", "RUNNING", "SUCCEEDED", "FAILED", "CANCELLED"];
const seconds = (iso) => Date.parse(iso) / 1000;

/** Start to finish, or "running for" until now; nothing before it starts. */
function duration(job, now) {
  if (!job.started_at) return "";
  if (job.finished_at) return formatSeconds(seconds(job.finished_at) - seconds(job.started_at));
  return `running for ${formatSeconds(now - seconds(job.started_at))}`;
}

export function jobsView(query, navigate) {
  const rows = new Map(); // job id -> {job, element}
  const followed = new Map(); // job id -> stop following
  const picked = new Set(query.getAll("pick"));
  const body = h("tbody");
  const status = h("div", { class: "status" });
  const stateFilter = h("select", { id: "state-filter", "aria-label": "state" },
    STATES.map((s) => h("option", { value: s, selected: s === (query.get("state") ?? "") }, s || "all states")));
  const kindOption = (name) => h("option", { value: name, selected: name === (query.get("kind") ?? "") }, name || "all kinds");
  const kindFilter = h("select", { id: "kind-filter", "aria-label": "kind" }, ["", query.get("kind")].filter((k) => k !== null).map(kindOption));
  const compare = h("button", { type: "button", id: "compare-selected", disabled: true }, "Compare");
  const older = h("button", { type: "button", id: "older", class: "link", hidden: true }, "Show older jobs");
  let limit = PAGE;
  let timer = null;
  let disposed = false;

  const onPick = (id, checked) => {
    if (checked) picked.add(id);
    else picked.delete(id);
    compare.disabled = picked.size !== 2;
  };
  compare.addEventListener("click", () => navigate(`#/compare/${[...picked].map(encodeURIComponent).join("/")}`));

  const row = (job) => {
    const now = Date.now() / 1000;
    const pick = h("input", {
      type: "checkbox", class: "pick", checked: picked.has(job.id), "aria-label": `pick ${job.id} to compare`,
      onchange: (event) => onPick(job.id, event.target.checked),
    });
    return h("tr", { "data-job": job.id, class: "job-row" },
      h("td", {}, pick),
      h("td", {}, h("a", { href: `#/jobs/${encodeURIComponent(job.id)}`, class: "job-link", title: job.id }, shortId(job.id))),
      h("td", { class: "kind" }, job.kind),
      h("td", { class: "scene" }, sceneLabel(job.scene)),
      h("td", { class: "wide" }, job.preset),
      h("td", {}, stateBadge(job.state), job.cancel_requested && !TERMINAL.has(job.state) ? " cancelling" : ""),
      h("td", { class: "wide" }, progressBar(job.progress, job.state)),
      h("td", { class: "num duration wide" }, duration(job, now)),
      h("td", { class: "num age", title: formatTime(job.created_at) }, formatAge(now - seconds(job.created_at))));
  };

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

  function filters() {
    const params = new URLSearchParams();
    if (kindFilter.value) params.set("kind", kindFilter.value);
    if (stateFilter.value) params.set("state", stateFilter.value);
    return params;
  }

  async function refresh() {
    try {
      const params = filters();
      params.set("limit", limit);
      const page = await getJson(paths.jobs(`?${params}`));
      if (disposed) return;
      rows.clear();
      fill(body, page.items.map(show));
      older.hidden = !page.next_cursor || limit >= MAX_LIMIT;
      const filtered = kindFilter.value || stateFilter.value;
      fill(status, page.items.length ? null : h("p", { class: "empty" }, filtered ? "No job matches." : "No jobs yet: submit one."));
      followUnfinished(page.items);
    } catch (error) {
      if (!disposed) fill(status, problemBox(error));
    }
    if (!disposed) timer = setTimeout(refresh, POLL_MS);
  }

  const reload = () => { clearTimeout(timer); refresh(); };
  const refilter = () => {
    const params = filters().toString();
    history.replaceState(null, "", `#/jobs${params ? `?${params}` : ""}`); // a link, without a new route
    reload();
  };
  stateFilter.addEventListener("change", refilter);
  kindFilter.addEventListener("change", refilter);
  older.addEventListener("click", () => { limit = Math.min(limit + PAGE, MAX_LIMIT); reload(); });
  getJson(paths.kinds).then((kinds) => {
    if (!disposed) fill(kindFilter, ["", ...kinds.items.map((k) => k.name)].map(kindOption));
  }, () => {}); // the list works without the kinds; it is the list that shows the error
  compare.disabled = picked.size !== 2;
  refresh();
  const element = h("section", { class: "jobs" },
    h("div", { class: "toolbar" }, h("h2", {}, "Jobs"), kindFilter, stateFilter, compare,
      h("a", { href: "#/submit", class: "button" }, "Submit a job")),
    h("div", { class: "table-wrap" }, h("table", { class: "table", id: "jobs-table" },
      h("thead", {}, h("tr", {}, [["", ""], ["Job", ""], ["Kind", ""], ["Scene", ""], ["Preset", "wide"], ["State", ""],
        ["Progress", "wide"], ["Duration", "num wide"], ["Age", "num"]].map(([t, cls]) => h("th", { class: cls || null }, t)))),
      body)),
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
