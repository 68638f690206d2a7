"""Shell mapping: the exact prism map and its inverse, shared faces, ray/prism intervals against brute force
marching, grazing rays, rays starting inside, and the shells that must be refused."""

from __future__ import annotations

import numpy as np
import pytest

from workers.models.mesogan.shell import Shell
from workers.scene.format.errors import SceneError
from workers.scene.geometry.shapes import sphere


def sphere_shell(height: float = 0.1, subdivisions: int = 2) -> Shell:
    mesh = sphere((0.0, 0.0, 0.0), 1.0, subdivisions)
    return Shell(mesh.vertices[mesh.faces], mesh.normals[mesh.faces], mesh.uvs[mesh.faces], height)


def brute_inside(shell: Shell, points: np.ndarray) -> np.ndarray:
    """Whether each point maps inside some prism: the inverse map in every prism, in one batch."""
    prism = np.repeat(np.arange(len(shell)), len(points))
    b, t = shell.inverse(prism, np.tile(points, (len(shell), 1)))
    return shell.contains(b, t).reshape(len(shell), len(points)).any(0)


def test_the_inverse_prism_map_round_trips_to_1e6():
    shell = sphere_shell()
    rng = np.random.default_rng(0)
    n = 2000
    prism = rng.integers(len(shell), size=n)
    b = rng.dirichlet([1, 1, 1], n)
    t = rng.uniform(0, 1, n)
    b2, t2 = shell.inverse(prism, shell.point(prism, b, t))
    assert np.abs(b2 - b).max() < 1e-6 and np.abs(t2 - t).max() < 1e-6


def test_neighbouring_prisms_agree_on_their_shared_side_face():
    mesh = sphere((0.0, 0.0, 0.0), 1.0, 2)
    shell = Shell(mesh.vertices[mesh.faces], mesh.normals[mesh.faces], mesh.uvs[mesh.faces], 0.15)
    faces = mesh.faces
    rng = np.random.default_rng(1)
    checked = 0
    for a in range(0, len(faces), 19):
        for i, j in ((0, 1), (1, 2), (2, 0)):
            edge = {faces[a, i], faces[a, j]}
            for other in np.flatnonzero([len(edge & set(f)) == 2 for f in faces]):
                if other == a:
                    continue
                s, t = rng.uniform(size=2)
                b = np.zeros((1, 3))
                b[0, i], b[0, j] = 1 - s, s
                point = shell.point(np.array([a]), b, np.array([t]))
                ba, ta = shell.inverse(np.array([a]), point)
                bo, to = shell.inverse(np.array([other]), point)
                assert abs(ta[0] - t) < 1e-9 and abs(to[0] - t) < 1e-9
                assert shell.contains(bo, to)[0]
                # the same point of the shared edge: equal weights on the two shared vertices
                for vertex in edge:
                    wa = ba[0, list(faces[a]).index(vertex)]
                    wo = bo[0, list(faces[other]).index(vertex)]
                    assert abs(wa - wo) < 1e-9
                checked += 1
    assert checked > 20


def test_ray_intervals_match_brute_force_marching():
    shell = sphere_shell(0.2, 1)
    rng = np.random.default_rng(2)
    n = 5
    origins = rng.normal(size=(n, 3))
    origins *= 2.5 / np.linalg.norm(origins, axis=1, keepdims=True)
    directions = -origins / 2.5 + 0.25 * rng.normal(size=(n, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    intervals = shell.intervals(origins, directions, np.zeros(n), np.full(n, np.inf))
    steps = np.linspace(0.0, 5.0, 1251)
    for ray in range(n):
        inside = brute_inside(shell, origins[ray] + steps[:, None] * directions[ray])
        mine = intervals.ray == ray
        assert abs(inside.mean() * 5.0 - (intervals.leave - intervals.enter)[mine].sum()) < 6e-3
        if inside.any():
            assert abs(steps[np.argmax(inside)] - intervals.enter[mine].min()) < 3e-3
            assert abs(steps[len(steps) - 1 - np.argmax(inside[::-1])] - intervals.leave[mine].max()) < 3e-3


def one_prism(height: float = 0.5) -> Shell:
    base = np.array([[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]])
    normals = np.array([[[0.0, 0.0, 1.0], [0.2, 0.0, 1.0], [0.0, 0.2, 1.0]]])
    uvs = base[:, :, :2]
    return Shell(base, normals, uvs, height)


def test_a_grazing_ray_still_hits_a_side_face():
    shell = one_prism()
    # almost parallel to the side face over the edge x = 0 (bilinear, leaning out by its normals)
    origin = np.array([[-1e-4, -0.5, 0.25]])
    direction = np.array([[1e-3, 1.0, 0.0]])
    direction /= np.linalg.norm(direction)
    intervals = shell.intervals(origin, direction, np.zeros(1), np.full(1, np.inf))
    steps = np.linspace(0.0, 2.0, 20001)
    inside = brute_inside(shell, origin + steps[:, None] * direction)
    assert inside.any() and len(intervals.ray) >= 1
    assert abs(inside.mean() * 2.0 - (intervals.leave - intervals.enter).sum()) < 1e-3


def test_a_ray_starting_inside_the_shell_is_inside_from_its_origin():
    shell = one_prism()
    origin = shell.point(np.array([0]), np.array([[0.3, 0.3, 0.4]]), np.array([0.5]))
    direction = np.array([[0.0, 0.0, 1.0]])
    intervals = shell.intervals(origin, direction, np.zeros(1), np.full(1, np.inf))
    assert intervals.enter[0] == 0.0 and 0 < intervals.leave[0] < 0.5


def test_degenerate_triangles_and_folding_shells_are_refused_naming_the_field():
    base = np.array([[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]]])
    normals = np.tile([0.0, 0.0, 1.0], (1, 3, 1))
    with pytest.raises(SceneError, match="degenerate") as error:
        Shell(base, normals, base[:, :, :2], 0.1, field="config.shell_height")
    assert error.value.field == "config.shell_height"
    with pytest.raises(SceneError, match="folds over"):
        sphere_shell(height=-1.5)  # the inward offset passes the centre: the prisms invert
    mesh = sphere((0.0, 0.0, 0.0), 0.1, 1)  # concave fold: normals flipped inwards, shell thicker than r
    with pytest.raises(SceneError, match="folds over"):
        Shell(mesh.vertices[mesh.faces], -mesh.normals[mesh.faces], mesh.uvs[mesh.faces], 0.3)


def test_the_frame_follows_u_and_v_also_where_the_uvs_are_mirrored():
    """The plane's x runs along +u and its y along +v, so the decoder's light and view must be expressed
    on the same sides: a mirrored UV layout (v against n x u) mirrors the frame."""
    positions = np.array([[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]] * 2)
    normals = np.tile([0.0, 0.0, 1.0], (2, 3, 1))
    uvs = np.array([[[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]], [[0.0, 1.0], [1.0, 1.0], [0.0, 0.0]]])
    shell = Shell(positions, normals, uvs, 0.1)
    tangent, bitangent, normal = shell.frame(np.array([0, 1]), np.full((2, 3), 1 / 3))
    assert np.allclose(tangent, [1, 0, 0]) and np.allclose(normal, [0, 0, 1])
    assert np.allclose(bitangent, [[0, 1, 0], [0, -1, 0]])
