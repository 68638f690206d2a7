"""The hostile uploads of issue 50's table, built procedurally: each a list of (file name, bytes) for
`POST /v1/assets`, shared by the integration tests and the hostile-input bench."""

from __future__ import annotations

import json
import struct
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
