"""A scene as it travels through a job: the validated spec and the folder its files live in.

The reference is what the plan, the driver and every sampler actor receive (it pickles small: a spec and a
path), and `compiled()` turns it into triangles once per process: compiling is cached by the scene's
content (its JSON) and folder, so a driver that plans, trains and renders a scene, or a sampler actor that
builds several sources over it, compiles it once.
"""

from __future__ import annotations

import hashlib
import threading
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

from workers.scene.budget import shape_triangles
from workers.scene.compile import CompiledScene, compile_scene
from workers.scene.io import scene_from_dict
from workers.scene.shapes import shape_mesh
from workers.scene.spec import SceneSpec

COMPILED_CACHE_SIZE = 4  # scenes kept compiled per process; a driver needs one, a test process a few

_cache: dict[tuple[str, str | None], CompiledScene] = {}
_cache_lock = threading.Lock()


@dataclass(frozen=True)
class SceneRef:
    """`spec`, and `folder` (a local directory) that relative file paths in it resolve against."""

    spec: SceneSpec
    folder: Path | None = None

    @classmethod
    def from_json(cls, scene: dict, folder: str | Path | None = None) -> SceneRef:
        """A reference to a scene given as JSON (validated here: SceneError names a bad field)."""
        return cls(scene_from_dict(scene), None if folder is None else Path(folder))

    @cached_property
    def content_key(self) -> str:
        """What identifies the compiled scene: the spec's JSON (the folder is part of the cache key)."""
        return hashlib.sha256(self.spec.model_dump_json().encode()).hexdigest()

    def object_triangles(self) -> list[int]:
        """Each object's triangles per placement, counted from its description without building it (a
        mesh file is read and checked): what a plan needs, cheap enough for the API process."""
        counts = []
        for i, obj in enumerate(self.spec.objects):
            known = shape_triangles(obj.shape, f"objects[{i}].shape")
            counts.append(
                known
                if known is not None
                else shape_mesh(obj.shape, f"objects[{i}].shape", self.folder).num_triangles
            )
        return counts

    def compiled(self) -> CompiledScene:
        """The scene's triangles, compiled at most once per process for equal content and folder."""
        key = (self.content_key, None if self.folder is None else str(self.folder))
        with _cache_lock:
            scene = _cache.get(key)
        if scene is None:
            scene = compile_scene(self.spec, self.folder)
            with _cache_lock:
                while len(_cache) >= COMPILED_CACHE_SIZE:
                    _cache.pop(next(iter(_cache)))
                _cache[key] = scene
        return scene
