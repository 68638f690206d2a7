"""A scene as it travels through a job: the validated spec and where its files live.

The reference is what the plan, the driver and every sampler actor receive (it pickles small: a spec and
either a local folder or the files' store URLs and digests), and `compiled()` turns it into triangles once
per process: compiling is cached by the scene's content (its JSON) and files, so a driver that plans,
trains and renders a scene, or a sampler actor that builds several sources over it, compiles it once. A
reference to stored files works on any node: the files are fetched into the node's cache on first use.
"""

from __future__ import annotations

import hashlib
import threading
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

from workers.scene.format.spec import SceneSpec
from workers.scene.geometry.budget import shape_triangles
from workers.scene.geometry.compile import CompiledScene, compile_scene
from workers.scene.geometry.shapes import shape_mesh
from workers.scene.portability.io import scene_from_dict
from workers.scene.portability.stored import StoredScene

COMPILED_CACHE_SIZE = 4  # scenes kept compiled per process; a driver needs one, a test process a few

_cache: dict[tuple[str, str | None], CompiledScene] = {}
_cache_lock = threading.Lock()


@dataclass(frozen=True)
class SceneRef:
    """`spec`, and where relative file paths in it resolve: `folder` (a local directory), or `stored`
    (files in the artifact store, fetched on the node that compiles the scene)."""

    spec: SceneSpec
    folder: Path | None = None
    stored: StoredScene | None = None

    @classmethod
    def from_json(
        cls, scene: dict, folder: str | Path | None = None, stored: StoredScene | dict | None = None
    ) -> SceneRef:
        """A reference to a scene given as JSON (validated here: SceneError names a bad field)."""
        if isinstance(stored, dict):
            stored = StoredScene.model_validate(stored)
        return cls(scene_from_dict(scene), None if folder is None else Path(folder), stored)

    def local_folder(self) -> Path | None:
        """The local directory of the scene's files (fetched into this node's cache if stored)."""
        if self.folder is None and self.stored is not None:
            return self.stored.local_folder()
        return self.folder

    @cached_property
    def content_key(self) -> str:
        """What identifies the compiled scene: the spec's JSON (the folder is part of the cache key)."""
        return hashlib.sha256(self.spec.model_dump_json().encode()).hexdigest()

    @property
    def files_key(self) -> str | None:
        """What identifies the files the spec's paths name: the stored files' key, or the local folder
        (with `content_key`, the key of anything built from the scene)."""
        if self.folder is None:
            return None if self.stored is None else f"stored:{self.stored.key}"
        return str(self.folder)

    def object_triangles(self) -> list[int]:
        """Each object's triangles per placement, counted from its description without building it (a
        mesh file is read and checked): what a plan needs, cheap enough for the API process."""
        counts = []
        for i, obj in enumerate(self.spec.objects):
            known = shape_triangles(obj.shape, f"objects[{i}].shape")
            counts.append(
                known
                if known is not None
                else shape_mesh(obj.shape, f"objects[{i}].shape", self.local_folder()).num_triangles
            )
        return counts

    def compiled(self) -> CompiledScene:
        """The scene's triangles, compiled at most once per process for equal content and files."""
        key = (self.content_key, self.files_key)
        with _cache_lock:
            scene = _cache.get(key)
        if scene is None:
            scene = compile_scene(self.spec, self.local_folder())
            with _cache_lock:
                while len(_cache) >= COMPILED_CACHE_SIZE:
                    _cache.pop(next(iter(_cache)))
                _cache[key] = scene
        return scene
