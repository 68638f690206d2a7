"""USD (`.usda`, `.usdc`, `.usd`, `.usdz`) as a SceneSpec, read with Pixar's usd-core.

`import_usd` walks the stage's default predicate (instance proxies included): each UsdGeom.Mesh becomes an
object (a `UsdShape` that `prim_mesh` triangulates at compile time), placed once per instance of it (native
instancing, and UsdGeom.PointInstancer prototypes per instance). A Z-up stage is turned Y-up.
UsdPreviewSurface materials become `pbr` materials (with the default energy-conserving diffuse, as for
glTF): diffuseColor, metallic, roughness, ior, emissiveColor (on the objects, as area lights), with
UsdUVTexture inputs for diffuseColor, emissiveColor and normal (scale 2, bias -1, as UsdPreviewSurface
asks), and metallic/roughness read from the B/G channels of one texture (glTF's packing). UsdLux
lights map onto ours: distant -> directional, sphere -> point (radius 0 or treatAsPoint) or an emitting
sphere, rect -> an emitting rectangle, dome -> environment (its latlong texture, or its colour).
Intensities are colour x intensity x 2^exposure, read as our units. The first camera in traversal order
is the view. Defaults (camera, environment) and ignored features are listed in `SceneSpec.notes`, as for
glTF (`workers.scene.importers.gltf`). A layer, reference or texture outside the root file's folder is a
SceneError naming it.
"""

from __future__ import annotations

import posixpath
import zipfile
from functools import lru_cache
from pathlib import Path

import numpy as np

from workers.scene.format import spec
from workers.scene.format.errors import SceneError
from workers.scene.geometry.budget import MAX_SCENE_INSTANCES
from workers.scene.geometry.framing import framing_camera
from workers.scene.geometry.mesh import MeshData, degenerate_triangles
from workers.scene.geometry.shapes import shape_path
from workers.scene.importers.gltf import DEFAULT_ENVIRONMENT, unique_name

USD_SUFFIXES = (".usda", ".usdc", ".usd", ".usdz")
Z_UP_TO_Y_UP = np.array([[1, 0, 0, 0], [0, 0, 1, 0], [0, -1, 0, 0], [0, 0, 0, 1]], dtype=np.float64)
WRAPS = {"repeat": "repeat", "clamp": "clamp", "mirror": "mirror"}


def _pxr():
    from pxr import Gf, Usd, UsdGeom, UsdLux, UsdShade

    return Gf, Usd, UsdGeom, UsdLux, UsdShade


def _package_path(real_path: str) -> Path:
    """The file a layer or asset lives in: `pkg.usdz[inner.usdc]` lives in `pkg.usdz`."""
    return Path(real_path.split("[", 1)[0])


def _check_inside(folder: Path, real_path: str, where: str, what: str) -> None:
    target = _package_path(real_path).resolve()
    if target != folder and folder not in target.parents:
        raise SceneError(where, f"{what} {real_path!r} is outside the folder of the scene file")


def _message(error: Exception) -> str:
    """usd-core's message, or a plain one when the message quotes bytes of the file that are not UTF-8
    (reading it then raises UnicodeDecodeError, and usd-core offers no other way to it)."""
    try:
        return str(error)
    except UnicodeDecodeError:
        return "the file is not a USD layer (it holds bytes that are not UTF-8 text)"


@lru_cache(maxsize=4)
def _open(path_text: str, modified_ns: int, size: int):
    _, usd, *_ = _pxr()
    path = Path(path_text)
    try:
        stage = usd.Stage.Open(path_text)
    except Exception as error:  # usd-core raises Tf.ErrorException for unreadable layers
        raise SceneError(path.name, f"cannot open USD stage: {_message(error)}") from error
    if stage is None:
        raise SceneError(path.name, "cannot open USD stage")
    folder = path.parent.resolve()
    for layer in stage.GetUsedLayers():
        if layer.realPath:
            _check_inside(folder, layer.realPath, f"{path.name}: layer {layer.identifier}", "layer")
    errors = stage.GetCompositionErrors()
    if errors:  # a missing layer, reference or payload: usd-core only warns and composes without it
        site = getattr(errors[0], "rootSite", None)
        where = f"{path.name}: {site.path}" if site is not None else path.name
        raise SceneError(where, f"{errors[0]} ({len(errors)} composition error(s))")
    return stage


def read_stage(path: Path):
    """The opened stage, cached per path and version; every layer it uses must sit beside it."""
    path = Path(path)
    if not path.is_file():
        raise SceneError(path.name, f"USD file not found: {path}")
    stat = path.stat()
    return _open(str(path.resolve()), stat.st_mtime_ns, stat.st_size)


def package_member(path: Path, member: str) -> bytes:
    """The bytes of `member` inside the USDZ package at `path` (a zip archive)."""
    with zipfile.ZipFile(path) as package:
        try:
            return package.read(member)
        except KeyError:
            raise ValueError(f"{Path(path).name} has no {member!r}") from None


# --------------------------------------------------------------------------- geometry


def _matrix(gf_matrix) -> np.ndarray:
    """USD's row-vector matrix as our column-vector one."""
    return np.array(gf_matrix, dtype=np.float64).T


def _per_corner(values, interpolation: str, indices: np.ndarray, face_of_corner: np.ndarray, n_points: int):
    """Primvar values per face corner (N_corners, k), or None for an interpolation we do not read."""
    values = np.asarray(values, dtype=np.float64)
    if interpolation in ("vertex", "varying") and len(values) == n_points:
        return values[indices]
    if interpolation == "faceVarying" and len(values) == len(indices):
        return values
    if interpolation == "uniform" and len(values) == face_of_corner.max() + 1:
        return values[face_of_corner]
    return None


def usd_shape_mesh(shape: spec.UsdShape, field: str, base_dir: Path | None) -> MeshData:
    """The mesh of a `usd` shape (`workers.scene.geometry.registry`)."""
    return prim_mesh(shape_path(shape.path, base_dir), shape.prim, field)


def _numbers(attribute, dtype, where: str) -> np.ndarray:
    """The attribute's array; a SceneError when the file gave it a value that holds no numbers (a value of
    a type usd-core does not know reads as an UnregisteredValue) or one usd-core cannot unpack (a corrupt
    crate file: Tf.ErrorException, a RuntimeError)."""
    try:
        return np.asarray(attribute.Get() or [], dtype=dtype)
    except (TypeError, ValueError, RuntimeError):
        raise SceneError(where, f"{attribute.GetName()} cannot be read as an array of numbers") from None


def prim_mesh(path: Path, prim_path: str, field: str) -> MeshData:
    """The triangles of the UsdGeom.Mesh at `prim_path` in its own space."""
    _, _, usd_geom, _, _ = _pxr()
    try:
        stage = read_stage(path)
    except SceneError as error:
        raise SceneError(f"{field}.path", error.problem) from None
    prim = stage.GetPrimAtPath(prim_path)
    where = f"{field} ({prim_path})"
    if not prim or not prim.IsA(usd_geom.Mesh):
        raise SceneError(where, f"{Path(path).name} has no mesh at {prim_path}")
    mesh = usd_geom.Mesh(prim)
    points = _numbers(mesh.GetPointsAttr(), np.float64, where).reshape(-1, 3)
    counts = _numbers(mesh.GetFaceVertexCountsAttr(), np.int64, where)
    indices = _numbers(mesh.GetFaceVertexIndicesAttr(), np.int64, where)
    if not len(counts):
        raise SceneError(where, "the mesh has no faces (faceVertexCounts is empty)")
    if counts.sum() != len(indices) or (len(indices) and (indices.min() < 0 or indices.max() >= len(points))):
        raise SceneError(where, "faceVertexCounts and faceVertexIndices do not describe faces of the points")
    if (counts < 3).any():
        raise SceneError(where, f"face {int(np.argmax(counts < 3))} has fewer than 3 vertices")
    if not np.isfinite(points).all():
        raise SceneError(where, "some points are NaN or Inf")
    face_of_corner = np.repeat(np.arange(len(counts)), counts)
    starts = np.cumsum(counts) - counts
    # Fan triangulation of each polygon, over corner indices.
    fans = np.repeat(starts, counts - 2)
    k = np.arange(len(fans)) - np.repeat(np.cumsum(counts - 2) - (counts - 2), counts - 2)
    triangles = np.stack([fans, fans + k + 1, fans + k + 2], axis=1)
    if mesh.GetOrientationAttr().Get() == "leftHanded":
        triangles = triangles[:, ::-1]
    normals = None
    primvars = usd_geom.PrimvarsAPI(prim)
    normal_var = primvars.GetPrimvar("normals")
    if normal_var and normal_var.HasValue():
        normals = _per_corner(
            normal_var.ComputeFlattened(), normal_var.GetInterpolation(), indices, face_of_corner, len(points)
        )
    elif mesh.GetNormalsAttr().HasValue():
        normals = _per_corner(
            mesh.GetNormalsAttr().Get(), mesh.GetNormalsInterpolation(), indices, face_of_corner, len(points)
        )
    uvs = None
    st = primvars.GetPrimvar("st")
    if st and st.HasValue():
        uvs = _per_corner(st.ComputeFlattened(), st.GetInterpolation(), indices, face_of_corner, len(points))
        if uvs is not None:
            uvs = np.stack([uvs[:, 0], 1.0 - uvs[:, 1]], axis=1)  # USD's st origin is the bottom-left
    # One vertex per distinct (point, normal, st) among the corners: shared where the data is per vertex,
    # split along seams of face-varying data.
    corner_data = [a for a in (normals, uvs) if a is not None]
    key = np.concatenate([indices[:, None].astype(np.float64), *corner_data], axis=1)
    _, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
    return MeshData(
        points[indices[first]],
        inverse.reshape(-1)[triangles],
        None if normals is None else normals[first],
        None if uvs is None else uvs[first],
    )


# --------------------------------------------------------------------------- the scene


class _Importer:
    def __init__(self, path: Path, prefix: str):
        self.path, self.prefix = path, prefix
        self.folder = path.parent.resolve()
        self.notes: list[str] = []
        self.ignored: set[str] = set()

    def texture(self, shader, output: str, color_space: str, where: str) -> spec.ImageTexture | None:
        """A UsdUVTexture as an ImageTexture; its `sourceColorSpace` wins over `color_space` when set."""
        if shader.GetIdAttr().Get() != "UsdUVTexture":
            self.ignored.add(f"{where}: {shader.GetIdAttr().Get()} shader (not a UsdUVTexture)")
            return None
        file_input = shader.GetInput("file")
        asset = file_input.Get() if file_input else None
        if asset is None or not asset.resolvedPath:
            raise SceneError(where, f"texture {asset.path if asset else '(none)'!r} is missing")
        resolved = asset.resolvedPath
        _check_inside(self.folder, resolved, where, "texture")
        st = shader.GetInput("st")
        if st and st.HasConnectedSource():
            reader = _pxr()[4].Shader(st.GetConnectedSource()[0].GetPrim())
            if reader.GetIdAttr().Get() != "UsdPrimvarReader_float2":
                self.ignored.add(f"{where}: {reader.GetIdAttr().Get()} on st (the mesh's st is used)")
        declared = shader.GetInput("sourceColorSpace")
        declared = declared.Get() if declared else None
        if declared == "raw":
            color_space = "linear"
        elif declared == "sRGB":
            color_space = "srgb"
        wraps = []
        for name in ("wrapS", "wrapT"):
            value = shader.GetInput(name).Get() if shader.GetInput(name) else None
            if value not in (None, "useMetadata") and value not in WRAPS:
                self.ignored.add(f"{where}: wrap mode {value!r} (read as clamp)")
            wraps.append(WRAPS.get(value, "clamp" if value == "black" else "repeat"))
        package = _package_path(resolved).resolve()
        relative = package.relative_to(self.folder).as_posix()
        member = resolved.split("[", 1)[1].rstrip("]") if "[" in resolved else None
        return spec.ImageTexture(
            path=posixpath.join(self.prefix, relative),
            member=member,
            color_space=color_space,
            wrap_u=wraps[0],
            wrap_v=wraps[1],
        )

    def material(self, material, name: str) -> tuple[spec.PbrMaterial, tuple[float, float, float]]:
        """A UsdPreviewSurface as a pbr material, and its emitted radiance."""
        where = f"{material.GetPath()}"
        shader = material.ComputeSurfaceSource()[0]
        if not shader or shader.GetIdAttr().Get() != "UsdPreviewSurface":
            self.ignored.add(f"{where}: surface is not a UsdPreviewSurface (a default grey material)")
            return spec.PbrMaterial(base_color=(0.18, 0.18, 0.18), metallic=0.0, roughness=0.5), (
                0.0,
                0.0,
                0.0,
            )

        def read(input_name: str, default):
            """(constant, (source shader, output name) or None)."""
            inp = shader.GetInput(input_name)
            if not inp:
                return default, None
            if inp.HasConnectedSource():
                source, output, _ = inp.GetConnectedSource()
                return default, (_pxr()[4].Shader(source.GetPrim()), output)
            value = inp.Get()
            return (default if value is None else value), None

        diffuse, diffuse_tex = read("diffuseColor", (0.18, 0.18, 0.18))
        metallic, metallic_tex = read("metallic", 0.0)
        roughness, roughness_tex = read("roughness", 0.5)
        ior, _ = read("ior", 1.5)
        emissive, emissive_tex = read("emissiveColor", (0.0, 0.0, 0.0))
        _, normal_tex = read("normal", None)
        for unsupported in ("opacity", "clearcoat", "displacement", "occlusion"):
            value, source = read(unsupported, None)
            if source is not None or (unsupported == "opacity" and value not in (None, 1.0)):
                self.ignored.add(f"{where}: {unsupported}")
        if read("useSpecularWorkflow", 0)[0]:
            self.ignored.add(f"{where}: useSpecularWorkflow (metallic workflow used)")
        mr_texture = None
        if metallic_tex or roughness_tex:
            same = metallic_tex and roughness_tex and metallic_tex[0].GetPath() == roughness_tex[0].GetPath()
            if same and metallic_tex[1] == "b" and roughness_tex[1] == "g":
                mr_texture = self.texture(metallic_tex[0], "b", "linear", f"{where}.metallic")
                metallic = roughness = 1.0  # the texels are the values (glTF: texel x factor)
            else:
                self.ignored.add(f"{where}: metallic/roughness textures not packed as glTF's (B, G)")

        def colour(source, space: str, what: str):
            return None if source is None else self.texture(source[0], source[1], space, f"{where}.{what}")

        base_texture = colour(diffuse_tex, "srgb", "diffuseColor")
        emission_texture = colour(emissive_tex, "srgb", "emissiveColor")
        if emission_texture is not None and max(emissive) == 0:
            emissive = (1.0, 1.0, 1.0)  # a connected input's value is the texture's
        pbr = spec.PbrMaterial(
            base_color=(1.0, 1.0, 1.0) if base_texture is not None else tuple(float(c) for c in diffuse),
            base_color_texture=base_texture,
            metallic=float(metallic),
            roughness=float(roughness),
            metallic_roughness_texture=mr_texture,
            ior=max(float(ior), 1.001),
            normal_texture=colour(normal_tex, "linear", "normal"),
            emission_texture=emission_texture,
        )
        return pbr, tuple(float(c) for c in emissive)


def _world(prim, time) -> np.ndarray:
    _, _, usd_geom, _, _ = _pxr()
    return _matrix(usd_geom.Xformable(prim).ComputeLocalToWorldTransform(time))


def import_usd(path: Path, prefix: str = "") -> spec.SceneSpec:
    """The scene of the USD file at `path`; paths relative to the folder `prefix` names (as for glTF).
    usd-core's own errors while it reads the stage (Tf.ErrorException: metadata of the wrong type, values
    a corrupt crate file cannot unpack) are the file's."""
    from pxr import Tf

    try:
        return _scene(Path(path), prefix)
    except Tf.ErrorException as error:
        raise SceneError(Path(path).name, f"usd-core cannot read it: {_message(error).strip()}") from None


def _scene(path: Path, prefix: str) -> spec.SceneSpec:
    _, usd, usd_geom, usd_lux, usd_shade = _pxr()
    path = Path(path)
    stage = read_stage(path)
    importer = _Importer(path, prefix)
    time = usd.TimeCode.Default()
    up = Z_UP_TO_Y_UP if usd_geom.GetStageUpAxis(stage) == usd_geom.Tokens.z else np.eye(4)
    if up is Z_UP_TO_Y_UP:
        importer.notes.append("axes: the stage is Z-up; turned Y-up")
    placements: dict[str, list[np.ndarray]] = {}
    bound: dict[str, object] = {}
    first_instance: dict[str, str] = {}
    xforms = usd_geom.XformCache(time)
    cameras, lights = [], []
    prims = iter(usd.PrimRange.Stage(stage, usd.TraverseInstanceProxies(usd.PrimDefaultPredicate)))
    for prim in prims:
        if prim.IsA(usd_geom.Imageable) and usd_geom.Imageable(prim).ComputeVisibility(time) == "invisible":
            prims.PruneChildren()
            continue
        if prim.IsA(usd_geom.PointInstancer):
            prims.PruneChildren()  # its prototypes are placed per instance below, not where they sit
            _instanced(prim, up @ _world(prim, time), placements, bound, time, importer)
        elif prim.IsA(usd_geom.Mesh):
            # Instances of one prototype share its geometry, keyed by the first instance's path (the
            # prototypes' own paths are made up per session).
            source = prim.GetPrimInPrototype() if prim.IsInstanceProxy() else prim
            key = first_instance.setdefault(str(source.GetPath()), str(prim.GetPath()))
            placements.setdefault(key, []).append(up @ _matrix(xforms.GetLocalToWorldTransform(prim)))
            bound.setdefault(key, usd_shade.MaterialBindingAPI(prim).ComputeBoundMaterial()[0])
        elif prim.IsA(usd_geom.Camera):
            cameras.append(prim)
        elif prim.HasAPI(usd_lux.LightAPI):
            lights.append(prim)
        elif prim.IsA(usd_geom.Gprim):
            importer.ignored.add(f"{prim.GetPath()}: {prim.GetTypeName()} (only meshes are rendered)")
    placements = {key: matrices for key, matrices in placements.items() if matrices}  # instanced 0 times
    if not placements:
        raise SceneError(path.name, "the USD stage has no mesh to render")

    materials: dict[str, spec.Material] = {}
    by_material: dict[str, tuple[str, tuple[float, float, float]]] = {}
    names: set[str] = set()
    object_names: set[str] = set()
    objects = []
    geometry = {key: prim_mesh(path, key, path.name) for key in placements}
    for key, matrices in placements.items():
        material = bound[key]
        material_key = str(material.GetPath()) if material else ""
        if material_key not in by_material:
            name = unique_name(Path(material_key).name if material_key else "default", "default", names)
            if material:
                materials[name], emitted = importer.material(material, name)
            else:  # UsdPreviewSurface's defaults
                materials[name] = spec.PbrMaterial(base_color=(0.18,) * 3, metallic=0.0, roughness=0.5)
                emitted = (0.0, 0.0, 0.0)
            by_material[material_key] = (name, emitted)
        material_name, emitted = by_material[material_key]
        name = unique_name(key.rsplit("/", 1)[-1], "mesh", object_names)
        degenerate = int(degenerate_triangles(geometry[key].vertices, geometry[key].faces).sum())
        if degenerate:
            importer.notes.append(
                f"geometry: {name}: dropped {degenerate} degenerate (zero-area) triangle(s)"
            )
        transforms = [spec.Transform(matrix=tuple(tuple(row) for row in m[:3].tolist())) for m in matrices]
        objects.append(
            spec.SceneObject(
                name=name,
                shape=spec.UsdShape(path=posixpath.join(prefix, path.name), prim=key, repair=degenerate > 0),
                material=material_name,
                emission=emitted if max(emitted) > 0 else None,
                transform=transforms[0] if len(transforms) == 1 else spec.Transform(),
                instances=None if len(transforms) == 1 else transforms,
            )
        )

    scene_lights, environment = [], None
    for prim in lights:
        light, env, emitter = _light(prim, up @ _world(prim, time), importer, materials, object_names)
        scene_lights += [light] if light is not None else []
        environment = env or environment
        objects += [emitter] if emitter is not None else []
    if cameras:
        camera = _camera(cameras[0], up @ _world(cameras[0], time), time)
        if len(cameras) > 1:
            importer.notes.append(f"camera: {cameras[0].GetPath()}, the first of {len(cameras)}")
    else:
        points = np.concatenate(
            [geometry[k].vertices @ m[:3, :3].T + m[:3, 3] for k, ms in placements.items() for m in ms]
        )
        camera = framing_camera(np.stack([points.min(0), points.max(0)]))
        importer.notes.append("camera: none in the file; a default camera frames the scene's bounds")
    if not scene_lights and environment is None and not any(o.emission for o in objects):
        environment = spec.EnvironmentMap(procedural=DEFAULT_ENVIRONMENT)
        importer.notes.append(
            f"environment: the file has no light or emission; the default {DEFAULT_ENVIRONMENT!r} environment"
        )
    notes = importer.notes + [f"ignored: {feature}" for feature in sorted(importer.ignored)]
    return spec.SceneSpec(
        name=path.stem,
        materials=materials,
        objects=objects,
        lights=scene_lights,
        environment=environment,
        camera=camera,
        notes=notes,
    )


def _instanced(instancer_prim, world: np.ndarray, placements, bound, time, importer: _Importer) -> None:
    """Each prototype's meshes, placed once per instance of the point instancer."""
    _, usd, usd_geom, _, usd_shade = _pxr()
    instancer = usd_geom.PointInstancer(instancer_prim)
    prototypes = instancer.GetPrototypesRel().GetTargets()
    where = f"{importer.path.name} ({instancer_prim.GetPath()})"
    proto_indices = _numbers(instancer.GetProtoIndicesAttr(), np.int64, where)  # time is Default
    if (placed := len(proto_indices) + sum(map(len, placements.values()))) > MAX_SCENE_INSTANCES:
        raise SceneError(
            importer.path.name,
            f"{instancer_prim.GetPath()}: {placed:,} instances, over the limit of {MAX_SCENE_INSTANCES:,}",
        )
    if len(proto_indices) and (proto_indices.min() < 0 or proto_indices.max() >= len(prototypes)):
        raise SceneError(
            importer.path.name,
            f"{instancer_prim.GetPath()}: protoIndices name prototypes it lacks (it has {len(prototypes)})",
        )
    matrices = instancer.ComputeInstanceTransformsAtTime(time, time)
    if len(matrices) != len(proto_indices):  # usd-core warns and returns none when the arrays disagree
        raise SceneError(
            importer.path.name,
            f"{instancer_prim.GetPath()}: {len(proto_indices):,} protoIndices but {len(matrices):,} instance "
            "transforms: positions (and orientations, scales when given) need one entry per instance",
        )
    cache = usd_geom.XformCache(time)
    for p, proto_path in enumerate(prototypes):
        proto = instancer_prim.GetStage().GetPrimAtPath(proto_path)
        chosen = [_matrix(matrices[int(i)]) for i in np.flatnonzero(proto_indices == p)]
        for prim in usd.PrimRange(proto):
            if not prim.IsA(usd_geom.Mesh):
                continue
            relative, _ = cache.ComputeRelativeTransform(prim, proto.GetParent())
            inner = _matrix(relative)
            key = str(prim.GetPath())
            placements.setdefault(key, []).extend(world @ m @ inner for m in chosen)
            bound.setdefault(key, usd_shade.MaterialBindingAPI(prim).ComputeBoundMaterial()[0])
    if not len(proto_indices):
        importer.ignored.add(f"{instancer_prim.GetPath()}: point instancer without instances")


def _camera(prim, world: np.ndarray, time) -> spec.Camera:
    gf, _, usd_geom, _, _ = _pxr()
    camera = usd_geom.Camera(prim).GetCamera(time)
    position = world[:3, 3]
    forward = world[:3, :3] @ np.array([0.0, 0.0, -1.0])
    up = world[:3, :3] @ np.array([0.0, 1.0, 0.0])
    height = 256
    return spec.Camera(
        position=tuple(position.tolist()),
        target=tuple((position + forward / np.linalg.norm(forward)).tolist()),
        up=tuple((up / np.linalg.norm(up)).tolist()),
        fov=min(max(camera.GetFieldOfView(gf.Camera.FOVVertical), 0.2), 178.0),
        width=max(1, round(height * camera.aspectRatio)),
        height=height,
    )


def _light(prim, world: np.ndarray, importer: _Importer, materials: dict, names: set[str]):
    """(light, environment, emitting object) for a UsdLux light; Nones for what it is not."""
    _, _, _, usd_lux, _ = _pxr()
    where = str(prim.GetPath())
    api = usd_lux.LightAPI(prim)
    colour = np.asarray(api.GetColorAttr().Get() or (1.0, 1.0, 1.0), dtype=np.float64)
    scale = float(api.GetIntensityAttr().Get() or 0.0) * 2.0 ** float(api.GetExposureAttr().Get() or 0.0)
    rgb = tuple(float(c) for c in np.maximum(colour * scale, 0.0))
    if api.GetNormalizeAttr().Get():
        importer.ignored.add(f"{where}: normalize (intensity read as radiance)")
    position = tuple(world[:3, 3].tolist())
    axis = world[:3, :3] @ np.array([0.0, 0.0, -1.0])
    if prim.IsA(usd_lux.DistantLight):
        direction = tuple((axis / np.linalg.norm(axis)).tolist())
        return spec.DirectionalLight(direction=direction, irradiance=rgb), None, None
    if prim.IsA(usd_lux.DomeLight):
        texture = usd_lux.DomeLight(prim).GetTextureFileAttr().Get()
        if texture is not None and texture.resolvedPath:
            _check_inside(importer.folder, texture.resolvedPath, where, "dome texture")
            relative = Path(texture.resolvedPath).resolve().relative_to(importer.folder).as_posix()
            importer.notes.append(f"environment: {where}'s latlong map, in Mitsuba's orientation")
            return (
                None,
                spec.EnvironmentMap(path=posixpath.join(importer.prefix, relative), scale=scale),
                None,
            )
        return None, spec.ConstantBackground(radiance=rgb), None
    emitter = None
    if prim.IsA(usd_lux.SphereLight):
        sphere = usd_lux.SphereLight(prim)
        radius = float(sphere.GetRadiusAttr().Get() or 0.0)
        if radius <= 0 or sphere.GetTreatAsPointAttr().Get():
            return spec.PointLight(position=position, intensity=rgb), None, None
        shape = spec.SphereShape(radius=radius, subdivisions=3)
        emitter = (shape, spec.Transform(matrix=tuple(tuple(r) for r in world[:3].tolist())))
    elif prim.IsA(usd_lux.RectLight):
        rect = usd_lux.RectLight(prim)
        size = np.diag(
            [float(rect.GetWidthAttr().Get()) / 2, float(rect.GetHeightAttr().Get()) / 2, -1.0, 1.0]
        )
        size[1, 1] *= -1  # a 180-degree turn about x: our rectangle faces +z, USD's rect light emits along -z
        matrix = world @ size
        emitter = (spec.RectangleShape(), spec.Transform(matrix=tuple(tuple(r) for r in matrix[:3].tolist())))
    if emitter is None:
        importer.ignored.add(f"{where}: {prim.GetTypeName()}")
        return None, None, None
    if "usd_light" not in materials:
        materials["usd_light"] = spec.Diffuse(reflectance=(0.0, 0.0, 0.0))
    shape, transform = emitter
    name = unique_name(where.rsplit("/", 1)[-1], "light", names)
    obj = spec.SceneObject(name=name, shape=shape, material="usd_light", emission=rgb, transform=transform)
    return None, None, obj
