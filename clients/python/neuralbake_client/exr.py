"""Reading the OpenEXR images the inference service renders, with NumPy and zlib only (the client depends on
no OpenEXR library): single-part scanline files, uncompressed, ZIPS or ZIP, with HALF, FLOAT or UINT
channels, which is what the service writes. Layout from "OpenEXR File Layout" (openexr.com).
"""

from __future__ import annotations

import struct
import zlib

import numpy as np

from neuralbake_client.errors import NeuralbakeError

MAGIC = 20000630
TILED, MULTIPART = 0x200, 0x1000  # version flags this reader refuses
LINES_PER_CHUNK = {0: 1, 2: 1, 3: 16}  # compression: NO, ZIPS, ZIP
PIXEL_TYPES = {0: np.dtype("<u4"), 1: np.dtype("<f2"), 2: np.dtype("<f4")}  # UINT, HALF, FLOAT


class _Reader:
    def __init__(self, data: bytes):
        self.data, self.pos = data, 0

    def take(self, size: int) -> bytes:
        if self.pos + size > len(self.data):
            raise NeuralbakeError("the EXR image ends early")
        chunk = self.data[self.pos : self.pos + size]
        self.pos += size
        return chunk

    def cstring(self) -> str:
        end = self.data.index(b"\0", self.pos)
        text = self.data[self.pos : end].decode()
        self.pos = end + 1
        return text


def _channels(value: bytes) -> list[tuple[str, np.dtype]]:
    """The `chlist` attribute: (name, pixel type) in the file's (alphabetical) order."""
    reader, channels = _Reader(value), []
    while (name := reader.cstring()) != "":
        pixel_type, _, _, x_sampling, y_sampling = struct.unpack("<iB3sii", reader.take(16))
        if (x_sampling, y_sampling) != (1, 1):
            raise NeuralbakeError(f"EXR channel {name} is subsampled, which this reader does not support")
        channels.append((name, PIXEL_TYPES[pixel_type]))
    return channels


def _unzip(block: bytes) -> bytes:
    """OpenEXR's ZIP: zlib, then undo the byte predictor (t[i] = t[i-1] + d[i] - 128) and the split of
    even and odd bytes into two halves."""
    t = np.frombuffer(zlib.decompress(block), np.uint8).astype(np.int64)
    t[1:] -= 128
    t = (np.cumsum(t) & 0xFF).astype(np.uint8)
    half = (len(t) + 1) // 2
    out = np.empty_like(t)
    out[0::2], out[1::2] = t[:half], t[half:]
    return out.tobytes()


def read_exr(data: bytes) -> dict[str, np.ndarray]:
    """Every channel of an EXR image as an (H, W) array, by name (`R`, `G`, `B`, or `Y`)."""
    reader = _Reader(data)
    magic, version = struct.unpack("<ii", reader.take(8))
    if magic != MAGIC:
        raise NeuralbakeError("not an OpenEXR image")
    if version & (TILED | MULTIPART):
        raise NeuralbakeError("tiled and multi-part EXR images are not supported")
    attributes = {}
    while (name := reader.cstring()) != "":
        reader.cstring()  # the attribute's type name; the names below fix their types
        (size,) = struct.unpack("<i", reader.take(4))
        attributes[name] = reader.take(size)
    channels = _channels(attributes["channels"])
    compression = attributes["compression"][0]
    if compression not in LINES_PER_CHUNK:
        raise NeuralbakeError(f"EXR compression {compression} is not supported (only none, ZIPS and ZIP)")
    x_min, y_min, x_max, y_max = struct.unpack("<iiii", attributes["dataWindow"])
    width, height = x_max - x_min + 1, y_max - y_min + 1
    lines = LINES_PER_CHUNK[compression]
    chunks = -(-height // lines)
    offsets = struct.unpack(f"<{chunks}Q", reader.take(8 * chunks))
    row_bytes = sum(width * dtype.itemsize for _, dtype in channels)
    images = {name: np.empty((height, width), dtype.newbyteorder("=")) for name, dtype in channels}
    for offset in offsets:
        y, size = struct.unpack_from("<ii", data, offset)
        rows = min(lines, y_max + 1 - y)
        block = data[offset + 8 : offset + 8 + size]
        raw = block if size == rows * row_bytes else _unzip(block)  # incompressible chunks are stored raw
        table = np.frombuffer(raw, np.uint8).reshape(rows, row_bytes)
        start = 0
        for name, dtype in channels:
            end = start + width * dtype.itemsize
            images[name][y - y_min : y - y_min + rows] = table[:, start:end].copy().view(dtype)
            start = end
    return images
