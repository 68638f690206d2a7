"""Embree queries bounded by a distance: what a caller keeps is what an unbounded query finds."""

from __future__ import annotations

import numpy as np

from workers.render.embree import RayScene
from workers.scene.builtin import cornell_box
from workers.scene.compile import compile_scene


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
