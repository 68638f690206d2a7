// Frames compared pixel for pixel: each image drawn into a canvas at its own size and magnified by a whole
// factor without smoothing (one image pixel is zoom x zoom screen pixels), every view scrolled with the
// others, one exposure (in stops, applied in linear light) for every panel, and difference panels
// |a - b| computed from the two images' pixels.

import { h } from "../dom.js";

const ZOOMS = [1, 2, 4, 8, 16];
const FIT_PX = 320; // the first zoom is the largest whose width fits this

async function pixelsOf(url) {
  const img = new Image();
  img.src = url;
  await img.decode();
  const canvas = h("canvas", { width: img.naturalWidth, height: img.naturalHeight });
  const context = canvas.getContext("2d");
  context.drawImage(img, 0, 0);
  return context.getImageData(0, 0, canvas.width, canvas.height);
}

function difference(a, b) {
  const out = new ImageData(a.width, a.height);
  for (let i = 0; i < a.data.length; i += 4) {
    out.data[i] = Math.abs(a.data[i] - b.data[i]);
    out.data[i + 1] = Math.abs(a.data[i + 1] - b.data[i + 1]);
    out.data[i + 2] = Math.abs(a.data[i + 2] - b.data[i + 2]);
    out.data[i + 3] = 255;
  }
  return out;
}

const toLinear = (c) => (c <= 0.04045 ? c / 12.92 : ((c + 0.055) / 1.055) ** 2.4);
const toSrgb = (c) => (c <= 0.0031308 ? 12.92 * c : 1.055 * c ** (1 / 2.4) - 0.055);

/** The 8-bit sRGB value each 8-bit sRGB value becomes at `stops` of exposure. */
function exposureTable(stops) {
  const gain = 2 ** stops;
  return Uint8ClampedArray.from({ length: 256 }, (_, v) => Math.round(255 * toSrgb(Math.min(1, toLinear(v / 255) * gain))));
}

function exposed(pixels, table) {
  const out = new ImageData(pixels.width, pixels.height);
  for (let i = 0; i < pixels.data.length; i += 4) {
    out.data[i] = table[pixels.data[i]];
    out.data[i + 1] = table[pixels.data[i + 1]];
    out.data[i + 2] = table[pixels.data[i + 2]];
    out.data[i + 3] = pixels.data[i + 3];
  }
  return out;
}

/** Panels `{label, url}` (an image) or `{label, difference: [labelA, labelB]}` with a zoom and an exposure. */
export async function frameViewer(panels) {
  const loaded = new Map();
  await Promise.all(panels.filter((p) => p.url).map(async (p) => loaded.set(p.label, await pixelsOf(p.url))));
  const shown = panels.map((panel) => {
    if (!panel.difference) return { panel, pixels: loaded.get(panel.label) };
    const [a, b] = panel.difference.map((label) => loaded.get(label));
    if (a.width !== b.width || a.height !== b.height) {
      return { panel, problem: `the frames' sizes differ (${a.width}×${a.height} and ${b.width}×${b.height})` };
    }
    return { panel, pixels: difference(a, b) };
  });

  const widest = Math.max(...shown.filter((s) => s.pixels).map((s) => s.pixels.width));
  const fit = ZOOMS.filter((z) => z * widest <= FIT_PX).pop() ?? 1;
  const zoom = h("select", { id: "zoom", "aria-label": "zoom" },
    ZOOMS.map((z) => h("option", { value: z, selected: z === fit }, `${z}×`)));
  const exposure = h("input", { type: "range", id: "exposure", min: -6, max: 6, step: 0.5, value: 0, "aria-label": "exposure" });
  const stops = h("output", { for: "exposure", class: "stops" });

  const views = [];
  let syncing = false;
  const follow = (source) => {
    if (syncing) return;
    syncing = true;
    for (const view of views) {
      if (view !== source) {
        view.scrollLeft = source.scrollLeft;
        view.scrollTop = source.scrollTop;
      }
    }
    syncing = false;
  };
  const figures = shown.map(({ panel, pixels, problem }) => {
    if (problem) return h("figure", { class: "figure" }, h("p", { class: "muted" }, problem), h("figcaption", {}, panel.label));
    const canvas = h("canvas", { width: pixels.width, height: pixels.height, class: "pixels", "data-panel": panel.label });
    const view = h("div", { class: "viewport" }, canvas);
    view.addEventListener("scroll", () => follow(view));
    views.push(view);
    return h("figure", { class: "figure", "data-figure": panel.label }, view, h("figcaption", {}, panel.label));
  });

  const render = () => {
    const table = exposureTable(Number(exposure.value));
    const value = Number(exposure.value);
    stops.textContent = `${value > 0 ? "+" : ""}${value} EV`;
    shown.forEach(({ pixels }, i) => {
      if (!pixels) return;
      const canvas = figures[i].querySelector("canvas");
      canvas.getContext("2d").putImageData(exposed(pixels, table), 0, 0);
      canvas.style.width = `${pixels.width * Number(zoom.value)}px`;
      canvas.style.height = `${pixels.height * Number(zoom.value)}px`;
    });
  };
  zoom.addEventListener("change", render);
  exposure.addEventListener("input", render);
  render();
  return h("div", { class: "frame-viewer" },
    h("div", { class: "viewer-controls" },
      h("label", {}, "Zoom ", zoom),
      h("label", {}, "Exposure ", exposure, stops),
      h("button", { type: "button", class: "link", onclick: () => { exposure.value = "0"; render(); } }, "reset")),
    h("div", { class: "gallery frames" }, figures));
}
