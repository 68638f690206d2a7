"""A variable scene compiled once: `at(v)` gives the concrete compiled scene without reloading anything.

Every object, including every alternative of a switch, is compiled once from the scene without its
variables. `at(v)` re-places only the triangles of the objects a variable moves (their meshes are kept in
local space) and rewrites emission, materials, lights, environment and camera from `SceneSpec.at(v)`;
what no variable touches is shared, array for array, with the base. Hidden switch alternatives keep their
triangles in the arrays (so triangle indices never change between states) but emit nothing, and the path
tracer leaves them out of its geometry (`workers.render.variable_tracer`), which also keeps one BVH over
the static triangles for every state.

The state's `spec` is `SceneSpec.at(v)`, which drops hidden objects; its `objects` are the base's, so
`object_ids` index the base scene's objects.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from workers.scene.format.spec import SceneSpec, euler_xyz
from workers.scene.format.variables import check_vector, moved_objects
from workers.scene.geometry.compile import CompiledScene, _place, compile_scene


@dataclasses.dataclass(frozen=True)
class SceneState:
    """The concrete scene at one v: its triangles and which of the moved ones are present."""

    v: np.ndarray
    compiled: CompiledScene
    visible_moved_triangles: np.ndarray  # (M,) triangle ids of moved objects present at v


class CompiledVariableScene:
    """The base compile of a variable scene and the split of its triangles into static and moved."""

    def __init__(self, spec: SceneSpec, base_dir: Path | str | None = None) -> None:
        self.spec = spec
        self.base = compile_scene(spec.model_copy(update={"variables": []}), base_dir)
        self.moved = moved_objects(spec)
        moved_rows = np.zeros(self.base.num_triangles, bool)
        for i in self.moved:
            for start, stop in self.base.objects[i].triangle_ranges:
                moved_rows[start:stop] = True
        self.static_triangles = np.flatnonzero(~moved_rows)
        self.moved_triangles = np.flatnonzero(moved_rows)

    @property
    def dimensions(self) -> int:
        return self.spec.dimensions

    def at(self, v) -> SceneState:
        """The compiled scene at `v` (ValueError naming `v` when it is not in [0, 1]^K)."""
        vector = check_vector(self.spec, v)
        concrete = self.spec.at(vector)
        present = {obj.name: obj for obj in concrete.objects}
        base = self.base
        positions, shading, uvs = base.positions, base.shading_normals, base.uvs
        geometric, areas, colors = base.geometric_normals, base.areas, base.vertex_colors
        if self.moved:
            positions, shading, uvs = positions.copy(), shading.copy(), uvs.copy()
            geometric, areas = geometric.copy(), areas.copy()
            colors = None if colors is None else colors.copy()
        visible: list[np.ndarray] = []
        for i in self.moved:
            geometry = base.objects[i]
            obj = present.get(geometry.name)
            if obj is None:
                continue
            for (start, stop), matrix in zip(geometry.triangle_ranges, obj.instance_matrices(), strict=True):
                pos, nrm, faces = _place(geometry.mesh, matrix)
                positions[start:stop] = pos
                shading[start:stop] = nrm
                if geometry.mesh.uvs is not None:
                    uvs[start:stop] = geometry.mesh.uvs[faces]
                if geometry.mesh.colors is not None:  # a mirroring move reverses the corners
                    colors[start:stop] = geometry.mesh.colors[faces]
                cross = np.cross(pos[:, 1] - pos[:, 0], pos[:, 2] - pos[:, 0])
                length = np.linalg.norm(cross, axis=1)
                areas[start:stop] = 0.5 * length
                geometric[start:stop] = cross / np.maximum(length, 1e-300)[:, None]
                visible.append(np.arange(start, stop))
        emission = np.zeros_like(base.emission)
        for geometry in base.objects:
            obj = present.get(geometry.name)
            if obj is not None and obj.emission is not None:
                for start, stop in geometry.triangle_ranges:
                    emission[start:stop] = obj.emission
        compiled = dataclasses.replace(
            base,
            spec=concrete,
            positions=positions,
            shading_normals=shading,
            uvs=uvs,
            geometric_normals=geometric,
            areas=areas,
            emission=emission,
            vertex_colors=colors,
        )
        if concrete.environment is not None and base.environment_image is not None:
            compiled.environment_rotation = euler_xyz(concrete.environment.rotate)
        moved = np.concatenate(visible) if visible else np.zeros(0, np.int64)
        return SceneState(vector, compiled, moved)
