"""Serving a `mesogan` artifact.

`generate`: the feature plane of a window of the infinite texture (lattice origin and size in texels) for
given structure parameters and seed, so a client can tile or cache it: windows of one seed agree on
their overlap.
`query`: density and rho at slab points (plane x, y and height in slab heights) of the seed's plane,
with light and view directions in the tangent frame (z up); any window holding a point answers it alike.
`render`: a scene with the material on its named surfaces (`params.surfaces`), for the given structure,
appearance, seed, shell height (`ShellHeight`) and camera, path-traced with the neural shell. The scene is
the one the artifact keeps, a built-in one (`params.scene`), an uploaded mesh (`arrays.mesh`, under the
neutral sky; all-zero UVs are box-projected, `atlas`) or a sphere under the neutral sky.
"""

from __future__ import annotations

import tempfile
from collections.abc import Mapping
from pathlib import Path
from typing import ClassVar

import numpy as np
import torch
from pydantic import BaseModel, ConfigDict, Field

from workers.models.mesogan import artifact
from workers.models.mesogan.covering import shell_aggregate
from workers.models.mesogan.sampling import normalized_structure
from workers.models.mesogan.slab import Window, draw_noise, generate_planes
from workers.models.mesogan.volume import HEIGHT_TO_RADIANS
from workers.models.registry import QUERY, RENDER, Answer, ArraySpec, Operation
from workers.render.integrator import PathTracer
from workers.runtime.view_render import (
    RENDER_WORKING_BYTES,
    SCENE,
    ViewRender,
    refuse_missing_scene,
    render_view,
)
from workers.scene.format.errors import SceneError
from workers.scene.format.spec import (
    Appearance,
    Camera,
    Diffuse,
    MeshShape,
    SceneObject,
    ShellHeight,
    SphereShape,
    Structure,
)
from workers.scene.generators.builtin import get_builtin
from workers.scene.geometry.compile import CompiledScene, compile_scene
from workers.scene.geometry.framing import framing_camera
from workers.scene.portability.portable import load_scene, neutral_scene

GENERATE = "generate"
MAX_WINDOW = 2048
# Working memory, estimated from the decoder's shapes (not measured): a query's outputs and their encoded
# copy, and per point its sampled features and the decoder's hidden layers; per call, what a plane costs
# whatever its size.
QUERY_ROW_BYTES, QUERY_ACTIVATION_ROW_BYTES, PLANE_BYTES = 32, 2 << 10, 16 << 20
NEUTRAL_SURFACE = "mesogan"
# An uploaded mesh: per triangle corner its position, shading normal and UV (a triangle soup, so that it
# is one array of rows; corners of neighbouring triangles with equal positions and normals give prisms
# that agree on their shared faces).
MESH = "mesh"
MESH_CORNER = 8


class Material(BaseModel):
    model_config = ConfigDict(extra="forbid")

    structure: Structure = Structure()
    appearance: Appearance = Appearance()
    seed: int = Field(0, ge=0, description="which instance of the distribution")


class GenerateParams(Material):
    origin: tuple[int, int] = (0, 0)
    size: tuple[int, int] = Field((64, 64), description="texels per side, at most 2048")


class QueryParams(Material):
    window: tuple[int, int, int, int] = Field(
        (-64, -64, 128, 128),
        description="the plane window the points lie in, edges included: origin and size in texels (any "
        "windows of a seed answer a point alike, so tiles agree with one large window)",
    )


class RenderParams(ViewRender, Material, ShellHeight):
    scene: str | None = Field(
        None, description="a built-in scene's name, rendered instead of the one the artifact keeps"
    )
    surfaces: list[str] | None = Field(
        None,
        min_length=1,
        description="scene materials the shell covers; default: the artifact's, or the whole uploaded mesh",
    )


class MesoganModel:
    def __init__(self, folder: Path, device: str) -> None:
        self.config, self.model = artifact.load(folder, device)
        self.device = device
        self.stored = load_scene(folder)
        self.nbytes = artifact.shipped_bytes(self.model)

    def answer(self, operation: str, params: BaseModel, arrays: dict[str, np.ndarray]) -> Answer:
        with torch.inference_mode():
            if operation == GENERATE:
                return self._generate(params)
            if operation == RENDER:
                return self._render(params, arrays.get(MESH))
            return self._query(params, arrays)

    def plane_bytes(self, size: tuple[int, int], margin: int) -> int:
        """Working memory of a generated window of `size` texels widened by `margin`, beyond PLANE_BYTES:
        per texel (with the generator's own margin) the position's Fourier features and their sines, three
        of the generator's activations, each layer's injected features, and the plane, its copy as an
        answer and that copy encoded. Measured by peak RSS on an AMD EPYC: quick's generator 540 bytes a
        texel at 512^2 (this says 704), paper's 4,160 at 256^2 (this says 8,096)."""
        c = self.config
        texel = 4 * (2 * c.fourier_features + 3 * c.generator_width + 2 * c.injected_features)
        texel += 4 * 3 * c.plane_channels + 32
        pad = 2 * (margin + c.generator_layers)
        return (size[0] + pad) * (size[1] + pad) * texel

    def _window(self, origin: tuple[int, int], size: tuple[int, int], field: str) -> Window:
        if max(size) > MAX_WINDOW or min(size) < 1:
            raise ValueError(f"{field}: a window is 1 to {MAX_WINDOW} texels per side, got {size}")
        return Window(origin, size, self.config.texel)

    def _plane(self, params: Material, window: Window) -> torch.Tensor:
        generator = torch.Generator().manual_seed(params.seed)
        latent = torch.randn(1, self.config.latent_dims, generator=generator).to(self.device)
        s = torch.tensor(normalized_structure(params.structure), dtype=torch.float32, device=self.device)[
            None
        ]
        noise = draw_noise(self.model, self.config, 1, params.seed)
        return generate_planes(self.model, self.config, s, latent, noise, window)

    def _generate(self, params: GenerateParams) -> Answer:
        window = self._window(params.origin, params.size, "params.size")
        plane = self._plane(params, window)[0].permute(1, 2, 0)
        return Answer({"plane": plane.float().cpu().numpy()}, {"texel": self.config.texel})

    def _query(self, params: QueryParams, arrays: dict[str, np.ndarray]) -> Answer:
        ox, oy, sx, sy = params.window
        window = self._window((ox, oy), (sx, sy), "params.window")
        points = torch.from_numpy(arrays["points"].astype(np.float32))
        uv = window.uv(points[:, :2])
        if ((uv < 0) | (uv > 1)).any():
            raise ValueError("arrays.points: points lie outside params.window")
        # One texel of margin: a point near the window's edge reads the texels past it, as a larger
        # window would, so tiled queries agree with one large query everywhere (`Window.bilinear`).
        margin = window.widened(1)
        features = margin.bilinear(self._plane(params, margin)[0], points[:, :2])
        height = points[:, 2].clamp(0, 1) * HEIGHT_TO_RADIANS
        density, hidden = self.model.decoder.density(features, height, torch.zeros_like(height))
        n = len(points)
        up = torch.tensor([0.0, 0.0, 1.0]).expand(n, 3)
        light = torch.from_numpy(arrays["light"].astype(np.float32)) if "light" in arrays else up
        view = torch.from_numpy(arrays["view"].astype(np.float32)) if "view" in arrays else up
        a = torch.tensor(params.appearance.color()).expand(n, 3)
        rho = self.model.decoder.rho(hidden, a, light, view)
        return Answer({"density": density.numpy(), "rho": rho.numpy()})

    def _render(self, params: RenderParams, mesh: np.ndarray | None) -> Answer:
        config = self.config
        with tempfile.TemporaryDirectory(prefix="mesogan-upload-") as folder:
            scene, surfaces = self._scene(params, mesh, Path(folder))
        unknown = [n for n in surfaces if n not in scene.material_names]
        if unknown:
            names = scene.material_names
            raise ValueError(f"params.surfaces: no material {unknown}; the scene's are {names}")
        camera = params.camera.over(scene.spec.camera)
        aggregate = shell_aggregate(
            scene, surfaces, self.model, config, params.structure, params.appearance, params.seed,
            params, camera, ("params.surfaces", "params."),
        )  # fmt: skip
        image = render_view(PathTracer(scene, aggregate=aggregate), params, camera).image
        return Answer({"image": image}, {"plane_resolution": aggregate.material.window.size[0]})

    def _scene(
        self, params: RenderParams, mesh: np.ndarray | None, folder: Path
    ) -> tuple[CompiledScene, list[str]]:
        """The compiled scene to render and the surfaces the shell covers (module docstring)."""
        if mesh is not None or params.background != SCENE:
            if params.scene is not None:
                raise ValueError("params.scene: a built-in scene is rendered with background: scene")
            if mesh is None:
                shape = SphereShape(radius=0.5, subdivisions=4)
                camera = Camera(position=(0.0, 0.4, 2.0), target=(0.0, 0.0, 0.0))
            else:
                shape, camera = uploaded_mesh(mesh, folder)
            model = SceneObject(name="model", shape=shape, material=NEUTRAL_SURFACE)
            spec = neutral_scene([model], {NEUTRAL_SURFACE: Diffuse()}).model_copy(update={"camera": camera})
            return compile_scene(spec, folder), params.surfaces or [NEUTRAL_SURFACE]
        if params.scene is not None:
            try:
                spec = get_builtin(params.scene)
            except SceneError as error:
                raise ValueError(f"params.scene: {error.problem}") from None
            return compile_scene(spec), params.surfaces or self.config.surfaces
        refuse_missing_scene(self.stored)
        return self.stored.compiled(), params.surfaces or self.config.surfaces


def uploaded_mesh(corners: np.ndarray, folder: Path) -> tuple[MeshShape, Camera]:
    """An uploaded triangle soup (F, 3, 8) written as an OBJ file in `folder` (read back by the scene's
    own mesh reader, which checks it), and a camera framing it."""
    if corners.ndim != 3 or corners.shape[1:] != (3, MESH_CORNER):
        raise ValueError(f"arrays.mesh: expected (triangles, 3, {MESH_CORNER}), got {corners.shape}")
    rows = corners.reshape(-1, MESH_CORNER).astype(np.float64)
    flipped = rows[:, 6:] * [1.0, -1.0] + [0.0, 1.0]  # OBJ's v runs up, the scene's UVs down
    index = np.arange(1, len(rows) + 1).reshape(-1, 3)
    lines = [
        *(f"v {x:.9g} {y:.9g} {z:.9g}" for x, y, z in rows[:, :3]),
        *(f"vn {x:.9g} {y:.9g} {z:.9g}" for x, y, z in rows[:, 3:6]),
        *(f"vt {u:.9g} {v:.9g}" for u, v in flipped),
        *(f"f {a}/{a}/{a} {b}/{b}/{b} {c}/{c}/{c}" for a, b, c in index),
    ]
    (folder / "upload.obj").write_text("\n".join(lines) + "\n")
    bounds = np.stack([rows[:, :3].min(0), rows[:, :3].max(0)])
    return MeshShape(path="upload.obj"), framing_camera(bounds)


class MesoganInference:
    operations: ClassVar[Mapping[str, Operation]] = {
        QUERY: Operation(
            params=QueryParams,
            inputs={
                "points": ArraySpec("float32", (None, 3)),
                "light": ArraySpec("float32", (None, 3), required=False),
                "view": ArraySpec("float32", (None, 3), required=False),
            },
            row_bytes=QUERY_ROW_BYTES,
            activation_row_bytes=QUERY_ACTIVATION_ROW_BYTES,
            call_bytes=PLANE_BYTES,
            params_bytes=lambda model, params: model.plane_bytes(params.window[2:], 1),
        ),
        GENERATE: Operation(
            params=GenerateParams,
            call_bytes=PLANE_BYTES,
            params_bytes=lambda model, params: model.plane_bytes(params.size, 0),
        ),
        RENDER: Operation(
            params=RenderParams,
            inputs={MESH: ArraySpec("float32", (None, 3, MESH_CORNER), required=False)},
            call_bytes=RENDER_WORKING_BYTES,
        ),
    }

    def load(self, folder: Path, device: str) -> MesoganModel:
        return MesoganModel(folder, device)


INFERENCE = MesoganInference()
