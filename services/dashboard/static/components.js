// Small pieces several views show the same way: a job's state, its progress, its scene, an error.

import { formatSeconds, h } from "./dom.js";

export const TERMINAL = new Set(["SUCCEEDED", "FAILED", "CANCELLED"]);

export function stateBadge(state) {
  return h("span", { class: `state state-${String(state).toLowerCase()}`, "data-state": state }, state);
}

/** A progress bar from a progress event's data (step, total, loss, samples_per_s, eta_s). */
export function progressBar(progress, state) {
  const done = state === "SUCCEEDED";
  const step = progress?.step, total = progress?.total;
  const fraction = done ? 1 : step != null && total ? Math.min(step / total, 1) : 0;
  const parts = [];
  if (step != null && total) parts.push(`${step}/${total}`);
  if (!TERMINAL.has(state) && progress?.eta_s != null) parts.push(`ETA ${formatSeconds(progress.eta_s)}`);
  if (progress?.loss != null) parts.push(`loss ${Number(progress.loss).toPrecision(3)}`);
  if (progress?.samples_per_s != null) parts.push(`${Math.round(progress.samples_per_s).toLocaleString()} samples/s`);
  const bar = h("div", { class: "bar" });
  bar.style.width = `${(100 * fraction).toFixed(1)}%`;
  return h("div", { class: "progress", "data-fraction": fraction.toFixed(3), title: parts.join(", ") },
    h("div", { class: "track" }, bar),
    h("span", { class: "progress-text" }, parts.join(" · ")));
}

/** How a job named its scene: built-in name, uploaded asset or inline spec. */
export function sceneLabel(scene) {
  const name = scene?.name ?? "";
  return scene?.source && scene.source !== "builtin" ? `${name} (${scene.source})` : name;
}

export function problemBox(error) {
  return h("div", { class: "problem", role: "alert" }, String(error.message || error));
}

export function shortId(id) {
  return id.replace(/^job-/, "").slice(0, 8);
}
