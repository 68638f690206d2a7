"""The hostile uploads of issue 50's table, built procedurally: each a list of (file name, bytes) for
`POST /v1/assets`, shared by the integration tests and the hostile-input bench."""

from __future__ import annotations

import base64
import io
import json
import struct
import zipfile
import zlib

Files = list[tuple[str, bytes]]
LIGHT = "lights: [{type: point, position: [0, 5, 0], intensity: [1, 1, 1]}]\n"


# ~700 bytes whose aliases expand to 10^8 leaves under `params`
YAML_ALIAS_BOMB = """\
materials: {grey: {type: diffuse}}
objects:
  - name: bomb
    material: grey
    shape:
      type: procedural
      generator: ground_plane
      params:
        a: &a [x, x, x, x, x, x, x, x, x, x]
        b: &b [*a, *a, *a, *a, *a, *a, *a, *a, *a, *a]
        c: &c [*b, *b, *b, *b, *b, *b, *b, *b, *b, *b]
        d: &d [*c, *c, *c, *c, *c, *c, *c, *c, *c, *c]
        e: &e [*d, *d, *d, *d, *d, *d, *d, *d, *d, *d]
        f: &f [*e, *e, *e, *e, *e, *e, *e, *e, *e, *e]
        g: &g [*f, *f, *f, *f, *f, *f, *f, *f, *f, *f]
        h: &h [*g, *g, *g, *g, *g, *g, *g, *g, *g, *g]
lights: [{type: point, position: [0, 5, 0], intensity: [1, 1, 1]}]
"""


def yaml_list(ones: int = 1_500_000) -> Files:
    """A plain YAML list of `ones` ones, no aliases (1.5M: 5.7 MiB, which took 1 GB and 97 s in the API)."""
    return [("scene.yaml", b"- 1\n" * ones)]


def gltf_accessor_bomb(count: int = 20_000_000) -> Files:
    """A 400-byte glTF whose one accessor declares `count` VEC3 floats and has no bufferView."""
    document = {
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
        "accessors": [{"componentType": 5126, "count": count, "type": "VEC3"}],
    }
    return [("bomb.gltf", json.dumps(document).encode())]


def png_header(width: int, height: int) -> bytes:
    """An 8-bit RGB PNG declaring `width` x `height` with a one-row IDAT (66 bytes)."""

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    header = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    return (
        b"\x89PNG\r\n\x1a\n"
        + chunk(b"IHDR", header)
        + chunk(b"IDAT", zlib.compress(b"\0"))
        + chunk(b"IEND", b"")
    )


def textured_scene(texture: str) -> str:
    """A lit floor whose material's reflectance is the image file `texture`."""
    return (
        f"materials: {{m: {{type: diffuse, reflectance: {{type: image, path: {texture}}}}}}}\n"
        "objects: [{name: floor, shape: {type: rectangle}, material: m}]\n" + LIGHT
    )


def mesh_scene(mesh: str) -> str:
    """A lit scene of the mesh file `mesh`."""
    return (
        "materials: {m: {type: diffuse}}\n"
        f"objects: [{{name: part, shape: {{type: mesh, path: {mesh}}}, material: m}}]\n" + LIGHT
    )


def png_bomb_texture(side: int = 100_000) -> Files:
    """A scene whose material's texture is a PNG declaring `side` x `side` pixels."""
    return [("scene.yaml", textured_scene("big.png").encode()), ("big.png", png_header(side, side))]


def usd_point_instancer(instances: int = 100_000) -> Files:
    """A USD stage with one PointInstancer placing a triangle `instances` times (100k: about 1.5 MB)."""
    indices = ", ".join(["0"] * instances)
    positions = ", ".join(f"({i % 1000}, 0, {i // 1000})" for i in range(instances))
    stage = f"""#usda 1.0
(
    upAxis = "Y"
)

def Xform "World"
{{
    def PointInstancer "Scatter"
    {{
        rel prototypes = [</World/Scatter/Protos>]
        int[] protoIndices = [{indices}]
        point3f[] positions = [{positions}]

        def Xform "Protos"
        {{
            def Mesh "Tri"
            {{
                int[] faceVertexCounts = [3]
                int[] faceVertexIndices = [0, 1, 2]
                point3f[] points = [(0, 0, 0), (1, 0, 0), (0, 1, 0)]
            }}
        }}
    }}
}}
"""
    return [("scene.usda", stage.encode())]


def gltf_triangle(**changes) -> dict:
    """A valid one-triangle glTF document (its buffer a data URI); `changes` replace top-level keys."""
    positions = struct.pack("<9f", 0, 0, 0, 1, 0, 0, 0, 1, 0)
    document = {
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
        "accessors": [
            {
                "bufferView": 0,
                "componentType": 5126,
                "count": 3,
                "type": "VEC3",
                "min": [0, 0, 0],
                "max": [1, 1, 0],
            }
        ],
        "bufferViews": [{"buffer": 0, "byteLength": 36}],
        "buffers": [
            {
                "byteLength": 36,
                "uri": "data:application/octet-stream;base64," + base64.b64encode(positions).decode(),
            }
        ],
    }
    return document | changes


def gltf_variants() -> dict[str, Files]:
    """glTF files with an index out of range, a matrix of the wrong size, a negative count or a data URI that
    is not base64 (each made the server answer 500 before issue 50)."""
    good = gltf_triangle()
    accessor = good["accessors"][0]
    variants = {
        "glTF scene index": {"scene": 5},
        "glTF node.mesh": {"nodes": [{"mesh": 9}]},
        "glTF node.camera": {"nodes": [{"mesh": 0, "camera": 9}]},
        "glTF primitive.material": {
            "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "material": 9}]}]
        },
        "glTF bufferView.buffer": {"bufferViews": [{"buffer": 9, "byteLength": 36}]},
        "glTF light": {
            "nodes": [{"mesh": 0}, {"extensions": {"KHR_lights_punctual": {"light": 9}}}],
            "scenes": [{"nodes": [0, 1]}],
            "extensionsUsed": ["KHR_lights_punctual"],
            "extensions": {"KHR_lights_punctual": {"lights": [{"type": "point"}]}},
        },
        "glTF 3-number matrix": {"nodes": [{"mesh": 0, "matrix": [1, 0, 0]}]},
        "glTF count -5": {"accessors": [accessor | {"count": -5}]},
        "glTF non-base64 data URI": {
            "buffers": [{"byteLength": 36, "uri": "data:application/octet-stream;base64,@@@"}]
        },
    }
    return {
        name: [("scene.gltf", json.dumps(gltf_triangle(**change)).encode())]
        for name, change in variants.items()
    }


def glb(document: dict) -> bytes:
    """`document` as a binary glTF: the 12-byte header and one JSON chunk (its buffers are data URIs)."""
    text = json.dumps(document).encode()
    text += b" " * (-len(text) % 4)  # chunks are 4-byte aligned, JSON padded with spaces
    chunk = struct.pack("<I4s", len(text), b"JSON") + text
    return struct.pack("<4sII", b"glTF", 2, 12 + len(chunk)) + chunk


def zip_with_bad_utf8_name() -> Files:
    """A zip whose entry is flagged UTF-8 (general purpose bit 11) and whose name bytes are not UTF-8."""
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w") as archive:
        archive.writestr("scene.yaml", "objects: []\n")
        archive.writestr("mX.obj", "v 0 0 0\n")
    data = bytearray(buffer.getvalue().replace(b"mX.obj", b"m\xff.obj"))
    for signature, flags_at in ((b"PK\x03\x04", 7), (b"PK\x01\x02", 9)):  # the high byte of the flags
        start = data.find(signature)
        while start >= 0:
            data[start + flags_at] |= 0x08  # bit 11: the name is UTF-8
            start = data.find(signature, start + 4)
    return [("scene.zip", bytes(data))]


def usd_mesh_without_faces() -> Files:
    """A USD stage whose one mesh has points but no faces."""
    stage = """#usda 1.0
def Xform "World"
{
    def Mesh "Empty"
    {
        int[] faceVertexCounts = []
        int[] faceVertexIndices = []
        point3f[] points = [(0, 0, 0), (1, 0, 0), (0, 1, 0)]
    }
}
"""
    return [("scene.usda", stage.encode())]


# Inputs the fuzz targets (tests/fuzz) found crashing the server's parsers, reduced by hand.


def usd_not_utf8() -> Files:
    """A USD text layer with a byte that is not UTF-8 where usd-core's parser quotes it in its error."""
    return [("scene.usda", b'#usda 1.0\ndef Mesh "M"\n{\n    int[] f\xbe = []\n}\n')]


def obj_vertex_with_two_coordinates() -> Files:
    """An OBJ whose third vertex has two coordinates (trimesh then returns [n, 1] vertices)."""
    return [("mesh.obj", b"v 0 0 0\nv 1 0 0\nv 0 1\nf 1 2 3\n")]


def _zip(**members: bytes) -> bytearray:
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w") as archive:
        for name, data in members.items():
            archive.writestr(zipfile.ZipInfo(name), data)
    return bytearray(buffer.getvalue())


def zip_with_unknown_compression() -> Files:
    """A zip whose member declares compression method 99, which zipfile cannot decompress."""
    data = _zip(**{"scene.yaml": b"objects: []\n"})
    for signature, method_at in ((b"PK\x03\x04", 8), (b"PK\x01\x02", 10)):
        struct.pack_into("<H", data, data.find(signature) + method_at, 99)
    return [("scene.zip", bytes(data))]


def zip_with_corrupt_bzip2() -> Files:
    """A zip whose member declares bzip2 compression (method 12) over bytes that are not bzip2."""
    data = _zip(**{"scene.yaml": b"objects: []\n"})
    for signature, method_at in ((b"PK\x03\x04", 8), (b"PK\x01\x02", 10)):
        struct.pack_into("<H", data, data.find(signature) + method_at, 12)
    return [("scene.zip", bytes(data))]


def zip_member_without_name() -> Files:
    """A zip with a member whose name is empty."""
    return [("scene.zip", bytes(_zip(**{"": b"x", "scene.yaml": b"objects: []\n"})))]


def zip_central_directory_past_its_place() -> Files:
    """A zip whose end record puts the central directory 100 bytes after where it is: zipfile then places
    the first member's header before the start of the file."""
    data = _zip(**{"scene.yaml": b"objects: []\n"})
    end = data.rfind(b"PK\x05\x06")
    struct.pack_into("<I", data, end + 16, struct.unpack_from("<I", data, end + 16)[0] + 100)
    return [("scene.zip", bytes(data))]


def gltf_view_without_length() -> Files:
    """A glTF whose buffer view lacks its (required) byteLength."""
    return [("scene.gltf", json.dumps(gltf_triangle(bufferViews=[{"buffer": 0}])).encode())]


def usd_instancer_with_fewer_positions() -> Files:
    """A PointInstancer with three protoIndices and two positions."""
    name, stage = usd_point_instancer(3)[0]
    return [(name, stage.replace(b"(0, 0, 0), (1, 0, 0), (2, 0, 0)", b"(0, 0, 0), (1, 0, 0)"))]


def gltf_data_uri_not_ascii() -> Files:
    """A glTF whose buffer's data URI holds a character that is not ASCII."""
    buffer = {"byteLength": 36, "uri": "data:application/octet-stream;base64,AAAA\u00e9AAA"}
    return [("scene.gltf", json.dumps(gltf_triangle(buffers=[buffer])).encode())]


def gltf_positions_of_two_numbers() -> Files:
    """A glTF whose POSITION accessor is a VEC2."""
    document = gltf_triangle()
    document["accessors"][0] |= {"type": "VEC2", "count": 4}
    return [("scene.gltf", json.dumps(document).encode())]


def gltf_without_vertices() -> Files:
    """A glTF (no camera) whose one primitive's POSITION accessor has count 0."""
    document = gltf_triangle()
    document["accessors"][0] |= {"count": 0}
    return [("scene.gltf", json.dumps(document).encode())]


def tar_gz_header_cut_short() -> Files:
    """The first four bytes of a gzip header (magic, method, no flags byte)."""
    return [("scene.tar.gz", b"\x1f\x8b\x08")]


def usd_instancer_of_no_prototype() -> Files:
    """A PointInstancer whose instances all name prototype 5 of its one."""
    name, stage = usd_point_instancer(3)[0]
    return [(name, stage.replace(b"protoIndices = [0, 0, 0]", b"protoIndices = [5, 5, 5]"))]


def usd_instancer_without_instances() -> Files:
    """A PointInstancer with no instances: its prototype's mesh is placed nowhere, and nothing else is."""
    name, stage = usd_point_instancer(3)[0]
    stage = stage.replace(b"protoIndices = [0, 0, 0]", b"protoIndices = []")
    return [(name, stage.replace(b"positions = [(0, 0, 0), (1, 0, 0), (2, 0, 0)]", b"positions = []"))]


def usd_instancer_indices_of_unknown_type() -> Files:
    """A PointInstancer whose protoIndices are declared `int6[]`, a type usd-core does not know."""
    name, stage = usd_point_instancer(3)[0]
    return [(name, stage.replace(b"int[] protoIndices", b"int6[] protoIndices"))]


def usd_points_of_unknown_type() -> Files:
    """A USD mesh whose points are declared `point6f[]`, a type usd-core does not know."""
    name, stage = usd_mesh_without_faces()[0]
    stage = stage.replace(b"int[] faceVertexCounts = []", b"int[] faceVertexCounts = [3]")
    stage = stage.replace(b"int[] faceVertexIndices = []", b"int[] faceVertexIndices = [0, 1, 2]")
    return [(name, stage.replace(b"point3f[] points", b"point6f[] points"))]
