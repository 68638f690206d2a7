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


def png_bomb_texture(side: int = 100_000) -> Files:
    """A scene whose material's texture is a PNG declaring `side` x `side` pixels."""
    scene = (
        "materials: {m: {type: diffuse, reflectance: {type: image, path: big.png}}}\n"
        "objects: [{name: floor, shape: {type: rectangle}, material: m}]\n" + LIGHT
    )
    return [("scene.yaml", scene.encode()), ("big.png", png_header(side, side))]


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
