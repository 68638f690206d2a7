"""glTF 2.0 (`.gltf` with its buffers and images, `.glb`) as a SceneSpec, read with pygltflib.

`import_gltf` turns the default scene's node hierarchy into objects: one per (mesh, primitive), a
`GltfShape` that `primitive_mesh` reads back at compile time, placed once per node using the mesh
(instancing). Materials become `pbr` materials (`workers.render.bsdfs.pbr`) with the extensions
KHR_materials_ior, KHR_materials_transmission and KHR_materials_emissive_strength, and the default
energy-conserving diffuse (glTF leaves the diffuse model to the renderer; a scene file overriding a
material by name can ask for principled's, `diffuse: burley`); emission goes on the objects as area
lights (one-sided unless the material is double-sided). KHR_lights_punctual point and
directional lights, and spot lights as point lights with glTF's smooth cone falloff, keep their intensity
numbers (candela and lux read as W/sr and W/m^2: one photometric unit per radiometric one, as renderers
without a photometric scale do). The first perspective camera in node order is the view.

Defaults, each recorded in `SceneSpec.notes` (job plans list them): no camera gives a camera framing the
scene's bounds (`workers.scene.geometry.framing`); no light and no emission gives the
`studio` environment. Unsupported optional features are listed as ignored; an unsupported extension in
`extensionsRequired`, a non-triangle primitive, a sparse accessor or a reference leaving the file's
folder is a SceneError naming it.
"""

from __future__ import annotations

import base64
import math
import posixpath
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from urllib.parse import unquote

import numpy as np
import pygltflib

from workers.scene.format import spec
from workers.scene.format.errors import SceneError
from workers.scene.geometry.framing import framing_camera
from workers.scene.geometry.mesh import MeshData, degenerate_triangles
from workers.scene.geometry.shapes import shape_path

GLTF_SUFFIXES = (".gltf", ".glb")
SUPPORTED_EXTENSIONS = frozenset(
    {
        "KHR_materials_ior",
        "KHR_materials_transmission",
        "KHR_materials_emissive_strength",
        "KHR_lights_punctual",
    }
)
TRIANGLES, TRIANGLE_STRIP, TRIANGLE_FAN = 4, 5, 6
MODE_NAMES = {0: "POINTS", 1: "LINES", 2: "LINE_LOOP", 3: "LINE_STRIP"}
COMPONENTS = {5120: "i1", 5121: "u1", 5122: "<i2", 5123: "<u2", 5125: "<u4", 5126: "<f4"}
WIDTHS = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}
WRAPS = {10497: "repeat", 33071: "clamp", 33648: "mirror"}
DEFAULT_ENVIRONMENT = "studio"


# --------------------------------------------------------------------------- reading the file


@dataclass
class GltfFile:
    """A parsed glTF document and its buffers' bytes."""

    path: Path
    document: pygltflib.GLTF2
    buffers: list[bytes]


def item(items: list | None, index, where: str, what: str):
    """`items[index]`, or a SceneError naming `where` when the file's index is not one of them."""
    items = items or []
    if isinstance(index, bool) or not isinstance(index, int) or not 0 <= index < len(items):
        raise SceneError(where, f"{what} {index!r} does not exist (the file has {len(items)})")
    return items[index]


def _inside_folder(path: Path, uri: str, where: str) -> Path:
    """The file a relative URI names, which must stay in the glTF file's folder (uploads are confined)."""
    relative = unquote(uri)
    if "://" in relative or relative.startswith(("/", "\\")) or ":" in relative.split("/")[0]:
        raise SceneError(where, f"{uri!r} must be a relative path inside the glTF file's folder")
    folder = path.parent.resolve()
    target = (folder / relative).resolve()
    if folder not in target.parents:
        raise SceneError(where, f"{uri!r} points outside the glTF file's folder")
    return target


def _uri_bytes(gltf_path: Path, uri: str, where: str) -> bytes:
    if uri.startswith("data:"):
        header, _, payload = uri.partition(",")
        if not header.endswith(";base64"):
            raise SceneError(where, "data URIs must be base64-encoded")
        try:
            return base64.b64decode(payload, validate=True)
        except ValueError as error:  # binascii.Error, or a character that is not ASCII
            raise SceneError(where, f"the data URI is not valid base64: {error}") from None
    target = _inside_folder(gltf_path, uri, where)
    if not target.is_file():
        raise SceneError(where, f"{uri!r} is missing (looked for {target.name} next to {gltf_path.name})")
    return target.read_bytes()


@lru_cache(maxsize=8)
def _read(path_text: str, modified_ns: int, size: int) -> GltfFile:
    path = Path(path_text)
    try:
        document = pygltflib.GLTF2.load(path_text)
    except Exception as error:  # pygltflib surfaces malformed JSON and GLB chunks as many exception types
        raise SceneError(path.name, f"cannot read glTF: {type(error).__name__}: {error}") from error
    if document is None:
        raise SceneError(path.name, "cannot read glTF: not a glTF 2.0 file")
    buffers = []
    for i, buffer in enumerate(document.buffers):
        if buffer.uri is None:
            blob = document.binary_blob()
            if i != 0 or blob is None:
                raise SceneError(f"{path.name}: buffers[{i}]", "buffer has no URI and no GLB binary chunk")
            buffers.append(bytes(blob))
        else:
            buffers.append(_uri_bytes(path, buffer.uri, f"{path.name}: buffers[{i}].uri"))
    return GltfFile(path, document, buffers)


def read_gltf(path: Path) -> GltfFile:
    """The parsed file, cached per path and version (a compile reads every primitive of one file)."""
    path = Path(path)
    if not path.is_file():
        raise SceneError(path.name, f"glTF file not found: {path}")
    stat = path.stat()
    return _read(str(path.resolve()), stat.st_mtime_ns, stat.st_size)


def _view_bytes(file: GltfFile, index: int, where: str) -> tuple[bytes, int, int, int | None]:
    """(buffer, start, length, stride) of buffer view `index`."""
    view = item(file.document.bufferViews, index, where, "buffer view")
    data = item(file.buffers, view.buffer, f"{where}: bufferViews[{index}].buffer", "buffer")
    start = view.byteOffset or 0
    if view.byteLength is None:
        raise SceneError(f"{where}: bufferViews[{index}]", "byteLength is required")
    if start < 0 or view.byteLength < 0 or start + view.byteLength > len(data):
        raise SceneError(where, f"buffer view {index} runs past the end of buffer {view.buffer}")
    return data, start, view.byteLength, view.byteStride


def accessor(file: GltfFile, index: int, where: str) -> np.ndarray:
    """(count, width) array of accessor `index`; normalized integers become floats in [0, 1] / [-1, 1]."""
    acc = item(file.document.accessors, index, where, "accessor")
    where = f"{where} (accessors[{index}])"
    if acc.sparse is not None:
        raise SceneError(where, "sparse accessors are not supported")
    if acc.componentType not in COMPONENTS or acc.type not in WIDTHS:
        raise SceneError(where, f"unknown component type {acc.componentType} or type {acc.type!r}")
    if isinstance(acc.count, bool) or not isinstance(acc.count, int) or acc.count < 0:
        raise SceneError(where, f"count {acc.count!r} is not a whole number of elements")
    dtype, width = np.dtype(COMPONENTS[acc.componentType]), WIDTHS[acc.type]
    element = dtype.itemsize * width
    if acc.bufferView is None:
        _zeros_fit(file, acc.count * element, where)
        return np.zeros((acc.count, width), dtype)
    data, start, length, stride = _view_bytes(file, acc.bufferView, where)
    stride = stride or element
    byte_offset = acc.byteOffset or 0
    if byte_offset < 0 or stride < element:
        raise SceneError(where, f"byteOffset {byte_offset} or byteStride {stride} is out of range")
    offset = start + byte_offset
    if acc.count and byte_offset + stride * (acc.count - 1) + element > length:
        raise SceneError(where, "accessor runs past the end of its buffer view")
    array = np.ndarray(
        (acc.count, width), dtype, buffer=data, offset=offset, strides=(stride, dtype.itemsize)
    )
    array = array.copy()
    if acc.normalized and dtype.kind in "iu":
        array = array.astype(np.float64) / np.iinfo(dtype).max
        array = np.maximum(array, -1.0)
    return array


def _zeros_fit(file: GltfFile, size: int, where: str) -> None:
    """An accessor without a buffer view is zeros (glTF fills it so): it may not ask for more bytes than
    the file's buffers hold, so a few bytes of JSON cannot allocate gigabytes."""
    held = sum(len(buffer) for buffer in file.buffers)
    if size > held:
        raise SceneError(
            where, f"an accessor without a bufferView asks for {size} bytes, more than the file's {held}"
        )


def embedded_image(path: Path, index: int) -> bytes:
    """The encoded bytes of image `index` of the glTF file at `path` (a buffer view or a data URI)."""
    file = read_gltf(path)
    images = file.document.images
    if not 0 <= index < len(images):
        raise ValueError(f"images[{index}] does not exist in {Path(path).name}")
    image = images[index]
    where = f"{Path(path).name}: images[{index}]"
    if image.bufferView is not None:
        data, start, length, _ = _view_bytes(file, image.bufferView, where)
        return data[start : start + length]
    if image.uri is not None:
        return _uri_bytes(file.path, image.uri, where)
    raise ValueError(f"{where} has neither a buffer view nor a URI")


# --------------------------------------------------------------------------- geometry


def _triangles(indices: np.ndarray, mode: int) -> np.ndarray:
    """(F, 3) triangles of a triangle list, strip or fan (strips alternate winding to keep it)."""
    if mode == TRIANGLES:
        return indices[: len(indices) // 3 * 3].reshape(-1, 3)
    k = np.arange(len(indices) - 2)
    if mode == TRIANGLE_STRIP:
        even = k % 2 == 0
        a = np.where(even, indices[k], indices[k + 1])
        b = np.where(even, indices[k + 1], indices[k])
        return np.stack([a, b, indices[k + 2]], axis=1)
    return np.stack([np.full(len(k), indices[0]), indices[k + 1], indices[k + 2]], axis=1)


def gltf_shape_mesh(shape: spec.GltfShape, field: str, base_dir: Path | None) -> MeshData:
    """The mesh of a `gltf` shape (`workers.scene.geometry.registry`)."""
    return primitive_mesh(shape_path(shape.path, base_dir), shape.mesh, shape.primitive, field)


def primitive_mesh(path: Path, mesh: int, primitive: int, field: str) -> MeshData:
    """Primitive `primitive` of mesh `mesh` in the file at `path`, in the mesh's space."""
    try:
        file = read_gltf(path)
    except SceneError as error:
        raise SceneError(f"{field}.path", error.problem) from None
    meshes = file.document.meshes
    if not 0 <= mesh < len(meshes) or not 0 <= primitive < len(meshes[mesh].primitives):
        raise SceneError(field, f"{Path(path).name} has no mesh {mesh} with a primitive {primitive}")
    prim = meshes[mesh].primitives[primitive]
    where = f"{field} (meshes[{mesh}].primitives[{primitive}])"
    mode = TRIANGLES if prim.mode is None else prim.mode
    if mode not in (TRIANGLES, TRIANGLE_STRIP, TRIANGLE_FAN):
        raise SceneError(where, f"mode {mode} ({MODE_NAMES.get(mode, '?')}) is not triangles")
    attributes = prim.attributes
    if attributes.POSITION is None:
        raise SceneError(where, "the primitive has no POSITION attribute")
    vertices = accessor(file, attributes.POSITION, where).astype(np.float64)
    if vertices.shape[1] != 3:
        raise SceneError(f"{where} (accessors[{attributes.POSITION}])", "POSITION must be a VEC3 accessor")
    if prim.indices is not None:
        indices = accessor(file, prim.indices, where)[:, 0].astype(np.int64)
    else:
        indices = np.arange(len(vertices))
    if len(indices) and (indices.min() < 0 or indices.max() >= len(vertices)):
        raise SceneError(where, f"indices reach {int(indices.max())}, past the {len(vertices)} vertices")
    bad = ~np.isfinite(vertices).all(axis=1)
    if bad.any():
        raise SceneError(
            where, f"{int(bad.sum())} vertices are NaN or Inf (first at index {int(np.argmax(bad))})"
        )
    faces = _triangles(indices, mode)

    def optional(index, width):
        if index is None:
            return None
        values = accessor(file, index, where).astype(np.float64)
        return values[:, :width] if values.shape == (len(vertices), values.shape[1]) else None

    return MeshData(
        vertices,
        faces,
        optional(attributes.NORMAL, 3),
        optional(attributes.TEXCOORD_0, 2),  # glTF's UV origin is the image's top-left, as ours
        optional(attributes.TANGENT, 4),
        optional(attributes.COLOR_0, 3),  # linear RGB(A), floats or normalized integers; alpha dropped
    )


# --------------------------------------------------------------------------- the scene


def _numbers(values, default: tuple[float, ...], field: str) -> np.ndarray:
    """A node's `values` (or `default`), which must be as many numbers as `default`."""
    if values is None:
        return np.array(default)
    try:
        array = np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError):
        array = None
    if array is None or array.shape != (len(default),):
        raise SceneError(field, f"must be a list of {len(default)} numbers")
    return array


def _node_matrix(node: pygltflib.Node, where: str) -> np.ndarray:
    if node.matrix is not None:
        return _numbers(node.matrix, (0.0,) * 16, f"{where}.matrix").reshape(4, 4).T  # column-major
    x, y, z, w = _numbers(node.rotation, (0.0, 0.0, 0.0, 1.0), f"{where}.rotation")
    rotation = np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )
    m = np.eye(4)
    m[:3, :3] = rotation @ np.diag(_numbers(node.scale, (1.0, 1.0, 1.0), f"{where}.scale"))
    m[:3, 3] = _numbers(node.translation, (0.0, 0.0, 0.0), f"{where}.translation")
    return m


def _walk(document: pygltflib.GLTF2) -> list[tuple[int, np.ndarray]]:
    """(node index, node-to-world matrix) of the default scene's nodes, parents first."""
    if document.scenes:
        scene = document.scene or 0
        roots, field = item(document.scenes, scene, "scene", "scene").nodes or [], f"scenes[{scene}].nodes"
    else:  # no scene: every node that is nobody's child
        children = {c for node in document.nodes for c in node.children or []}
        roots, field = [i for i in range(len(document.nodes)) if i not in children], "nodes"
    out, stack, seen = [], [(r, np.eye(4), field) for r in reversed(roots)], set()
    while stack:
        index, parent, field = stack.pop()
        node = item(document.nodes, index, field, "node")
        if index in seen:
            raise SceneError(f"nodes[{index}]", "the node hierarchy is not a tree (a node is reached twice)")
        seen.add(index)
        world = parent @ _node_matrix(node, f"nodes[{index}]")
        out.append((index, world))
        stack.extend((child, world, f"nodes[{index}].children") for child in reversed(node.children or []))
    return out


def _extension(obj, name: str) -> dict:
    return (obj.extensions or {}).get(name) or {}


class _Importer:
    """Builds the SceneSpec pieces; paths in it are `prefix`-relative (the folder a scene file resolves)."""

    def __init__(self, file: GltfFile, prefix: str):
        self.file, self.doc, self.prefix = file, file.document, prefix
        self.notes: list[str] = []
        self.ignored: set[str] = set()

    def ignore(self, feature: str) -> None:
        self.ignored.add(feature)

    def texture(self, info, color_space: str, where: str) -> spec.ImageTexture | None:
        if info is None:
            return None
        texture = item(self.doc.textures, info.index, f"{where}.index", "texture")
        if texture.source is None:
            raise SceneError(where, f"texture {info.index} has no image")
        if (info.texCoord or 0) != 0:
            self.ignore(f"{where}: TEXCOORD_{info.texCoord} (read with TEXCOORD_0)")
        if info.extensions:
            self.ignore(f"{where}: extensions {sorted(info.extensions)}")
        wrap_u = wrap_v = "repeat"
        if texture.sampler is not None:
            sampler = item(self.doc.samplers, texture.sampler, f"{where}.sampler", "sampler")
            wrap_u, wrap_v = WRAPS.get(sampler.wrapS, "repeat"), WRAPS.get(sampler.wrapT, "repeat")
        image = item(self.doc.images, texture.source, f"{where}.source", "image")
        own_path = posixpath.join(self.prefix, self.file.path.name)
        if image.uri is not None and not image.uri.startswith("data:"):
            target = _inside_folder(self.file.path, image.uri, f"{where}: images[{texture.source}].uri")
            if not target.is_file():
                raise SceneError(where, f"image {image.uri!r} is missing (looked for {target.name})")
            path, index = posixpath.join(self.prefix, unquote(image.uri)), None
        else:
            path, index = own_path, texture.source
        return spec.ImageTexture(
            path=path, image=index, color_space=color_space, wrap_u=wrap_u, wrap_v=wrap_v
        )

    def material(self, index: int) -> tuple[spec.PbrMaterial, tuple[float, float, float], bool]:
        """The material, its emitted radiance and whether it is double-sided."""
        where = f"materials[{index}]"
        m = item(self.doc.materials, index, where, "material")
        pbr = m.pbrMetallicRoughness or pygltflib.PbrMetallicRoughness()
        known = SUPPORTED_EXTENSIONS | {"KHR_lights_punctual"}
        for name in m.extensions or {}:
            if name not in known:
                self.ignore(f"{where}: {name}")
        if (m.alphaMode or "OPAQUE") != "OPAQUE":
            self.ignore(f"{where}: alphaMode {m.alphaMode} (rendered opaque)")
        if m.occlusionTexture is not None:
            self.ignore(f"{where}: occlusionTexture (the path tracer computes occlusion)")
        base = pbr.baseColorFactor or [1.0, 1.0, 1.0, 1.0]
        transmission = _extension(m, "KHR_materials_transmission")
        normal = m.normalTexture
        material = spec.PbrMaterial(
            base_color=tuple(float(c) for c in base[:3]),
            base_color_texture=self.texture(pbr.baseColorTexture, "srgb", f"{where}.baseColorTexture"),
            metallic=1.0 if pbr.metallicFactor is None else pbr.metallicFactor,
            roughness=1.0 if pbr.roughnessFactor is None else pbr.roughnessFactor,
            metallic_roughness_texture=self.texture(
                pbr.metallicRoughnessTexture, "linear", f"{where}.metallicRoughnessTexture"
            ),
            ior=min(max(float(_extension(m, "KHR_materials_ior").get("ior", 1.5)), 1.001), 4.0),
            transmission=float(transmission.get("transmissionFactor", 0.0)),
            transmission_texture=self.texture(
                _texture_info(transmission.get("transmissionTexture")),
                "linear",
                f"{where}.transmissionTexture",
            ),
            normal_texture=self.texture(normal, "linear", f"{where}.normalTexture"),
            normal_scale=1.0 if normal is None or normal.scale is None else float(normal.scale),
            emission_texture=self.texture(m.emissiveTexture, "srgb", f"{where}.emissiveTexture"),
        )
        strength = float(_extension(m, "KHR_materials_emissive_strength").get("emissiveStrength", 1.0))
        emission = tuple(float(c) * strength for c in (m.emissiveFactor or (0.0, 0.0, 0.0)))
        return material, emission, bool(m.doubleSided)


def _texture_info(data: dict | None) -> pygltflib.TextureInfo | None:
    if data is None:
        return None
    return pygltflib.TextureInfo(index=data["index"], texCoord=data.get("texCoord", 0))


def unique_name(name: str | None, fallback: str, taken: set[str]) -> str:
    base = (name or fallback)[:120] or fallback
    candidate, k = base, 1
    while candidate in taken:
        k += 1
        candidate = f"{base}.{k}"
    taken.add(candidate)
    return candidate


def _bounds(
    geometry: dict[tuple[int, int], MeshData], placements: dict[tuple[int, int], list[np.ndarray]], name: str
):
    """World bounds of every placed primitive; a SceneError naming the file `name` when none has a vertex."""
    points = np.concatenate(
        [
            geometry[key].vertices @ m[:3, :3].T + m[:3, 3]
            for key, matrices in placements.items()
            for m in matrices
        ]
    )
    if not len(points):
        raise SceneError(name, "no vertex to frame a camera on: the file's meshes have no vertices")
    return np.stack([points.min(0), points.max(0)])


def import_gltf(path: Path, prefix: str = "") -> spec.SceneSpec:
    """The scene of the glTF file at `path`; its paths are relative to the folder `prefix` names
    (`posixpath.join(prefix, name)`: "" when the scene file is the glTF file itself)."""
    file = read_gltf(path)
    doc = file.document
    unsupported = sorted(set(doc.extensionsRequired or []) - SUPPORTED_EXTENSIONS)
    if unsupported:
        raise SceneError("extensionsRequired", f"unsupported required extension(s): {', '.join(unsupported)}")
    importer = _Importer(file, prefix)
    for name in sorted(set(doc.extensionsUsed or []) - SUPPORTED_EXTENSIONS):
        importer.ignore(f"extension {name}")
    if doc.animations:
        importer.ignore(f"{len(doc.animations)} animation(s) (the rest pose is rendered)")
    if doc.skins:
        importer.ignore(f"{len(doc.skins)} skin(s) (the bind pose is rendered)")

    placements: dict[tuple[int, int], list[np.ndarray]] = {}
    cameras, lights = [], []
    light_defs = _extension(doc, "KHR_lights_punctual").get("lights", [])
    for index, world in _walk(doc):
        node = doc.nodes[index]
        where = f"nodes[{index}]" + (f" ({node.name})" if node.name else "")
        if node.mesh is not None:
            mesh = item(doc.meshes, node.mesh, f"{where}.mesh", "mesh")
            if abs(np.linalg.det(world[:3, :3])) < 1e-12:
                importer.ignore(f"{where}: zero scale (hidden)")
                continue
            if getattr(node, "weights", None) or getattr(mesh, "weights", None):
                importer.ignore(f"{where}: morph targets (the base mesh is rendered)")
            for j, prim in enumerate(mesh.primitives):
                mode = TRIANGLES if prim.mode is None else prim.mode
                if mode not in (TRIANGLES, TRIANGLE_STRIP, TRIANGLE_FAN):
                    problem = f"mesh {mesh.name or node.mesh!r} primitive {j} has mode {mode} "
                    raise SceneError(
                        f"{where}.mesh", problem + f"({MODE_NAMES.get(mode, '?')}), not triangles"
                    )
                placements.setdefault((node.mesh, j), []).append(world)
        if node.camera is not None:
            cameras.append((where, item(doc.cameras, node.camera, f"{where}.camera", "camera"), world))
        light = _extension(node, "KHR_lights_punctual")
        if light:
            field = f"{where}.extensions.KHR_lights_punctual.light"
            lights.append((where, item(light_defs, light.get("light"), field, "light"), world))
    if not placements:
        raise SceneError(file.path.name, "the glTF scene has no mesh to render")

    geometry = {key: primitive_mesh(file.path, *key, file.path.name) for key in placements}
    materials: dict[str, spec.Material] = {}
    material_names: dict[int | None, str] = {}
    emission: dict[int | None, tuple[tuple[float, float, float], bool]] = {None: ((0.0, 0.0, 0.0), False)}
    taken: set[str] = set()
    objects = []
    object_names: set[str] = set()
    for (mesh, j), matrices in placements.items():
        m = doc.meshes[mesh].primitives[j].material
        if m not in material_names:
            if m is not None:
                item(doc.materials, m, f"meshes[{mesh}].primitives[{j}].material", "material")
            if m is None:
                material_names[m] = unique_name("default", "default", taken)
                materials[material_names[m]] = spec.PbrMaterial()  # glTF's default material
            else:
                material, emitted, two_sided = importer.material(m)
                material_names[m] = unique_name(doc.materials[m].name, f"material_{m}", taken)
                materials[material_names[m]] = material
                emission[m] = (emitted, two_sided)
        emitted, two_sided = emission[m]
        name = unique_name(doc.meshes[mesh].name, f"mesh_{mesh}", object_names)
        if len(doc.meshes[mesh].primitives) > 1:
            object_names.discard(name)
            name = unique_name(f"{doc.meshes[mesh].name or f'mesh_{mesh}'}/{j}", "", object_names)
        degenerate = int(degenerate_triangles(geometry[mesh, j].vertices, geometry[mesh, j].faces).sum())
        if degenerate:
            importer.notes.append(
                f"geometry: {name}: dropped {degenerate} degenerate (zero-area) triangle(s)"
            )
        transforms = [spec.Transform(matrix=tuple(tuple(row) for row in w[:3].tolist())) for w in matrices]
        objects.append(
            spec.SceneObject(
                name=name,
                shape=spec.GltfShape(
                    path=posixpath.join(prefix, file.path.name), mesh=mesh, primitive=j, repair=degenerate > 0
                ),
                material=material_names[m],
                emission=emitted if max(emitted) > 0 else None,
                two_sided_emission=two_sided and max(emitted) > 0,
                transform=transforms[0] if len(transforms) == 1 else spec.Transform(),
                instances=None if len(transforms) == 1 else transforms,
            )
        )

    scene_lights = [_light(where, light, world, importer) for where, light, world in lights]
    scene_lights = [light for light in scene_lights if light is not None]
    camera = None
    perspective = [(w, c, m) for w, c, m in cameras if c.type == "perspective" and c.perspective is not None]
    for where, c, _ in cameras:
        if c.type != "perspective":
            importer.ignore(f"{where}: {c.type} camera")
    if perspective:
        where, c, world = perspective[0]
        camera = _camera(c.perspective, world)
        if len(perspective) > 1:
            importer.notes.append(f"camera: {where}'s, the first of {len(perspective)} in node order")
    else:
        camera = framing_camera(_bounds(geometry, placements, path.name))
        importer.notes.append("camera: none in the file; a default camera frames the scene's bounds")
    environment = None
    if not scene_lights and not any(o.emission for o in objects):
        environment = spec.EnvironmentMap(procedural=DEFAULT_ENVIRONMENT)
        importer.notes.append(
            f"environment: the file has no light or emission; the default {DEFAULT_ENVIRONMENT!r} environment"
        )
    notes = importer.notes + [f"ignored: {feature}" for feature in sorted(importer.ignored)]
    name = Path(file.path).stem
    return spec.SceneSpec(
        name=name,
        materials=materials,
        objects=objects,
        lights=scene_lights,
        environment=environment,
        camera=camera,
        notes=notes,
    )


def _camera(perspective, world: np.ndarray) -> spec.Camera:
    """glTF cameras look down their -Z with +Y up; `yfov` is vertical, in radians."""
    position = world[:3, 3]
    forward = world[:3, :3] @ np.array([0.0, 0.0, -1.0])
    up = world[:3, :3] @ np.array([0.0, 1.0, 0.0])
    height = 256
    width = height if not perspective.aspectRatio else max(1, round(height * perspective.aspectRatio))
    return spec.Camera(
        position=tuple(position.tolist()),
        target=tuple((position + forward / np.linalg.norm(forward)).tolist()),
        up=tuple((up / np.linalg.norm(up)).tolist()),
        fov=min(max(math.degrees(perspective.yfov), 0.2), 178.0),
        width=width,
        height=height,
    )


def _light(where: str, light: dict, world: np.ndarray, importer: _Importer) -> spec.Light | None:
    colour = np.asarray(light.get("color", (1.0, 1.0, 1.0)), float) * float(light.get("intensity", 1.0))
    rgb = tuple(float(c) for c in np.maximum(colour, 0.0))
    position = tuple(world[:3, 3].tolist())
    direction = world[:3, :3] @ np.array([0.0, 0.0, -1.0])
    direction = tuple((direction / np.linalg.norm(direction)).tolist())
    if "range" in light:
        importer.ignore(f"{where}: light range (lights fall off with the inverse square law only)")
    match light.get("type"):
        case "point":
            return spec.PointLight(position=position, intensity=rgb)
        case "directional":
            return spec.DirectionalLight(direction=direction, irradiance=rgb)
        case "spot":
            cone = light.get("spot", {})
            return spec.SpotLight(
                position=position,
                direction=direction,
                intensity=rgb,
                inner_cone=math.degrees(cone.get("innerConeAngle", 0.0)),
                outer_cone=math.degrees(cone.get("outerConeAngle", math.pi / 4)),
            )
    importer.ignore(f"{where}: light of type {light.get('type')!r}")
    return None
