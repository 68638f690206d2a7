"""Imported scenes and the pbr material: BSDF throughput of `pbr` against `plastic` and `diffuse` (the
peers, same batches), and the cost of importing and compiling a scene from glTF against its YAML twin."""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np

import workers.render.bsdfs  # noqa: F401  (registers the built-in families)
from tests.bench.common import BenchSection, median_seconds
from workers.render.bsdf import SurfaceBatch, bsdf_code, bsdf_family, eval_bsdf, sample_bsdf
from workers.scene.format import spec
from workers.scene.geometry.compile import compile_scene
from workers.scene.portability.io import dump_scene, load_scene

N = 1 << 18


def _rows(material: spec.Material) -> SurfaceBatch:
    p = bsdf_family(material.type).parameters(material)
    base = p.base if isinstance(p.base, tuple) else (0.5, 0.5, 0.5)
    extra = np.tile(p.extra, (N, 1)) if p.extra else None
    return SurfaceBatch(
        np.full(N, bsdf_code(material.type), np.int8),
        np.tile(base, (N, 1)),
        np.full(N, p.alpha),
        np.full(N, p.ior),
        extra,
    )


def bsdf_section() -> BenchSection:
    section = BenchSection(f"BSDF eval + sample, {N} rows, median of 5")
    rng = np.random.default_rng(0)
    wo = rng.normal(size=(N, 3))
    wo /= np.linalg.norm(wo, axis=1, keepdims=True)
    wo[:, 2] = np.abs(wo[:, 2])
    wi = rng.normal(size=(N, 3))
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    u, uc = rng.random((N, 2)), rng.random(N)
    materials = {
        "diffuse": spec.Diffuse(),
        "plastic (alpha 0.3)": spec.Plastic(roughness=0.3),
        "pbr opaque": spec.PbrMaterial(metallic=0.3, roughness=0.5),
        "pbr glass": spec.PbrMaterial(metallic=0.0, roughness=0.3, transmission=1.0),
    }
    times = {}
    for name, material in materials.items():
        s = _rows(material)
        times[name] = median_seconds(lambda s=s: (eval_bsdf(s, wo, wi), sample_bsdf(s, wo, u, uc)))
    for name, seconds in times.items():
        section.add(
            material=name,
            M_rows_per_s=N / seconds / 1e6,
            vs_plastic=times["plastic (alpha 0.3)"] / seconds,
        )
    return section


def import_section() -> BenchSection:
    from tests.unit.test_scene_usd import write_gltf

    section = BenchSection("Load + compile: a textured glTF scene, and its imported spec written as YAML")
    with tempfile.TemporaryDirectory() as folder:
        gltf = write_gltf(Path(folder))
        imported, _ = load_scene(gltf)
        yaml_path = dump_scene(imported, Path(folder) / "twin.yaml")
        gltf_s = median_seconds(lambda: compile_scene(*load_scene(gltf)))
        yaml_s = median_seconds(lambda: compile_scene(*load_scene(yaml_path)))
        section.add(scene="glTF file", seconds=gltf_s, vs_yaml=gltf_s / yaml_s)
        section.add(scene="YAML twin", seconds=yaml_s, vs_yaml=1.0)
        section.notes.append(
            "both read their meshes from the same glTF file (parsed once per process, cached)"
        )
    return section


def run() -> list[BenchSection]:
    return [bsdf_section(), import_section()]
