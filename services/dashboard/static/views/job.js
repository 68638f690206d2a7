// One job: its state and live progress, a cancel button, and four tabs: overview (details, plan, config,
// events and log), files (the artifact's files with PNG previews), report (speed against error) and
// compare (the model's frame over the path-traced reference, split by a slider, and both with their
// difference in the frame viewer). A failed job shows its cause in one line, its traceback collapsed.

import { ApiError, fileUrl, getJson, paths, postJson } from "../api.js";
import { fill, formatBytes, formatNumber, formatSeconds, formatTime, h } from "../dom.js";
import { follow } from "../events.js";
import { TERMINAL, problemBox, progressBar, sceneLabel, stateBadge } from "../components.js";
import { speedErrorPlot } from "../plot.js";
import { frameViewer } from "./frames.js";

const TABS = [["overview", "Overview"], ["files", "Files"], ["report", "Report"], ["compare", "Compare"]];
const MAX_EVENT_ROWS = 300;
const REFERENCE = "reference.png", FRAME = "frame.png", REPORT = "report.json";

/** A log message of several lines (a traceback): its last line, the rest collapsed under it. */
function logMessage(message) {
  const lines = message.trimEnd().split("\n");
  if (lines.length === 1) return message;
  return h("details", { class: "traceback" },
    h("summary", {}, `${lines[lines.length - 1]} (traceback, ${lines.length} lines)`), h("pre", {}, message));
}

export function jobView(jobId, requestedTab) {
  const tab = TABS.some(([name]) => name === requestedTab) ? requestedTab : "overview";
  const header = h("div", { class: "job-header" });
  const content = h("div", { class: "tab-content", id: `tab-${tab}` }, h("p", {}, "Loading…"));
  const events = [];
  let job = null;
  let finishedWhenLoaded = false;
  let disposed = false;
  let stop = () => {};

  const tabs = h("nav", { class: "tabs" }, TABS.map(([name, label]) => h("a", {
    href: `#/jobs/${encodeURIComponent(jobId)}${name === "overview" ? "" : `/${name}`}`,
    class: name === tab ? "tab active" : "tab", "data-tab": name,
  }, label)));

  // The header is built once and its parts updated, so the cancel button stays the same element while
  // progress streams in (a button replaced between mousedown and mouseup would swallow the click).
  const stateSlot = h("span"), progressSlot = h("div");
  const titleSlot = h("h2"), idSlot = h("div", { class: "job-id" });
  const cancelStatus = h("span", { class: "cancel-status" });
  const cancel = h("button", { type: "button", id: "cancel", class: "danger", hidden: true }, "Cancel");
  cancel.addEventListener("click", async () => {
    cancel.disabled = true;
    try {
      job = await postJson(paths.cancel(job.id));
      renderHeader();
    } catch (error) {
      cancel.disabled = false;
      cancelStatus.replaceChildren(problemBox(error));
    }
  });
  const compareWith = h("a", { href: `#/jobs?pick=${encodeURIComponent(jobId)}`, id: "compare-with" }, "Compare with…");
  // A failure's cause and traceback are filled in place, so an opened traceback stays open.
  const cause = h("div", { class: "cause" }), tracebackSlot = h("div");
  const failure = h("div", { class: "problem failure", hidden: true }, cause, tracebackSlot);
  fill(header, h("div", { class: "title-row" }, titleSlot, stateSlot, compareWith, cancel), idSlot, progressSlot, failure, cancelStatus);

  function renderFailure() {
    failure.hidden = !job.error;
    cause.textContent = cause.title = job.error ?? "";
    const traceback = events.find((e) => e.type === "log" && e.data.message?.startsWith("Traceback"));
    if (traceback && !tracebackSlot.firstChild) {
      fill(tracebackSlot, h("details", { class: "traceback" }, h("summary", {}, "Traceback"), h("pre", {}, traceback.data.message)));
    }
  }

  function renderHeader() {
    fill(titleSlot, h("span", { class: "kind" }, job.kind), " of ", h("span", { class: "scene" }, sceneLabel(job.scene)));
    fill(idSlot, job.id, " · preset ", job.preset);
    fill(stateSlot, stateBadge(job.state));
    fill(progressSlot, progressBar(job.progress, job.state));
    renderFailure();
    cancel.hidden = TERMINAL.has(job.state);
    if (job.cancel_requested) {
      cancel.disabled = true;
      cancel.textContent = "Cancelling…";
    }
  }

  async function reload() {
    try {
      job = await getJson(paths.job(jobId));
    } catch (error) {
      if (!disposed) fill(content, problemBox(error));
      return;
    }
    if (disposed) return;
    renderHeader();
    renderTab();
  }

  // Events arrive in bursts (a finished job replays all of them at once): draw once per frame.
  let drawPending = false;
  function draw() {
    drawPending = false;
    if (disposed || !job) return;
    renderHeader();
    if (tab === "overview") renderEvents();
  }

  function onEvent(event) {
    if (disposed) return;
    if (event === null) { // the final state: a job that finished while shown now has its artifact (or error)
      if (!finishedWhenLoaded) reload();
      return;
    }
    events.push(event);
    if (!job) return;
    if (event.type === "progress") job = { ...job, progress: event.data };
    if (event.type === "state") job = { ...job, state: event.data.state };
    if (!drawPending) {
      drawPending = true;
      requestAnimationFrame(draw);
    }
  }

  // ----------------------------------------------------------------- overview
  const eventsBody = h("tbody");
  const log = h("div", { class: "log", id: "log" });

  function eventSummary(event) {
    const d = event.data;
    if (event.type === "state") return `${d.previous ?? ""} → ${d.state}${d.message ? `: ${d.message}` : ""}${d.error ? ` (${d.error})` : ""}`;
    if (event.type === "progress") return [d.step != null ? `step ${d.step}/${d.total}` : "", d.loss != null ? `loss ${formatNumber(d.loss)}` : "", d.eta_s != null ? `ETA ${formatSeconds(d.eta_s)}` : ""].filter(Boolean).join(", ");
    return d.message !== undefined ? logMessage(d.message) : JSON.stringify(d);
  }

  function renderEvents() {
    fill(eventsBody, events.slice(-MAX_EVENT_ROWS).map((event) => h("tr", { class: `event event-${event.type}` },
      h("td", {}, event.seq), h("td", {}, formatTime(event.time)), h("td", {}, event.type), h("td", {}, eventSummary(event)))));
    fill(log, events.filter((e) => e.type === "log").map((e) => h("div", { class: "log-line" }, `${formatTime(e.time)}  `, logMessage(e.data.message))));
  }

  function overview() {
    const plan = job.plan;
    const details = [
      ["Job", job.id], ["Kind", job.kind], ["Scene", sceneLabel(job.scene)], ["Preset", job.preset], ["Seed", job.seed],
      ["Priority", job.priority], ["Attempts", `${job.attempts} of ${job.max_attempts}`], ["Created", formatTime(job.created_at)],
      ["Started", formatTime(job.started_at)], ["Finished", formatTime(job.finished_at)], ["Artifact", job.artifact_id ?? ""],
    ];
    renderEvents();
    return [
      h("section", { class: "card" }, h("h3", {}, "Details"),
        h("dl", { class: "details" }, details.map(([k, v]) => [h("dt", {}, k), h("dd", {}, String(v))]))),
      h("section", { class: "card", id: "plan" }, h("h3", {}, "Plan"),
        plan ? [
          h("p", {}, plan.summary, " ", h("span", { class: "muted" }, `(estimated ${formatSeconds(plan.estimated_seconds)})`)),
          h("div", { class: "table-wrap" }, h("table", { class: "table" }, h("thead", {}, h("tr", {}, h("th", {}, "Part"), h("th", {}, "Choice"), h("th", {}, "Why"))),
            h("tbody", {}, plan.items.map((item) => h("tr", {}, h("td", {}, item.name), h("td", {}, item.choice), h("td", {}, item.reason)))))),
        ] : h("p", {}, "No plan.")),
      h("section", { class: "card" }, h("h3", {}, "Config"), h("pre", { class: "config" }, JSON.stringify(job.config, null, 2))),
      h("section", { class: "card" }, h("h3", {}, "Log"), log),
      h("section", { class: "card" }, h("h3", {}, "Events"),
        h("div", { class: "table-wrap" }, h("table", { class: "table events", id: "events" },
          h("thead", {}, h("tr", {}, ["#", "Time", "Type", "What"].map((t) => h("th", {}, t)))), eventsBody))),
    ];
  }

  // ----------------------------------------------------------------- artifact tabs
  async function manifest() {
    if (!job.artifact_id) {
      throw new Error(TERMINAL.has(job.state) ? `This job has no artifact (${job.state}).` : "The artifact appears when the job succeeds.");
    }
    return getJson(paths.artifact(job.artifact_id));
  }

  async function image(name, alt, attrs = {}) {
    const img = h("img", { alt, class: "preview", ...attrs });
    img.src = await fileUrl(job.artifact_id, name);
    await img.decode().catch(() => {});
    return img;
  }

  async function download(entry) {
    const link = h("a", { href: await fileUrl(job.artifact_id, entry.name), download: entry.name.split("/").pop() }, "download");
    link.click();
  }

  async function files() {
    const found = await manifest();
    const pngs = found.files.filter((f) => f.media_type === "image/png");
    const previews = await Promise.all(pngs.map(async (f) => h("figure", { class: "figure" }, await image(f.name, f.name, { "data-file": f.name }), h("figcaption", {}, f.name))));
    return [
      h("section", { class: "card" }, h("h3", {}, "Previews"), previews.length ? h("div", { class: "gallery" }, previews) : h("p", {}, "No PNG files.")),
      h("section", { class: "card" }, h("h3", {}, "Files of ", h("code", {}, found.artifact_id)),
        h("div", { class: "table-wrap" }, h("table", { class: "table", id: "files" },
          h("thead", {}, h("tr", {}, ["Name", "Media type", "Size", "Digest", ""].map((t) => h("th", {}, t)))),
          h("tbody", {}, found.files.map((f) => h("tr", {},
            h("td", {}, f.name), h("td", {}, f.media_type), h("td", { class: "num" }, formatBytes(f.size)),
            h("td", { class: "digest", title: f.digest }, f.digest.slice(0, 19)),
            h("td", {}, h("button", { type: "button", class: "link", onclick: () => download(f) }, "Download")))))))),
      h("section", { class: "card" }, h("h3", {}, "Metrics"), keyValues(found.metrics)),
      Object.keys(found.annotations ?? {}).length
        ? h("section", { class: "card", id: "annotations" }, h("h3", {}, "Annotations"), keyValues(found.annotations)) : null,
    ];
  }

  function formatValue(key, value) {
    if (typeof value === "object" && value !== null) return JSON.stringify(value);
    if (typeof value === "number" && /bytes$/.test(key)) return formatBytes(value);
    if (typeof value === "number" && /seconds/.test(key)) return formatSeconds(value);
    return formatNumber(value);
  }

  function keyValues(object) {
    const entries = Object.entries(object ?? {});
    if (!entries.length) return h("p", { class: "muted" }, "None.");
    return h("div", { class: "table-wrap" }, h("table", { class: "table kv" }, h("tbody", {}, entries.map(([k, v]) => h("tr", {}, h("th", {}, k),
      h("td", { class: "num" }, formatValue(k, v)))))));
  }

  function equalTime(ratio) {
    // none in reports from before the ratio was recorded; "Infinity" for a broken model (flagged above)
    if (!ratio || typeof ratio.flip !== "number" || typeof ratio.psnr !== "number") return null;
    return h("p", { id: "equal-time-ratio" },
      `At its own error the model's frame takes ${formatNumber(ratio.flip, 2)}x path tracing's time by FLIP and `
      + `${formatNumber(ratio.psnr, 2)}x by PSNR (below 1: faster than the path tracer it replaces).`);
  }

  async function report() {
    const found = await manifest();
    if (!found.files.some((f) => f.name === REPORT)) return h("p", {}, "This artifact has no report.");
    const data = await getJson(paths.file(job.artifact_id, REPORT));
    if (!data.model || !Array.isArray(data.path_tracing)) {
      return h("section", { class: "card" }, h("h3", {}, "Report"),
        h("p", { class: "muted" }, `A ${job.kind} job trains no model: its report has no speed-against-error curve.`), keyValues(data));
    }
    const points = [...data.path_tracing.map((p) => ["path tracing", p]), ["equal time", data.path_tracing_equal_time], [data.kind, data.model]];
    return [
      data.worse_than_one_spp ? h("div", { class: "problem" }, "The model's frame is worse than 1-spp path tracing of the same view: it is not usable.") : null,
      h("section", { class: "card" }, h("h3", {}, "Speed against error"), equalTime(data.equal_time_ratio),
        h("div", { class: "plots", id: "speed-error" }, speedErrorPlot(data, "flip", "FLIP"), speedErrorPlot(data, "relative_mse", "relative MSE"))),
      h("section", { class: "card" }, h("h3", {}, "Frames against the reference"),
        h("div", { class: "table-wrap" }, h("table", { class: "table", id: "report-table" },
          h("thead", {}, h("tr", {}, ["Method", "Frame", "Time per frame", "FLIP", "PSNR (dB)", "Relative MSE"].map((t) => h("th", {}, t)))),
          h("tbody", {}, points.map(([method, p]) => h("tr", { class: method === data.kind ? "model-row" : "" },
            h("td", {}, method), h("td", {}, p.label), h("td", { class: "num" }, formatSeconds(p.seconds_per_frame)),
            h("td", { class: "num" }, formatNumber(p.error.flip)), h("td", { class: "num" }, formatNumber(p.error.psnr)),
            h("td", { class: "num" }, formatNumber(p.error.relative_mse)))))))),
      h("section", { class: "card" }, h("h3", {}, "Cost"), keyValues({
        training_seconds: data.training_seconds, training_samples: data.training_samples,
        training_samples_per_s: data.training_samples_per_s, seconds_per_query: data.seconds_per_query,
        parameter_bytes: data.parameter_bytes, peak_rss_bytes: data.peak_rss_bytes, peak_gpu_bytes: data.peak_gpu_bytes,
      })),
      h("section", { class: "card" }, h("h3", {}, "Method figures"), keyValues(data.method_metrics)),
    ];
  }

  async function compare() {
    const found = await manifest();
    const names = new Set(found.files.map((f) => f.name));
    if (!names.has(REFERENCE) || !names.has(FRAME)) {
      return h("p", {}, `This artifact has no ${REFERENCE} and ${FRAME} to compare (a ${job.kind} job trains no model).`);
    }
    const [reference, frame] = await Promise.all([
      image(REFERENCE, "path-traced reference", { id: "compare-reference" }),
      image(FRAME, "model frame", { id: "compare-frame" }),
    ]);
    frame.classList.add("over");
    const divider = h("div", { class: "divider" });
    const slider = h("input", { type: "range", min: 0, max: 100, value: 50, step: 0.5, id: "compare-slider", "aria-label": "split" });
    const split = () => {
      frame.style.clipPath = `inset(0 0 0 ${slider.value}%)`;
      divider.style.left = `${slider.value}%`;
    };
    slider.addEventListener("input", split);
    split();
    const stage = h("div", { class: "compare", id: "compare" }, reference, frame, divider);
    const drag = (event) => {
      if (event.buttons !== 1) return;
      const box = stage.getBoundingClientRect();
      slider.value = String(Math.min(100, Math.max(0, (100 * (event.clientX - box.left)) / box.width)));
      split();
    };
    stage.addEventListener("pointerdown", drag);
    stage.addEventListener("pointermove", drag);
    const viewer = await frameViewer([
      { label: "reference", url: reference.src }, { label: "frame", url: frame.src },
      { label: "difference", difference: ["reference", "frame"] },
    ]);
    return [
      h("section", { class: "card" }, h("h3", {}, "Model frame over the reference"),
        h("div", { class: "compare-labels" }, h("span", {}, "◀ reference (converged path tracing)"), h("span", {}, `${job.kind} model frame ▶`)),
        stage, slider),
      h("section", { class: "card", id: "side-by-side" }, h("h3", {}, "Side by side"), viewer),
    ];
  }

  async function renderTab() {
    try {
      const parts = tab === "overview" ? overview() : await { files, report, compare }[tab]();
      if (!disposed) fill(content, parts);
    } catch (error) {
      if (!disposed) fill(content, error instanceof ApiError ? problemBox(error) : h("p", { class: "muted" }, error.message));
    }
  }

  const element = h("section", { class: "job" }, h("a", { href: "#/jobs", class: "back" }, "← Jobs"), header, tabs, content);
  getJson(paths.job(jobId)).then((found) => {
    if (disposed) return;
    job = found;
    finishedWhenLoaded = TERMINAL.has(found.state);
    renderHeader();
    renderTab().then(() => { if (!disposed) stop = follow(jobId, onEvent); });
  }, (error) => fill(content, problemBox(error)));
  return { element, dispose() { disposed = true; stop(); } };
}
