// Submitting a job on a built-in scene: the kinds, their presets (with the config each resolves to) and
// the scenes come from the server; an error names the field at fault, as the API's problem document does.

import { ApiError, getJson, paths, postJson } from "../api.js";
import { fill, h } from "../dom.js";
import { problemBox } from "../components.js";

export function submitView(navigate) {
  const status = h("div", { class: "status" });
  const form = h("form", { class: "submit card", id: "submit-form" }, h("p", {}, "Loading kinds and scenes…"));
  let disposed = false;

  function build(kinds, scenes) {
    const kind = h("select", { id: "kind", name: "kind" }, kinds.map((k) => h("option", { value: k.name }, k.name)));
    const preset = h("select", { id: "preset", name: "preset" });
    const scene = h("select", { id: "scene", name: "scene" }, scenes.map((s) => h("option", { value: s.name }, s.name)));
    const sceneHelp = h("p", { class: "help" });
    const resolved = h("pre", { class: "config", id: "preset-config" });
    const overrides = h("textarea", { id: "config", name: "config", rows: 4, placeholder: '{"spp": 64}', spellcheck: "false" });
    const seed = h("input", { id: "seed", name: "seed", type: "number", min: 0, value: 0 });
    const priority = h("input", { id: "priority", name: "priority", type: "number", min: -1000, max: 1000, value: 0 });
    const force = h("input", { id: "force", name: "force", type: "checkbox" });
    const fields = { kind, preset, scene, config: overrides, seed, priority, force };

    const currentKind = () => kinds.find((k) => k.name === kind.value);
    const showPreset = () => {
      const found = currentKind().presets.find((p) => p.name === preset.value);
      resolved.textContent = JSON.stringify(found?.config ?? {}, null, 2);
    };
    const showScene = () => { sceneHelp.textContent = scenes.find((s) => s.name === scene.value)?.description ?? ""; };
    const showKind = () => {
      const k = currentKind();
      fill(preset, k.presets.map((p) => h("option", { value: p.name, selected: p.name === "quick" }, p.name)));
      scene.value = k.example_scene;
      showPreset();
      showScene();
    };
    kind.addEventListener("change", showKind);
    preset.addEventListener("change", showPreset);
    scene.addEventListener("change", showScene);
    showKind();

    const field = (label, input, ...help) => h("div", { class: "field" }, h("label", { for: input.id }, label), input, help);
    fill(form,
      h("h2", {}, "Submit a job"),
      field("Kind", kind),
      field("Built-in scene", scene, sceneHelp),
      field("Preset", preset, h("details", {}, h("summary", {}, "Resolved config"), resolved)),
      field("Config overrides (JSON, optional)", overrides),
      h("div", { class: "row" }, field("Seed", seed), field("Priority", priority),
        h("div", { class: "field" }, h("label", { for: "force" }, force, " run even if identical work exists"))),
      h("button", { type: "submit", id: "submit" }, "Submit"),
      status);

    form.addEventListener("submit", async (event) => {
      event.preventDefault();
      for (const input of Object.values(fields)) input.removeAttribute("aria-invalid");
      let config = {};
      try {
        config = overrides.value.trim() ? JSON.parse(overrides.value) : {};
      } catch (error) {
        overrides.setAttribute("aria-invalid", "true");
        fill(status, problemBox(`config: not valid JSON: ${error.message}`));
        return;
      }
      const body = {
        kind: kind.value, scene: scene.value, preset: preset.value, config,
        seed: Number(seed.value), priority: Number(priority.value), force: force.checked,
      };
      try {
        const job = await postJson(paths.jobs(), body);
        navigate(`#/jobs/${encodeURIComponent(job.id)}`);
      } catch (error) {
        const name = error instanceof ApiError ? String(error.problem.field ?? "").split(".")[0] : "";
        fields[name]?.setAttribute("aria-invalid", "true");
        fill(status, problemBox(error));
      }
    });
  }

  Promise.all([getJson(paths.kinds), getJson(paths.scenes)]).then(
    ([kinds, scenes]) => { if (!disposed) build(kinds.items, scenes.items); },
    (error) => { if (!disposed) fill(form, problemBox(error)); });
  return { element: h("section", {}, form), dispose() { disposed = true; } };
}
