// Two jobs side by side: their details, their artifacts' metrics with the change from A to B, and their
// frames (the model's frame, or a render's preview, and the path-traced reference) with the differences.

import { getJson, fileUrl, paths } from "../api.js";
import { fill, formatNumber, h } from "../dom.js";
import { problemBox, sceneLabel, shortId, stateBadge } from "../components.js";
import { frameViewer } from "./frames.js";

const FRAMES = ["frame.png", "preview.png"]; // the first an artifact has is its frame
const REFERENCE = "reference.png";

async function load(jobId) {
  const job = await getJson(paths.job(jobId));
  const manifest = job.artifact_id ? await getJson(paths.artifact(job.artifact_id)) : null;
  return { job, manifest, names: new Set(manifest?.files.map((f) => f.name) ?? []) };
}

/** B − A with its sign ("0" when equal), or "" when either is not a number. */
function delta(a, b) {
  if (typeof a !== "number" || typeof b !== "number") return "";
  const d = b - a;
  return d === 0 ? "0" : `${d > 0 ? "+" : "−"}${formatNumber(Math.abs(d))}`;
}

function metricsTable(a, b) {
  const keys = [...new Set([...Object.keys(a.manifest?.metrics ?? {}), ...Object.keys(b.manifest?.metrics ?? {})])].sort();
  if (!keys.length) return h("p", { class: "muted" }, "Neither job has an artifact with metrics.");
  const [ma, mb] = [a.manifest?.metrics ?? {}, b.manifest?.metrics ?? {}];
  return h("div", { class: "table-wrap" }, h("table", { class: "table", id: "compare-metrics" },
    h("thead", {}, h("tr", {}, ["Metric", "A", "B", "B − A"].map((t) => h("th", {}, t)))),
    h("tbody", {}, keys.map((key) => h("tr", { "data-metric": key },
      h("th", {}, key), h("td", { class: "num" }, formatNumber(ma[key])), h("td", { class: "num" }, formatNumber(mb[key])),
      h("td", { class: "num delta" }, delta(ma[key], mb[key])))))));
}

async function frames(a, b) {
  const frameOf = (side) => FRAMES.find((name) => side.names.has(name));
  const [fa, fb] = [frameOf(a), frameOf(b)];
  if (!fa || !fb) return h("p", { class: "muted" }, "Both jobs need an artifact with a frame to compare frames.");
  const panels = [
    { label: "A frame", url: await fileUrl(a.job.artifact_id, fa) },
    { label: "B frame", url: await fileUrl(b.job.artifact_id, fb) },
    { label: "frame difference", difference: ["A frame", "B frame"] },
  ];
  if (a.names.has(REFERENCE) && b.names.has(REFERENCE)) {
    panels.push(
      { label: "A reference", url: await fileUrl(a.job.artifact_id, REFERENCE) },
      { label: "B reference", url: await fileUrl(b.job.artifact_id, REFERENCE) },
      { label: "reference difference", difference: ["A reference", "B reference"] });
  }
  return frameViewer(panels);
}

function summary(letter, { job }) {
  return h("div", { class: "card compared", "data-side": letter },
    h("h3", {}, `${letter}: `, h("a", { href: `#/jobs/${encodeURIComponent(job.id)}`, title: job.id }, shortId(job.id)), " ", stateBadge(job.state)),
    h("p", {}, job.kind, " of ", sceneLabel(job.scene), ` · preset ${job.preset} · seed ${job.seed}`));
}

export function compareView(idA, idB) {
  const element = h("section", { class: "compare-jobs" }, h("a", { href: "#/jobs", class: "back" }, "← Jobs"),
    h("h2", {}, "Compare two jobs"), h("p", {}, "Loading…"));
  let disposed = false;
  Promise.all([load(idA), load(idB)]).then(async ([a, b]) => {
    const viewer = await frames(a, b);
    if (disposed) return;
    fill(element, h("a", { href: "#/jobs", class: "back" }, "← Jobs"), h("h2", {}, "Compare two jobs"),
      h("div", { class: "sides" }, summary("A", a), summary("B", b)),
      h("section", { class: "card" }, h("h3", {}, "Metrics"), metricsTable(a, b)),
      h("section", { class: "card" }, h("h3", {}, "Frames"), viewer));
  }).catch((error) => { if (!disposed) fill(element, problemBox(error)); });
  return { element, dispose() { disposed = true; } };
}
