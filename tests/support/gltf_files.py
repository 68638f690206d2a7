"""Writing glTF 2.0 files for tests, with pygltflib: meshes, node hierarchies, materials, textures, lights
and cameras, saved as `.gltf` (with a `.bin` and, optionally, PNG files beside it) or `.glb`."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import pygltflib as g
from PIL import Image

FLOAT, UINT32 = 5126, 5125
TYPES = {1: "SCALAR", 2: "VEC2", 3: "VEC3", 4: "VEC4"}


class GltfBuilder:
    def __init__(self) -> None:
        self.doc = g.GLTF2(asset=g.Asset(version="2.0"), scenes=[g.Scene(nodes=[])], scene=0)
        self.blob = bytearray()
        self.files: dict[str, bytes] = {}  # external images, written beside the file

    def _view(self, data: bytes) -> int:
        while len(self.blob) % 4:
            self.blob.append(0)
        self.doc.bufferViews.append(g.BufferView(buffer=0, byteOffset=len(self.blob), byteLength=len(data)))
        self.blob += data
        return len(self.doc.bufferViews) - 1

    def accessor(self, array: np.ndarray, component: int = FLOAT, bounds: bool = False) -> int:
        array = np.asarray(array, np.float32 if component == FLOAT else np.uint32)
        width = 1 if array.ndim == 1 else array.shape[1]
        acc = g.Accessor(
            bufferView=self._view(array.tobytes()),
            componentType=component,
            count=len(array),
            type=TYPES[width],
        )
        if bounds:
            acc.min, acc.max = array.min(0).tolist(), array.max(0).tolist()
        self.doc.accessors.append(acc)
        return len(self.doc.accessors) - 1

    def mesh(
        self,
        positions,
        indices=None,
        *,
        normals=None,
        uvs=None,
        tangents=None,
        colors=None,
        material=None,
        mode=None,
        name=None,
    ) -> int:
        attributes = g.Attributes(POSITION=self.accessor(positions, bounds=True))
        if normals is not None:
            attributes.NORMAL = self.accessor(normals)
        if uvs is not None:
            attributes.TEXCOORD_0 = self.accessor(uvs)
        if tangents is not None:
            attributes.TANGENT = self.accessor(tangents)
        if colors is not None:
            attributes.COLOR_0 = self.accessor(colors)
        primitive = g.Primitive(attributes=attributes, material=material, mode=mode)
        if indices is not None:
            primitive.indices = self.accessor(np.asarray(indices).ravel(), UINT32)
        self.doc.meshes.append(g.Mesh(name=name, primitives=[primitive]))
        return len(self.doc.meshes) - 1

    def image(self, pixels: np.ndarray, uri: str | None = None) -> int:
        """An 8-bit RGB(A) PNG image: embedded in the buffer, or a file `uri` beside the glTF file."""
        encoded = io.BytesIO()
        Image.fromarray(np.asarray(pixels, np.uint8)).save(encoded, format="PNG")
        if uri is None:
            self.doc.images.append(g.Image(bufferView=self._view(encoded.getvalue()), mimeType="image/png"))
        else:
            self.files[uri] = encoded.getvalue()
            self.doc.images.append(g.Image(uri=uri))
        return len(self.doc.images) - 1

    def texture(self, image: int, wrap_s: int = 10497, wrap_t: int = 10497) -> int:
        self.doc.samplers.append(g.Sampler(wrapS=wrap_s, wrapT=wrap_t))
        self.doc.textures.append(g.Texture(source=image, sampler=len(self.doc.samplers) - 1))
        return len(self.doc.textures) - 1

    def material(self, **fields) -> int:
        self.doc.materials.append(g.Material(**fields))
        return len(self.doc.materials) - 1

    def node(self, *, root: bool = True, **fields) -> int:
        self.doc.nodes.append(g.Node(**fields))
        index = len(self.doc.nodes) - 1
        if root:
            self.doc.scenes[0].nodes.append(index)
        return index

    def camera(self, yfov: float, aspect: float | None = None) -> int:
        perspective = g.Perspective(yfov=yfov, aspectRatio=aspect, znear=0.01)
        self.doc.cameras.append(g.Camera(type="perspective", perspective=perspective))
        return len(self.doc.cameras) - 1

    def light(self, **light) -> int:
        ext = self.doc.extensions.setdefault("KHR_lights_punctual", {"lights": []})
        ext["lights"].append(light)
        self.use("KHR_lights_punctual")
        return len(ext["lights"]) - 1

    def use(self, extension: str, required: bool = False) -> None:
        if extension not in self.doc.extensionsUsed:
            self.doc.extensionsUsed.append(extension)
        if required and extension not in self.doc.extensionsRequired:
            self.doc.extensionsRequired.append(extension)

    def save(self, path: Path) -> Path:
        """`.glb` (one binary chunk) or `.gltf` with `<stem>.bin` and the external images beside it."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        for uri, data in self.files.items():
            (path.parent / uri).parent.mkdir(parents=True, exist_ok=True)
            (path.parent / uri).write_bytes(data)
        if path.suffix == ".glb":
            self.doc.buffers = [g.Buffer(byteLength=len(self.blob))]
            self.doc.set_binary_blob(bytes(self.blob))
            self.doc.save_binary(str(path))
        else:
            (path.parent / f"{path.stem}.bin").write_bytes(bytes(self.blob))
            self.doc.buffers = [g.Buffer(uri=f"{path.stem}.bin", byteLength=len(self.blob))]
            self.doc.save_json(str(path))
        return path


QUAD_POSITIONS = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], np.float32)
QUAD_UVS = np.array([[0, 1], [1, 1], [1, 0], [0, 0]], np.float32)  # glTF: v grows down the image
QUAD_INDICES = np.array([[0, 1, 2], [0, 2, 3]])
QUAD_NORMALS = np.tile([0.0, 0.0, 1.0], (4, 1))


def quad(builder: GltfBuilder, material: int | None = None, name: str | None = None, **fields) -> int:
    """The square [-1, 1]^2 at z = 0 facing +z, u along +x and v down the image (along -y)."""
    return builder.mesh(
        QUAD_POSITIONS,
        QUAD_INDICES,
        normals=QUAD_NORMALS,
        uvs=QUAD_UVS,
        material=material,
        name=name,
        **fields,
    )
