"""Closest-hit and occlusion queries through Embree, as `Intersector`s; each releases the GIL.

Embree's C API is called from compiled kernels (`_intersect16`, `_occluded16`), 16 rays at a time
(`rtcIntersect16` / `rtcOccluded16`, Embree's packet queries). The library is the one embreex's wheel
ships; embreex's own `run` asks one ray at a time (`rtcIntersect1`) and returns a dict of fresh arrays.
Same hits bit for bit. Measured on cornell_box's render queries (128x128, 16 spp, replayed, one thread,
thread CPU): one ray at a time from a kernel 102 ms closest hit + 43 ms shadow rays, 16 at a time
91 + 28 ms; through embreex the render spent 112 + 46 ms in these queries.

Embree takes float32 rays: origins and directions are rounded to float32 here, as before.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools
import glob
import os

import embreex
import numpy as np
from llvmlite import binding as llvm
from numba import types

from workers.render import heap
from workers.render.intersector import Hits
from workers.render.jit import njit

# Embree 4's enums (rtcore_common.h, rtcore_buffer.h, rtcore_geometry.h, rtcore_scene.h).
_SCENE_FLAG_ROBUST = 1 << 2
_GEOMETRY_TYPE_TRIANGLE = 0
_BUFFER_TYPE_INDEX, _BUFFER_TYPE_VERTEX = 0, 1
_FORMAT_UINT3, _FORMAT_FLOAT3 = 0x5003, 0x9003
_INVALID_ID = -1  # RTC_INVALID_GEOMETRY_ID as int32
# RTCRayHit16's layout, in 32-bit words: 12 ray fields of 16 lanes (org xyz, tnear, dir xyz, time, tfar,
# mask, id, flags), then the hit's (Ng xyz, u, v, primID, geomID, instID, instPrimID).
_TFAR, _MASK, _U, _V, _PRIM, _GEOM, _INST = 8, 9, 15, 16, 17, 18, 19
# Room for the fields above and more, 64-byte aligned, for both queries: Embree 4.4's rtcOccluded16 reads
# past RTCRay16's 12 fields (bytes 0x4c0-0x540 of the packet, where RTCRayHit16 keeps its instance
# fields, whose count is a build option), which segfaulted where a 12-field packet ended at a page's end
# (about every other run of tests/unit/test_explore_model.py on one machine; test_render_embree.py puts a
# packet before an unreadable page); 64 fields, 4 KB
_PACKET_WORDS = 64 * 16
_PACKET = 16


def _library_path() -> str:
    """libembree4 as embreex's wheel ships it (manylinux: embreex.libs, macOS: embreex/.dylibs), else the
    system's."""
    root = os.path.dirname(embreex.__file__)
    for pattern in ("../embreex.libs/libembree4*", ".dylibs/libembree4*"):
        found = sorted(glob.glob(os.path.join(root, pattern)))
        if found:
            return found[0]
    path = ctypes.util.find_library("embree4")
    if path is None:
        raise ImportError("libembree4 not found beside embreex nor on the system")
    return path


@functools.cache
def _embree() -> ctypes.CDLL:
    """The library, with the signatures of the calls made from Python; its symbols are also made visible
    to the compiled kernels (resolved by name, so their cached machine code stays valid)."""
    path = _library_path()
    llvm.load_library_permanently(path)
    lib = ctypes.CDLL(path)
    handle, size, uint, enum = ctypes.c_void_p, ctypes.c_size_t, ctypes.c_uint, ctypes.c_int
    signatures = {
        "rtcNewDevice": (handle, [ctypes.c_char_p]),
        "rtcNewScene": (handle, [handle]),
        "rtcSetSceneFlags": (None, [handle, enum]),
        "rtcNewGeometry": (handle, [handle, enum]),
        "rtcSetNewGeometryBuffer": (ctypes.c_void_p, [handle, enum, uint, enum, size, size]),
        "rtcCommitGeometry": (None, [handle]),
        "rtcAttachGeometry": (uint, [handle, handle]),
        "rtcReleaseGeometry": (None, [handle]),
        "rtcCommitScene": (None, [handle]),
        "rtcReleaseScene": (None, [handle]),
    }
    for name, (restype, argtypes) in signatures.items():
        function = getattr(lib, name)
        function.restype, function.argtypes = restype, argtypes
    return lib


@functools.cache
def _device() -> int:
    """One Embree device for the process (as embreex, which made one per scene)."""
    return _embree().rtcNewDevice(None)


# Pointers are passed as 64-bit integers (the same registers on the platforms Embree supports).
_query16 = types.void(types.uintp, types.uintp, types.uintp, types.uintp)
_rtc_intersect16 = types.ExternalFunction("rtcIntersect16", _query16)
_rtc_occluded16 = types.ExternalFunction("rtcOccluded16", _query16)


@njit(cache=True, nogil=True)
def _aligned(words, dtype, alignment):
    """A zeroed array of `words` 32-bit words starting at a multiple of `alignment` bytes."""
    buffer = np.zeros(words + alignment // 4, dtype)
    start = (alignment - buffer.ctypes.data % alignment) % alignment // 4
    return buffer[start : start + words]


@njit(cache=True, nogil=True)
def _load_packet(o, d, t_far, start, count, packet, valid):
    """Rays start .. start + count (float64, rounded to float32) into an RTCRay16 or RTCRayHit16."""
    words = packet.view(np.int32)
    for k in range(_PACKET):
        if k >= count:
            valid[k] = 0
            continue
        i = start + k
        valid[k] = -1
        for c in range(3):
            packet[c * _PACKET + k] = np.float32(o[i, c])
            packet[(4 + c) * _PACKET + k] = np.float32(d[i, c])
        packet[3 * _PACKET + k] = 0.0  # tnear
        packet[7 * _PACKET + k] = 0.0  # time
        packet[_TFAR * _PACKET + k] = t_far[i]
        words[_MASK * _PACKET + k] = -1
        words[(_MASK + 1) * _PACKET + k] = 0  # id
        words[(_MASK + 2) * _PACKET + k] = 0  # flags


@njit(cache=True, nogil=True)
def _clear_hits(words):
    """No hit and no instance in every lane of a packet's hit fields (Embree reads them on both queries)."""
    for k in range(_PACKET):
        words[_GEOM * _PACKET + k] = _INVALID_ID
        words[_INST * _PACKET + k] = _INVALID_ID


@njit(cache=True, nogil=True)
def _intersect16(scene, o, d, t_far, prim, t, u, v):
    """Closest hits of rays (o, d) up to `t_far` (float32): prim (-1 on a miss), t, u, v per ray."""
    _intersect16_through(scene, o, d, t_far, prim, t, u, v, _aligned(_PACKET_WORDS, np.float32, 64))


@njit(cache=True, nogil=True)
def _intersect16_through(scene, o, d, t_far, prim, t, u, v, packet):
    """`_intersect16` asked through a given packet of `_PACKET_WORDS` (a test places one)."""
    words = packet.view(np.int32)
    valid = _aligned(_PACKET, np.int32, 64)
    n = len(o)
    for start in range(0, n, _PACKET):
        count = min(_PACKET, n - start)
        _load_packet(o, d, t_far, start, count, packet, valid)
        _clear_hits(words)
        _rtc_intersect16(valid.ctypes.data, scene, packet.ctypes.data, 0)
        for k in range(count):
            i = start + k
            hit = words[_GEOM * _PACKET + k] != _INVALID_ID
            prim[i] = words[_PRIM * _PACKET + k] if hit else -1
            t[i] = packet[_TFAR * _PACKET + k]
            u[i], v[i] = packet[_U * _PACKET + k], packet[_V * _PACKET + k]


@njit(cache=True, nogil=True)
def _occluded16(scene, o, d, t_far, blocked):
    """Whether something lies on each ray (o, d) up to `t_far` (float32); Embree sets tfar to -inf then."""
    _occluded16_through(scene, o, d, t_far, blocked, _aligned(_PACKET_WORDS, np.float32, 64))


@njit(cache=True, nogil=True)
def _occluded16_through(scene, o, d, t_far, blocked, packet):
    """`_occluded16` asked through a given packet of `_PACKET_WORDS` (a test places one)."""
    words = packet.view(np.int32)
    valid = _aligned(_PACKET, np.int32, 64)
    n = len(o)
    for start in range(0, n, _PACKET):
        count = min(_PACKET, n - start)
        _load_packet(o, d, t_far, start, count, packet, valid)
        _clear_hits(words)
        _rtc_occluded16(valid.ctypes.data, scene, packet.ctypes.data, 0)
        for k in range(count):
            blocked[start + k] = packet[_TFAR * _PACKET + k] == -np.inf


@njit(cache=True, nogil=True)
def _scene_prims(prim, triangle_ids):
    """The scene's triangle index of each subset hit `prim` (int64, -1 on a miss): one pass, where four
    NumPy operations cost a voxel bounce of a few paths about 4 us (of its about 10 us closest-hit query)."""
    out = np.empty(len(prim), np.int64)
    for i in range(len(prim)):
        out[i] = triangle_ids[prim[i]] if prim[i] >= 0 else -1
    return out


class RayScene:
    """One Embree scene over world-space triangles (T, 3, 3)."""

    def __init__(self, positions: np.ndarray, robust: bool = True):
        heap.keep_freed_arrays()  # each query allocates arrays of about 1 MB, as the tracer's bounces do
        lib = _embree()
        self._lib = lib  # released with the scene, after it
        triangles = np.ascontiguousarray(positions, dtype=np.float32).reshape(-1, 9)
        n = len(triangles)
        self._scene = lib.rtcNewScene(_device())
        if robust:
            lib.rtcSetSceneFlags(self._scene, _SCENE_FLAG_ROBUST)
        geometry = lib.rtcNewGeometry(_device(), _GEOMETRY_TYPE_TRIANGLE)
        vertices = lib.rtcSetNewGeometryBuffer(geometry, _BUFFER_TYPE_VERTEX, 0, _FORMAT_FLOAT3, 12, 3 * n)
        indices = lib.rtcSetNewGeometryBuffer(geometry, _BUFFER_TYPE_INDEX, 0, _FORMAT_UINT3, 12, n)
        if n:
            np.ctypeslib.as_array((ctypes.c_float * (9 * n)).from_address(vertices))[:] = triangles.ravel()
            np.ctypeslib.as_array((ctypes.c_uint32 * (3 * n)).from_address(indices))[:] = np.arange(
                3 * n, dtype=np.uint32
            )
        lib.rtcCommitGeometry(geometry)
        lib.rtcAttachGeometry(self._scene, geometry)
        lib.rtcReleaseGeometry(geometry)
        lib.rtcCommitScene(self._scene)  # builds the BVH now, once, not inside a worker thread

    def __del__(self):
        scene = getattr(self, "_scene", None)
        if scene:
            self._lib.rtcReleaseScene(scene)

    def intersect(self, origins: np.ndarray, directions: np.ndarray, t_max: np.ndarray | None = None) -> Hits:
        """Closest hits; with `t_max` (N,), only those up to it (float32 rounded up: a farther hit may
        still be reported), which lets Embree skip what lies beyond: callers that only keep hits
        closer than a bound pass it."""
        n = len(origins)
        if t_max is None:
            t_far = np.full(n, 1e37, np.float32)
        else:
            bound = np.minimum(t_max, 3.0e38).astype(np.float32)
            t_far = np.nextafter(bound, np.float32(np.inf))
        prim, t = np.empty(n, np.int32), np.empty(n)
        u, v = np.empty(n, np.float32), np.empty(n, np.float32)
        if n:
            _intersect16(self._scene, _f64(origins), _f64(directions), t_far, prim, t, u, v)
        return Hits(prim, t, u, v)

    def occluded(self, origins: np.ndarray, directions: np.ndarray, t_max: np.ndarray) -> np.ndarray:
        """True where something lies on the segment [0, t_max) of each ray."""
        n = len(origins)
        blocked = np.empty(n, np.bool_)
        if n:
            t_far = np.ascontiguousarray(np.minimum(t_max, 3.0e38), dtype=np.float32)
            _occluded16(self._scene, _f64(origins), _f64(directions), t_far, blocked)
        return blocked


def _f64(a: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=np.float64)


class SubsetRayScene:
    """Embree over some of a scene's triangles (`triangle_ids` into its positions), answering with the
    scene's own triangle indices, so a `PathTracer` over the whole scene can trace just these. An empty
    subset is answered without Embree: every ray escapes."""

    def __init__(self, positions: np.ndarray, triangle_ids: np.ndarray, robust: bool = True):
        self.triangle_ids = np.asarray(triangle_ids, np.int64)
        self._scene = RayScene(positions[self.triangle_ids], robust) if len(self.triangle_ids) else None

    def intersect(self, origins: np.ndarray, directions: np.ndarray, t_max: np.ndarray | None = None) -> Hits:
        """As `RayScene.intersect`."""
        if self._scene is None:
            return Hits.misses(len(origins))
        hits = self._scene.intersect(origins, directions, t_max)
        hits.prim = _scene_prims(hits.prim, self.triangle_ids)
        return hits

    def occluded(self, origins: np.ndarray, directions: np.ndarray, t_max: np.ndarray) -> np.ndarray:
        if self._scene is None:
            return np.zeros(len(origins), bool)
        return self._scene.occluded(origins, directions, t_max)
