"""The traced data a `prt` job learns from and is measured on, built once per process and cached.

- The training set: for each training view, `rows_per_view` pixels that see geometry, their G-buffer
  inputs and their indirect transport rows (`transport`), plus the pixel maps training samples from and
  each row's training target, the mean of as many of its nearest rows as its object's rows call for
  (`neighbours`), as its Haar coefficients.
- The test set: the near and far held-out views and their G-buffers (their ground truth depends on the
  lighting: `evaluate.truth` path-traces it importance-sampled per held-out lighting).
- The box of the hash grid: what the camera sees from every view, padded.

Everything is a function of (scene, config, seed).
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field

import numpy as np
import torch

from workers.models.prt.config import PrtConfig
from workers.models.prt.gbuffer import SurfaceInputs, surface_inputs
from workers.models.prt.lighting import (
    lighting_cube,
    relit_tracer,
    training_lighting,
    uniform_cube,
    unit_mean,
)
from workers.models.prt.neighbours import smoothed_rows, smoothing_choices
from workers.models.prt.transport import trace_rows
from workers.models.prt.views import FAR, NEAR, TRAIN, pixel_rays, trajectory_cameras
from workers.nn.haar import cubemap_wavelets
from workers.render.integrator import PathTracer
from workers.scene.format.spec import Camera
from workers.scene.portability.reference import SceneRef

BOX_PADDING = 0.02  # of the box's diagonal, around every point a view sees
PIXEL_MAPS = ("uniform", "glossy", "transport_detail")
CACHE_SIZE = 8  # traced sets and tracers kept per process (a job needs four)
MAP_CHUNK = 4096  # rows per Haar transform of the pixel maps (float64 temporaries of ~100 MB, not GBs)
JUDGE_LIGHTINGS = 16  # training lightings the targets' smoothing is chosen under (`smoothing_choices`)
JUDGE_STREAM = 16  # their random stream (the rows draw from [seed, 15])


@dataclass
class TrainingSet:
    inputs: SurfaceInputs  # (P,) pixels, all hitting geometry
    rows: np.ndarray  # (P, 6 R^2, 3) float32 indirect transport
    box: np.ndarray  # (2, 3)
    map_weights: dict[str, np.ndarray]  # pixel map -> (P,) sampling weights
    # (P, 6 R^2, 3) float32: the Haar coefficients (`cubemap_wavelets`) of each row's training target, the
    # rows averaged once (`smoothing`). Under a lighting the target is their dot product with the lighting's
    # coefficients, and a wavelet's transport is one of them: no transform per step (with the pooled
    # lightings' cubes no longer needed, a default batch took 3.9-4.6 CPU ms against 14.1-16.2 on a loaded
    # machine, `PrtConfig.train`).
    target_wavelets: np.ndarray
    smoothing: dict[int, tuple[int, float]]  # object -> (rows averaged, direction weight) of its targets
    # pixel map -> (P,) normalised cumulative weights, None if the map is zero everywhere (built once: a
    # `rng.choice(p=...)` per draw is O(P), which made a step's cost grow with the rows)
    map_cdfs: dict[str, np.ndarray | None] = field(init=False)

    def __post_init__(self) -> None:
        self.map_cdfs = {name: _cdf(w) for name, w in self.map_weights.items()}

    def targets(self, picked: np.ndarray) -> np.ndarray:
        """(N, 6 R^2, 3) float64: the Haar coefficients of the transport training takes for pixels `picked`,
        the mean of each one's nearest rows (`PrtConfig.row_neighbours`)."""
        return self.target_wavelets[picked].astype(np.float64)


def _cdf(weights: np.ndarray) -> np.ndarray | None:
    """The normalised cumulative sum `Generator.choice` builds from p (the same draws), None if all zero."""
    total = float(weights.sum())
    if total <= 0:
        return None
    cdf = (weights / total).cumsum()
    return cdf / cdf[-1]


@dataclass
class TestView:
    name: str  # "near_0", "far_1", ...
    camera: Camera
    inputs: SurfaceInputs  # every pixel, row-major


_cache: dict[tuple, object] = {}
_lock = threading.Lock()


def cached(key: tuple, build):
    with _lock:
        if key in _cache:
            return _cache[key]
    value = build()
    with _lock:
        while len(_cache) >= CACHE_SIZE:
            _cache.pop(next(iter(_cache)))
        _cache[key] = value
    return value


# What the traced data depends on: changing the network or the training loop reuses it.
TRACING_FIELDS = {
    "cube_size",
    "image_size",
    "rows_per_view",
    "row_spp",
    "test_spp",
    "max_depth",
    "probe_spp",
    "cameras",
    "row_neighbours",
    "lighting",  # the targets' smoothing is chosen under training lightings
}


def tracing_key(what: str, scene: SceneRef, config: PrtConfig, seed: int) -> tuple:
    return (what, scene.content_key, scene.files_key, config.model_dump_json(include=TRACING_FIELDS), seed)


def transport_tracer(scene: SceneRef, config: PrtConfig) -> PathTracer:
    """The scene under a white cube map: the tracer every row is binned from (built once per process)."""
    key = ("tracer", scene.content_key, scene.files_key, config.cube_size)
    return cached(key, lambda: relit_tracer(scene.compiled(), uniform_cube(config.cube_size)))


def cameras(scene: SceneRef, config: PrtConfig) -> dict[str, list[Camera]]:
    return trajectory_cameras(scene.spec.camera, config.cameras, config.image_size)


def scene_box(scene: SceneRef, config: PrtConfig) -> np.ndarray:
    """The hash grid's box: every first hit of every (training and test) view's pixel centres, padded."""

    def build():
        tracer = transport_tracer(scene, config)
        lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
        for camera in (c for views in cameras(scene, config).values() for c in views):
            rec = tracer.first_hits(*pixel_rays(camera))
            if rec.hit.any():
                lo = np.minimum(lo, rec.position[rec.hit].min(0))
                hi = np.maximum(hi, rec.position[rec.hit].max(0))
        if not np.isfinite(lo).all():
            raise ValueError("scene: no camera of the trajectory sees any geometry")
        pad = BOX_PADDING * max(float(np.linalg.norm(hi - lo)), 1e-6)
        return np.stack([lo - pad, hi + pad])

    return cached(tracing_key("box", scene, config, 0), build)


def training_set(scene: SceneRef, config: PrtConfig, seed: int, objects: tuple[int, ...]) -> TrainingSet:
    """Rows of the pixels on `objects` (the modelled ones, `probe`)."""
    key = (*tracing_key("train", scene, config, seed), objects)
    return cached(key, lambda: _build_training_set(scene, config, seed, objects))


def _build_training_set(
    scene: SceneRef, config: PrtConfig, seed: int, objects: tuple[int, ...]
) -> TrainingSet:
    tracer = transport_tracer(scene, config)
    rng = np.random.default_rng([seed, 15])
    inputs, rows = [], []
    for camera in cameras(scene, config)[TRAIN]:
        origins, directions = pixel_rays(camera)
        surfaces = surface_inputs(tracer, origins, directions)
        seen = np.flatnonzero(surfaces.modelled(np.asarray(objects, np.int64)))
        if len(seen) == 0:
            continue
        chosen = rng.choice(seen, min(config.rows_per_view, len(seen)), replace=False)
        traced = trace_rows(
            tracer,
            origins[chosen],
            directions[chosen],
            config.row_spp,
            config.cube_size,
            rng,
            config.max_depth,
        )
        inputs.append(surfaces.take(chosen))
        rows.append(traced.indirect.astype(np.float32))
    if not inputs:
        raise ValueError("scene: no training view sees an object whose indirect light is modelled")
    merged = SurfaceInputs(
        *(np.concatenate([getattr(i, k) for i in inputs]) for k in SurfaceInputs.__dataclass_fields__)
    )
    all_rows = np.concatenate(rows)
    box = scene_box(scene, config)
    smoothing = _smoothing(merged, all_rows, box, config, seed)
    maps = _pixel_maps(merged, all_rows, config.cube_size)
    smoothed = smoothed_rows(merged, all_rows, box, smoothing)
    targets = _row_wavelets(smoothed, config.cube_size, out=None if smoothed is all_rows else smoothed)
    return TrainingSet(merged, all_rows, box, maps, targets, smoothing)


def _smoothing(
    inputs: SurfaceInputs, rows: np.ndarray, box: np.ndarray, config: PrtConfig, seed: int
) -> dict[int, tuple[int, float]]:
    """Per object, how many nearest rows its targets average and under which direction weight: chosen by
    leave-one-out under `JUDGE_LIGHTINGS` training lightings (`smoothing_choices`); none for k = 1."""
    if config.row_neighbours == 1:
        return {int(o): (1, 0.0) for o in np.unique(inputs.object_id)}
    rng = np.random.default_rng([seed, JUDGE_STREAM])
    lightings = [training_lighting(config.lighting, rng) for _ in range(JUDGE_LIGHTINGS)]
    size, width = config.cube_size, config.lighting.map_width
    cubes = np.stack([unit_mean(lighting_cube(env, size, width)) for env in lightings])
    return smoothing_choices(inputs, rows, box, config.row_neighbours, cubes, rng)


def _pixel_maps(inputs: SurfaceInputs, rows: np.ndarray, size: int) -> dict[str, np.ndarray]:
    """Sec. 5's pixel maps, as far as sparse rows allow: uniform; ks (1 - sigma), where glossy
    interreflections are; and the energy of each row's Haar detail coefficients, where indirect light
    changes most with the lighting (standing in for the paper's variance-across-views and high-frequency
    maps, which need whole images)."""
    glossy = inputs.ks.mean(1) * (1 - np.clip(inputs.roughness, 0, 1))
    detail = np.concatenate(
        [_detail_energy(rows[i : i + MAP_CHUNK], size) for i in range(0, len(rows), MAP_CHUNK)]
    )
    return {"uniform": np.ones(len(rows)), "glossy": glossy, "transport_detail": detail}


def _detail_energy(rows: np.ndarray, size: int) -> np.ndarray:
    """The norm of each row's Haar detail coefficients (the scaling functions dropped: what is left varies
    with direction)."""
    coefficients = _wavelets(rows, size)
    coefficients[:, :, 0, 0] = 0
    return coefficients.square().sum(dim=(1, 2, 3, 4)).sqrt().numpy()


def _wavelets(rows: np.ndarray, size: int) -> torch.Tensor:
    """(N, 6, R, R, 3) float64: the Haar coefficients of rows (N, 6 R^2, 3), face by face."""
    faces = torch.from_numpy(rows.reshape(len(rows) * 6, size, size, 3)).double()
    return cubemap_wavelets(faces).reshape(len(rows), 6, size, size, 3)


def _row_wavelets(rows: np.ndarray, size: int, out: np.ndarray | None) -> np.ndarray:
    """(N, 6 R^2, 3) float32: the Haar coefficients of rows, computed in float64 a chunk at a time, written
    into `out` (which may be `rows` itself: each chunk is transformed from a copy) or a new array."""
    out = np.empty(rows.shape, np.float32) if out is None else out
    for start in range(0, len(rows), MAP_CHUNK):
        chunk = rows[start : start + MAP_CHUNK]
        out[start : start + len(chunk)] = _wavelets(chunk, size).reshape(chunk.shape).numpy()
    return out


def test_views(scene: SceneRef, config: PrtConfig, seed: int) -> list[TestView]:
    return cached(tracing_key("test", scene, config, seed), lambda: _build_test_views(scene, config, seed))


def _build_test_views(scene: SceneRef, config: PrtConfig, seed: int) -> list[TestView]:
    tracer = transport_tracer(scene, config)
    views = []
    by_split = cameras(scene, config)
    for split in (NEAR, FAR):
        for number, camera in enumerate(by_split[split]):
            inputs = surface_inputs(tracer, *pixel_rays(camera))
            views.append(TestView(f"{split}_{number}", camera, inputs))
    return views
