"""The scene description users write (YAML or JSON) and every component reads.

A `SceneSpec` is small and serialisable: geometry is referenced (mesh files,
analytic shapes, named procedural generators), never inlined, so a spec can be
hashed for job identity and shipped to Ray workers cheaply.

Conventions: right-handed, y-up; colours are linear RGB; roughness is the GGX
`alpha` (as Mitsuba's `alpha`); angles are in degrees.
"""

from __future__ import annotations

import math
import re
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import (
    ConfigDict,
    Field,
    FiniteFloat,
    ValidationInfo,
    field_validator,
    model_validator,
)

from workers.scene.format.strict import StrictModel
from workers.scene.format.variables import apply_variables, check_variables, scene_dimensions

Vec3 = tuple[FiniteFloat, FiniteFloat, FiniteFloat]
NonNegRGB = tuple[
    Annotated[FiniteFloat, Field(ge=0)],
    Annotated[FiniteFloat, Field(ge=0)],
    Annotated[FiniteFloat, Field(ge=0)],
]
Albedo = tuple[
    Annotated[FiniteFloat, Field(ge=0, le=1)],
    Annotated[FiniteFloat, Field(ge=0, le=1)],
    Annotated[FiniteFloat, Field(ge=0, le=1)],
]
Roughness = Annotated[FiniteFloat, Field(ge=0, le=1, description="GGX alpha")]


class Model(StrictModel):
    """Base: unknown fields are errors, so typos are caught at upload."""

    model_config = ConfigDict(frozen=True)


# --------------------------------------------------------------------------- transforms


class Transform(Model):
    """Scale, then rotate (Euler X, then Y, then Z, degrees), then translate; or a 4x4 matrix."""

    translate: Vec3 = (0.0, 0.0, 0.0)
    rotate: Vec3 = (0.0, 0.0, 0.0)
    scale: Vec3 | FiniteFloat = 1.0
    matrix: tuple[Vec3 | tuple[FiniteFloat, ...], ...] | None = Field(
        default=None, description="row-major 4x4 (or 3x4) affine matrix; overrides the other fields"
    )

    @field_validator("matrix")
    @classmethod
    def _matrix_shape(cls, m):
        if m is None:
            return m
        if len(m) not in (3, 4) or any(len(row) != 4 for row in m):
            raise ValueError("matrix must have 3 or 4 rows of 4 numbers")
        if len(m) == 4 and tuple(m[3]) != (0.0, 0.0, 0.0, 1.0):
            raise ValueError("the last row of an affine matrix must be (0, 0, 0, 1)")
        singular_values = np.linalg.svd(np.asarray(m, dtype=np.float64)[:3, :3], compute_uv=False)
        if singular_values[-1] <= 1e-12 * singular_values[0]:  # scale-free: tiny scenes are fine
            raise ValueError("matrix is singular (it flattens space)")
        return m

    @field_validator("scale")
    @classmethod
    def _scale_nonzero(cls, s):
        values = (s,) if isinstance(s, float | int) else s
        if any(abs(v) < 1e-12 for v in values):
            raise ValueError("scale must be non-zero on every axis")
        return s

    def to_matrix(self) -> np.ndarray:
        """The 4x4 float64 matrix taking local points to the parent space."""
        if self.matrix is not None:
            m = np.eye(4)
            m[: len(self.matrix)] = np.asarray(self.matrix, dtype=np.float64)
            return m
        s = np.broadcast_to(np.asarray(self.scale, dtype=np.float64), (3,))
        m = np.eye(4)
        m[:3, :3] = euler_xyz(self.rotate) @ np.diag(s)
        m[:3, 3] = self.translate
        return m


def euler_xyz(degrees: Vec3) -> np.ndarray:
    """Rotation about X, then Y, then Z (R = Rz @ Ry @ Rx), angles in degrees."""
    ax, ay, az = (math.radians(a) for a in degrees)
    cx, sx, cy, sy, cz, sz = (
        math.cos(ax),
        math.sin(ax),
        math.cos(ay),
        math.sin(ay),
        math.cos(az),
        math.sin(az),
    )
    rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return rz @ ry @ rx


# --------------------------------------------------------------------------- textures


Wrap = Literal["repeat", "clamp", "mirror"]


class ImageTexture(Model):
    """An image addressed by UV (`workers.scene.importers.textures`): by default 8-bit images are
    sRGB-decoded and EXR is linear; `color_space` says otherwise (data such as roughness or normals is
    linear)."""

    type: Literal["image"] = "image"
    path: str
    image: Annotated[int, Field(ge=0)] | None = Field(
        default=None, description="the index of an image inside the glTF file `path` (embedded images)"
    )
    member: str | None = Field(default=None, description="a file inside the USDZ package `path`")
    color_space: Literal["srgb", "linear"] | None = None
    wrap_u: Wrap = "repeat"
    wrap_v: Wrap = "repeat"


class CheckerTexture(Model):
    """A procedural checkerboard in UV space, useful for tests without files."""

    type: Literal["checker"] = "checker"
    color0: Albedo = (0.8, 0.8, 0.8)
    color1: Albedo = (0.2, 0.2, 0.2)
    scale: Annotated[FiniteFloat, Field(gt=0)] = 8.0


Texture = Annotated[ImageTexture | CheckerTexture, Field(discriminator="type")]
ColorOrTexture = Albedo | Texture


# --------------------------------------------------------------------------- materials


class Diffuse(Model):
    type: Literal["diffuse"] = "diffuse"
    reflectance: ColorOrTexture = (0.5, 0.5, 0.5)


class Conductor(Model):
    """GGX microfacet metal whose Fresnel term is the specular colour (Mitsuba `material: none`)."""

    type: Literal["conductor"] = "conductor"
    roughness: Roughness = 0.1
    specular: Albedo = (1.0, 1.0, 1.0)


class Plastic(Model):
    """A diffuse base under a GGX dielectric coat; energy-conserving by construction."""

    type: Literal["plastic"] = "plastic"
    diffuse: ColorOrTexture = (0.5, 0.5, 0.5)
    roughness: Roughness = 0.1
    ior: Annotated[FiniteFloat, Field(gt=1.0, le=4.0)] = 1.5


class Dielectric(Model):
    """Glass: smooth when roughness is 0, GGX rough otherwise. `ior` is interior over exterior."""

    type: Literal["dielectric"] = "dielectric"
    ior: Annotated[FiniteFloat, Field(gt=1.0, le=4.0)] = 1.5
    roughness: Roughness = 0.0


class PbrMaterial(Model):
    """glTF 2.0's metallic-roughness material (`workers.render.bsdfs.pbr`), with glTF's defaults.

    Textures multiply their factors, as in glTF: `base_color_texture` (sRGB), `metallic_roughness_texture`
    (linear; roughness in G, metallic in B), `transmission_texture` (R), `normal_texture` (tangent space,
    linear, +Y up as glTF's), and `emission_texture` (sRGB) scaling the emission of the objects using it.
    `roughness` is glTF's perceptual roughness (GGX alpha = roughness^2). `diffuse` is the non-metal base's
    diffuse lobe: `energy_conserving` (albedo scaling under the specular lobe: a white non-metal reflects
    exactly what arrives) or `burley` (Burley's, as Mitsuba's and Blender's `principled`: up to ~1.4x at
    grazing angles); the metal and transmission lobes are the same in both.
    """

    type: Literal["pbr"] = "pbr"
    base_color: Albedo = (1.0, 1.0, 1.0)
    base_color_texture: Texture | None = None
    metallic: Annotated[FiniteFloat, Field(ge=0, le=1)] = 1.0
    roughness: Annotated[FiniteFloat, Field(ge=0, le=1)] = 1.0
    metallic_roughness_texture: Texture | None = None
    ior: Annotated[FiniteFloat, Field(gt=1.0, le=4.0)] = 1.5
    transmission: Annotated[FiniteFloat, Field(ge=0, le=1)] = 0.0
    transmission_texture: Texture | None = None
    normal_texture: Texture | None = None
    normal_scale: FiniteFloat = 1.0
    emission_texture: Texture | None = None
    diffuse: Literal["energy_conserving", "burley"] = "energy_conserving"


SurfaceMaterial = Annotated[
    Diffuse | Conductor | Plastic | Dielectric | PbrMaterial, Field(discriminator="type")
]


Unit = Annotated[FiniteFloat, Field(ge=0, le=1)]


class Structure(Model):
    """The geometric parameters a generated mesoscale instance is drawn from (what the mapping network
    sees; `workers.scene.generators.mesoscale`)."""

    length: Annotated[FiniteFloat, Field(gt=0, le=1, description="strand length / slab height")] = 0.8
    density: Annotated[FiniteFloat, Field(gt=0, le=400, description="strands per squared slab height")] = 40.0
    curliness: Annotated[Unit, Field(description="how far strands bend sideways (0: straight)")] = 0.3


class Appearance(Model):
    """The strands' colour (what only the decoder's radiance head sees)."""

    hue: Annotated[Unit, Field(description="the strands' hue on the colour wheel (0.02: red-brown)")] = 0.02
    saturation: Annotated[Unit, Field(description="the strands' colour saturation (0: grey)")] = 0.8

    def color(self, value: float = 0.7) -> tuple[float, float, float]:
        """The strands' reflectance: HSV with the given value."""
        k = (np.array([5.0, 3.0, 1.0]) + self.hue * 6.0) % 6.0
        rgb = value - value * self.saturation * np.clip(np.minimum(k, 4.0 - k), 0.0, 1.0)
        return tuple(float(c) for c in rgb)


ARTIFACT_ID = re.compile(r"sha256:[0-9a-f]{64}")


class AggregateMaterial(Model):
    """A trained model drawn as a volume over the surfaces that use it, which the path tracer scatters in
    (`workers.render.aggregate_materials`: a family registered under the material's `type` builds it);
    `base` shades the surfaces themselves, beneath the volume.

    The model is an artifact of the kind that declares the material's `type` (`Kind.materials`), named
    by exactly one of `path`, its folder relative to the scene file (as `nbake download` writes it), or
    `artifact`, its id in the job server's store (`sha256:...`, as a finished job reports it), which the
    server checks at submission and fetches into the job's folder
    (`workers.scene.portability.stored.artifact_folder`).
    """

    base: SurfaceMaterial = Diffuse()
    path: str | None = Field(None, min_length=1, description="the artifact's folder, relative to the scene")
    artifact: str | None = Field(None, validate_default=True, description="a stored artifact's id")

    @field_validator("artifact")
    @classmethod
    def _one_source(cls, artifact: str | None, info: ValidationInfo) -> str | None:
        if artifact is not None and ARTIFACT_ID.fullmatch(artifact) is None:
            raise ValueError("an artifact id is 'sha256:' and 64 hex digits, as a finished job reports it")
        if "path" not in info.data:
            return artifact  # `path` itself was refused: that error is the one reported
        if (artifact is None) == (info.data["path"] is None):
            raise ValueError(
                "give exactly one of `path` (the artifact's folder, relative to the scene file) or "
                "`artifact` (its id in the job server's store)"
            )
        return artifact


class ShellHeight(Model):
    """The height of a shell over surfaces: `shell_height` in world units, or `shell_height_relative`, a
    fraction of the bounding-box diagonal of the surfaces it covers, which scales with the object (a scan
    in millimetres or in metres); neither: the artifact's own, in world units."""

    shell_height: Annotated[FiniteFloat, Field(gt=0, description="world units")] | None = None
    shell_height_relative: (
        Annotated[
            FiniteFloat,
            Field(gt=0, le=1, description="a fraction of the covered surfaces' bounding-box diagonal"),
        ]
        | None
    ) = None

    @field_validator("shell_height_relative")
    @classmethod
    def _one_height(cls, relative: float | None, info: ValidationInfo) -> float | None:
        if relative is not None and info.data.get("shell_height") is not None:
            raise ValueError("give at most one of `shell_height` (world units) and `shell_height_relative`")
        return relative

    def world_height(self, diagonal: float, default: float) -> float:
        """The height in world units over surfaces whose bounding box has this `diagonal`."""
        if self.shell_height_relative is not None:
            return self.shell_height_relative * diagonal
        return self.shell_height or default

    def height_field(self) -> str:
        """The field that sets the height (the world-units one when neither is given)."""
        return "shell_height_relative" if self.shell_height_relative is not None else "shell_height"


class MesoganMaterial(ShellHeight, AggregateMaterial):
    """A trained `mesogan` model's generated fur, grass or carpet on a shell over the surfaces (Diolatzis
    2022, Sec. 6.2.8; `workers.models.mesogan.material`), its artifact named by `path` or `artifact`; the
    parameters left out are the artifact's own (those its job rendered)."""

    type: Literal["mesogan"] = "mesogan"
    structure: Structure | None = None
    appearance: Appearance | None = None
    seed: Annotated[int, Field(ge=0, description="which instance of the distribution")] = 0


Material = Annotated[
    Diffuse | Conductor | Plastic | Dielectric | PbrMaterial | MesoganMaterial, Field(discriminator="type")
]


def surface_material(material: Material) -> SurfaceMaterial:
    """What shades a material's surfaces: the material itself, or an aggregate material's `base`."""
    return material.base if isinstance(material, AggregateMaterial) else material


# --------------------------------------------------------------------------- shapes


class MeshShape(Model):
    """A mesh file (OBJ, PLY, glTF/GLB, STL) read with trimesh; relative paths resolve from the scene file."""

    type: Literal["mesh"] = "mesh"
    path: str
    repair: bool = Field(default=False, description="drop degenerate triangles instead of rejecting the mesh")


class SphereShape(Model):
    type: Literal["sphere"] = "sphere"
    center: Vec3 = (0.0, 0.0, 0.0)
    radius: Annotated[FiniteFloat, Field(gt=0)] = 1.0
    subdivisions: Annotated[int, Field(ge=0, le=7)] = 5


class RectangleShape(Model):
    """The square [-1, 1]^2 in the z = 0 plane facing +z (Mitsuba's `rectangle`)."""

    type: Literal["rectangle"] = "rectangle"


class BoxShape(Model):
    """The cube [-1, 1]^3 with outward faces (Mitsuba's `cube`)."""

    type: Literal["box"] = "box"


class ProceduralShape(Model):
    """Geometry made by a named generator (`workers.scene.generators.catalogue`), deterministic for its
    params."""

    type: Literal["procedural"] = "procedural"
    generator: str
    params: dict[str, Any] = Field(default_factory=dict)


class GltfShape(Model):
    """One primitive of a mesh in a glTF 2.0 file (`.gltf` or `.glb`), in the mesh's own space: what
    `workers.scene.importers.gltf` imports each (mesh, primitive) as, placed once per node that uses the
    mesh."""

    type: Literal["gltf"] = "gltf"
    path: str
    mesh: Annotated[int, Field(ge=0)] = 0
    primitive: Annotated[int, Field(ge=0)] = 0
    repair: bool = Field(default=False, description="drop degenerate triangles instead of rejecting the mesh")


class UsdShape(Model):
    """A UsdGeom.Mesh prim of a USD file (`.usda`, `.usdc`, `.usd`, `.usdz`), triangulated, in its own space:
    what `workers.scene.importers.usd` imports each mesh as, placed once per instance of it."""

    type: Literal["usd"] = "usd"
    path: str
    prim: str = Field(pattern=r"^/", description="the mesh prim's path in the stage")
    repair: bool = Field(default=False, description="drop degenerate triangles instead of rejecting the mesh")


Shape = Annotated[
    MeshShape | SphereShape | RectangleShape | BoxShape | ProceduralShape | GltfShape | UsdShape,
    Field(discriminator="type"),
]


class SceneObject(Model):
    """A shape with a material, placed once per instance (geometry is shared between instances)."""

    name: str = Field(min_length=1, max_length=128)
    shape: Shape
    material: str = Field(description="a key of SceneSpec.materials")
    emission: NonNegRGB | None = Field(default=None, description="area-light radiance (one-sided, front)")
    two_sided_emission: bool = False
    transform: Transform = Transform()
    instances: list[Transform] | None = Field(
        default=None, description="extra placements, each applied before `transform`"
    )

    def instance_matrices(self) -> list[np.ndarray]:
        base = self.transform.to_matrix()
        if not self.instances:
            return [base]
        return [base @ t.to_matrix() for t in self.instances]


# --------------------------------------------------------------------------- lights


class PointLight(Model):
    type: Literal["point"] = "point"
    position: Vec3
    intensity: NonNegRGB = Field(description="radiant intensity, W/sr")


class DirectionalLight(Model):
    type: Literal["directional"] = "directional"
    direction: Vec3 = Field(description="the direction light travels")
    irradiance: NonNegRGB

    @field_validator("direction")
    @classmethod
    def _nonzero(cls, d):
        if math.hypot(*d) < 1e-12:
            raise ValueError("direction must be non-zero")
        return d


class SpotLight(Model):
    """A point light limited to a cone, with glTF's (KHR_lights_punctual) smooth falloff: full intensity
    within `inner_cone` of `direction`, squared-linear in the cosine down to zero at `outer_cone`."""

    type: Literal["spot"] = "spot"
    position: Vec3
    direction: Vec3 = Field(description="the cone's axis, the direction light travels")
    intensity: NonNegRGB = Field(description="radiant intensity on the axis, W/sr")
    inner_cone: Annotated[FiniteFloat, Field(ge=0, lt=90)] = 0.0
    outer_cone: Annotated[FiniteFloat, Field(gt=0, le=90)] = 45.0

    @model_validator(mode="after")
    def _cones(self):
        if math.hypot(*self.direction) < 1e-12:
            raise ValueError("direction must be non-zero")
        if self.inner_cone >= self.outer_cone:
            raise ValueError("inner_cone must be smaller than outer_cone")
        return self


Light = Annotated[PointLight | DirectionalLight | SpotLight, Field(discriminator="type")]


class EnvironmentMap(Model):
    """A lat-long HDR map (Mitsuba's convention: u = atan2(x, -z) / 2pi, v = acos(y) / pi).

    `path` is an EXR file, `procedural` names a generator in `workers.scene.generators.envmaps`
    (`sky`, `studio`) with `params`, and `builtin` names an HDRI shipped in `assets/hdri`.
    """

    type: Literal["envmap"] = "envmap"
    path: str | None = None
    procedural: str | None = None
    builtin: str | None = None
    params: dict[str, Any] = Field(default_factory=dict)
    rotate: Vec3 = (0.0, 0.0, 0.0)
    scale: Annotated[FiniteFloat, Field(ge=0)] = 1.0

    @model_validator(mode="after")
    def _one_source(self):
        given = [x for x in (self.path, self.procedural, self.builtin) if x is not None]
        if len(given) != 1:
            raise ValueError("give exactly one of `path`, `procedural` or `builtin`")
        return self


class ConstantBackground(Model):
    type: Literal["constant"] = "constant"
    radiance: NonNegRGB = (1.0, 1.0, 1.0)


Environment = Annotated[EnvironmentMap | ConstantBackground, Field(discriminator="type")]


# --------------------------------------------------------------------------- camera


class Camera(Model):
    """A pinhole camera; `fov` is the vertical field of view in degrees."""

    position: Vec3 = (0.0, 0.0, 5.0)
    target: Vec3 = (0.0, 0.0, 0.0)
    up: Vec3 = (0.0, 1.0, 0.0)
    fov: Annotated[FiniteFloat, Field(gt=0.1, lt=179.0)] = 40.0
    width: Annotated[int, Field(ge=1, le=16384)] = 256
    height: Annotated[int, Field(ge=1, le=16384)] = 256

    @model_validator(mode="after")
    def _well_posed(self):
        forward = np.subtract(self.target, self.position)
        n = np.linalg.norm(forward)
        if n < 1e-9:
            raise ValueError("camera target coincides with its position")
        up = np.asarray(self.up, dtype=np.float64)
        if np.linalg.norm(up) < 1e-9:
            raise ValueError("camera up vector is zero")
        if np.linalg.norm(np.cross(forward / n, up / np.linalg.norm(up))) < 1e-6:
            raise ValueError("camera looks along its up vector; choose another `up`")
        return self


# --------------------------------------------------------------------------- variables


class _Variable(Model):
    """A named variable: one or more dimensions of the scene vector v in [0, 1]^K, each mapped linearly
    onto its range (`workers.scene.format.variables` applies them)."""

    name: str = Field(min_length=1, max_length=128, pattern=r"^[A-Za-z_][\w.-]*$")


class TranslateVariable(_Variable):
    """An object's offset from its placement, `min` at 0 to `max` at 1; one dimension per axis that moves."""

    type: Literal["translate"] = "translate"
    object: str
    min: Vec3 = (0.0, 0.0, 0.0)
    max: Vec3


class RotateVariable(_Variable):
    """An object turned about `axis` through `pivot` by `min_angle` + v `range_angle` degrees."""

    type: Literal["rotate"] = "rotate"
    object: str
    axis: Vec3 = (0.0, 1.0, 0.0)
    pivot: Vec3 = (0.0, 0.0, 0.0)
    min_angle: FiniteFloat = 0.0
    range_angle: FiniteFloat


class SwitchVariable(_Variable):
    """One of `objects` is present: v in [k/n, (k+1)/n) picks the k-th (v = 1 the last)."""

    type: Literal["switch"] = "switch"
    objects: list[str] = Field(min_length=2)


class AlbedoVariable(_Variable):
    """A diffuse or plastic material's base colour, per channel that varies."""

    type: Literal["albedo"] = "albedo"
    material: str
    min: Albedo
    max: Albedo


class SpecularVariable(_Variable):
    """A conductor's specular colour, per channel that varies."""

    type: Literal["specular"] = "specular"
    material: str
    min: Albedo
    max: Albedo


class RoughnessVariable(_Variable):
    """A glossy material's GGX alpha."""

    type: Literal["roughness"] = "roughness"
    material: str
    min: Roughness
    max: Roughness


class LightIntensityVariable(_Variable):
    """A light's intensity (or an emitting object's radiance) scaled by a factor from `min` to `max`.
    `light` names an emitting object or a light as `lights[i]`."""

    type: Literal["light_intensity"] = "light_intensity"
    light: str
    min: Annotated[FiniteFloat, Field(ge=0)]
    max: Annotated[FiniteFloat, Field(ge=0)]


class LightColorVariable(_Variable):
    """A light's RGB intensity (or an emitting object's radiance), per channel that varies."""

    type: Literal["light_color"] = "light_color"
    light: str
    min: NonNegRGB
    max: NonNegRGB


class LightPositionVariable(_Variable):
    """A point light or an emitting object offset from its place, per axis that moves."""

    type: Literal["light_position"] = "light_position"
    light: str
    min: Vec3 = (0.0, 0.0, 0.0)
    max: Vec3


class EnvironmentRotationVariable(_Variable):
    """The environment map turned about the vertical axis by `min_angle` + v `range_angle` degrees."""

    type: Literal["environment_rotation"] = "environment_rotation"
    min_angle: FiniteFloat = 0.0
    range_angle: FiniteFloat


class CameraVariable(_Variable):
    """The camera's position in the box [`position_min`, `position_max`] and its target in the box
    [`target_min`, `target_max`]; one dimension per coordinate that varies."""

    type: Literal["camera"] = "camera"
    position_min: Vec3
    position_max: Vec3
    target_min: Vec3
    target_max: Vec3


Variable = Annotated[
    TranslateVariable
    | RotateVariable
    | SwitchVariable
    | AlbedoVariable
    | SpecularVariable
    | RoughnessVariable
    | LightIntensityVariable
    | LightColorVariable
    | LightPositionVariable
    | EnvironmentRotationVariable
    | CameraVariable,
    Field(discriminator="type"),
]


# --------------------------------------------------------------------------- scene


class SceneSpec(Model):
    """A complete scene: named materials, objects, lights, an environment and a camera."""

    name: str = "scene"
    materials: dict[str, Material]
    objects: list[SceneObject] = Field(min_length=1)
    lights: list[Light] = Field(default_factory=list)
    environment: Environment | None = None
    camera: Camera = Camera()
    notes: list[str] = Field(
        default_factory=list, description="what an importer defaulted or ignored; job plans list them"
    )
    variables: list[Variable] = Field(
        default_factory=list, description="what may vary: the scene vector v in [0, 1]^K (`at`)"
    )

    @model_validator(mode="after")
    def _references(self):
        names = set()
        for i, obj in enumerate(self.objects):
            if obj.material not in self.materials:
                known = ", ".join(sorted(self.materials)) or "none"
                raise ValueError(f"objects[{i}].material: unknown material {obj.material!r} (known: {known})")
            if obj.name in names:
                raise ValueError(f"objects[{i}].name: duplicate object name {obj.name!r}")
            names.add(obj.name)
        return self

    @model_validator(mode="after")
    def _variables_valid(self):
        check_variables(self)
        return self

    @property
    def dimensions(self) -> int:
        """K, the length of the scene vector."""
        return scene_dimensions(self)

    def at(self, v) -> SceneSpec:
        """The concrete scene (no variables) at the scene vector `v` in [0, 1]^K."""
        return apply_variables(self, v)

    def emitters_present(self) -> bool:
        return bool(self.lights) or self.environment is not None or any(o.emission for o in self.objects)
