"""Embree queries: bounded by a distance, what a caller keeps is what an unbounded query finds; 16 rays at
a time, what embreex's one-ray queries find; and no query reads past its ray packet."""

from __future__ import annotations

import contextlib
import ctypes
import mmap

import numpy as np

from workers.render.embree import _PACKET_WORDS, RayScene, _intersect16_through, _occluded16_through
from workers.scene.generators.builtin import cornell_box
from workers.scene.geometry.compile import compile_scene


def test_a_bounded_query_finds_the_hits_up_to_its_bound_and_skips_farther_ones():
    scene = compile_scene(cornell_box())
    rays = RayScene(scene.positions)
    rng = np.random.default_rng(0)
    lo, hi = scene.bounds
    n = 20_000
    origins = rng.uniform(lo + 0.05 * (hi - lo), hi - 0.05 * (hi - lo), (n, 3))
    directions = rng.normal(size=(n, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    free = rays.intersect(origins, directions)
    hit = np.flatnonzero(free.found)  # the box is open at the front
    origins, directions, free, n = origins[hit], directions[hit], free.take(hit), len(hit)
    # a third of the bounds fall short of the hit, a third are exactly at it, a third beyond
    t_max = free.t * rng.choice([0.5, 1.0, 2.0], n)
    bounded = rays.intersect(origins, directions, t_max)
    within = free.t <= t_max
    np.testing.assert_array_equal(bounded.prim[within], free.prim[within])
    np.testing.assert_array_equal(bounded.t[within], free.t[within])
    assert not bounded.found[~within].any()
    assert 0.25 < within.mean() < 0.75 and (t_max == free.t).sum() > n // 4


def test_packet_queries_answer_as_embreex_one_ray_at_a_time():
    """`RayScene` asks Embree 16 rays at a time; embreex's `run` (one ray at a time, the same library)
    must give the same hits, distances, barycentrics and occlusion, including a last partial packet."""
    from embreex import rtcore_scene
    from embreex.mesh_construction import TriangleMesh

    scene = compile_scene(cornell_box())
    reference = rtcore_scene.EmbreeScene(robust=True)
    TriangleMesh(reference, np.ascontiguousarray(scene.positions, dtype=np.float32))
    rays = RayScene(scene.positions)
    rng = np.random.default_rng(1)
    lo, hi = scene.bounds
    n = 16 * 300 + 7
    origins = rng.uniform(lo + 0.05 * (hi - lo), hi - 0.05 * (hi - lo), (n, 3))
    directions = rng.normal(size=(n, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    o32, d32 = origins.astype(np.float32), directions.astype(np.float32)
    hits = rays.intersect(origins, directions)
    expected = reference.run(o32, d32, output=1)
    np.testing.assert_array_equal(hits.prim, expected["primID"])
    found = hits.found
    assert 0.5 < found.mean() < 1.0
    np.testing.assert_array_equal(hits.t[found], expected["tfar"][found])
    np.testing.assert_array_equal(hits.u[found], expected["u"][found])
    np.testing.assert_array_equal(hits.v[found], expected["v"][found])
    t_max = np.where(found, hits.t, 1.0) * rng.uniform(0.5, 1.5, n)
    blocked = rays.occluded(origins, directions, t_max)
    expected_blocked = reference.run(o32, d32, dists=t_max.astype(np.float32), query="OCCLUDED") != -1
    np.testing.assert_array_equal(blocked, expected_blocked)
    assert 0.2 < blocked.mean() < 0.8


@contextlib.contextmanager
def packet_before_a_guard_page():
    """A `_PACKET_WORDS` float32 ray packet whose last byte ends a page that an unreadable page follows:
    a query that reads past its packet faults instead of reading whatever the heap holds there."""
    page, size = mmap.PAGESIZE, _PACKET_WORDS * 4
    region = mmap.mmap(-1, 2 * page)
    address = ctypes.addressof(ctypes.c_char.from_buffer(region))
    libc = ctypes.CDLL(None, use_errno=True)
    libc.mprotect.argtypes = [ctypes.c_void_p, ctypes.c_size_t, ctypes.c_int]
    assert libc.mprotect(address + page, page, 0) == 0, ctypes.get_errno()  # PROT_NONE
    packet = np.frombuffer(region, np.float32, _PACKET_WORDS, offset=page - size)
    try:
        yield packet
    finally:
        libc.mprotect(address + page, page, mmap.PROT_READ | mmap.PROT_WRITE)


def test_queries_read_nothing_past_their_packet():
    """Embree 4.4's rtcOccluded16 reads the packet past RTCRay16's 12 fields: with a 12-field packet that
    ended a page, the query segfaulted (about every other run of the explore unit tests); a packet of the
    size the kernels are given answers as `RayScene`'s own queries."""
    scene = compile_scene(cornell_box())
    rays = RayScene(scene.positions)
    rng = np.random.default_rng(1)
    n = 37  # two full packets and a partial one
    origins = np.tile([0.0, 0.0, 3.0], (n, 1))
    directions = rng.normal(size=(n, 3)) * [0.3, 0.3, 1.0] - [0.0, 0.0, 1.0]
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    t_far = np.full(n, 4.0, np.float32)
    expected_hits, expected_blocked = (
        rays.intersect(origins, directions),
        rays.occluded(origins, directions, t_far),
    )
    with packet_before_a_guard_page() as packet:
        assert packet.flags.writeable and packet.ctypes.data % 64 == 0
        blocked = np.empty(n, np.bool_)
        _occluded16_through(rays._scene, origins, directions, t_far, blocked, packet)
        prim, t = np.empty(n, np.int32), np.empty(n)
        u, v = np.empty(n, np.float32), np.empty(n, np.float32)
        _intersect16_through(
            rays._scene, origins, directions, np.full(n, 1e37, np.float32), prim, t, u, v, packet
        )
    np.testing.assert_array_equal(blocked, expected_blocked)
    np.testing.assert_array_equal(prim, expected_hits.prim)
    np.testing.assert_array_equal(t, expected_hits.t)
    assert expected_blocked.any() and not expected_blocked.all() and expected_hits.found.any()
