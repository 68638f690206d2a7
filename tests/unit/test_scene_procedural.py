"""Procedural generators: deterministic per seed, valid meshes, consistent normals, clear parameter errors."""

import numpy as np
import pytest

from workers.scene.errors import SceneError
from workers.scene.procedural import GENERATORS, generate, gradient_noise
from workers.scene.shapes import check_mesh

SMALL = {
    "ground_plane": {},
    "fractal_tree": {"depth": 4},
    "displaced_sphere": {"resolution": 24},
    "fur": {"strands": 200},
}


def geometric_normals(mesh):
    v, f = mesh.vertices, mesh.faces
    n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    return n / np.linalg.norm(n, axis=1, keepdims=True)


def test_every_registered_generator_is_covered():
    assert set(GENERATORS) == set(SMALL)


@pytest.mark.parametrize("name", sorted(SMALL))
def test_generators_are_deterministic_valid_and_consistently_oriented(name):
    seeded = "seed" in GENERATORS[name][0].model_fields
    params = SMALL[name] | ({"seed": 5} if seeded else {})
    a, b = generate(name, params, "x"), generate(name, params, "x")
    np.testing.assert_array_equal(a.vertices, b.vertices)
    np.testing.assert_array_equal(a.faces, b.faces)
    checked = check_mesh(a, "x")  # finite, in-range indices, no degenerate triangles
    assert checked.num_triangles == a.num_triangles
    assert a.normals is not None and a.uvs is not None
    # shading normals agree with the winding, so renderers may use either to decide the front side
    mean_shading = a.normals[a.faces].mean(axis=1)
    assert (np.einsum("ij,ij->i", mean_shading, geometric_normals(a)) > 0).all()


@pytest.mark.parametrize("name", ["fractal_tree", "displaced_sphere", "fur"])
def test_seed_changes_the_geometry(name):
    a = generate(name, SMALL[name] | {"seed": 1}, "x")
    b = generate(name, SMALL[name] | {"seed": 2}, "x")
    assert a.vertices.shape == b.vertices.shape and not np.allclose(a.vertices, b.vertices)


def test_fractal_tree_default_size_and_parts_partition_the_tree():
    tree = generate("fractal_tree", {"seed": 3}, "x")
    assert 50_000 <= tree.num_triangles <= 150_000
    branches = generate("fractal_tree", {"seed": 3, "parts": "branches"}, "x")
    leaves = generate("fractal_tree", {"seed": 3, "parts": "leaves"}, "x")
    assert branches.num_triangles + leaves.num_triangles == tree.num_triangles
    np.testing.assert_array_equal(np.concatenate([branches.vertices, leaves.vertices]), tree.vertices)
    assert tree.vertices[:, 1].min() >= 0.0  # stands on the ground


def test_displaced_sphere_is_outward_closed_and_sized_by_resolution():
    r = 30
    mesh = generate("displaced_sphere", {"resolution": r, "amplitude": 0.3}, "x")
    assert mesh.num_triangles == 4 * r * (r - 1)
    centroids = mesh.vertices[mesh.faces].mean(axis=1)
    assert (np.einsum("ij,ij->i", geometric_normals(mesh), centroids) > 0).all()
    radii = np.linalg.norm(mesh.vertices, axis=1)
    assert radii.min() > 0.2 and radii.std() > 0.01  # displaced, never collapsed
    # seam copies share positions and normals: no shading seam
    width = 2 * r + 1
    grid = mesh.vertices.reshape(r + 1, width, 3)
    np.testing.assert_allclose(grid[:, 0], grid[:, -1], atol=1e-12)
    normals = mesh.normals.reshape(r + 1, width, 3)
    np.testing.assert_allclose(normals[:, 0], normals[:, -1])


def test_fur_counts_and_strands_stay_above_the_base():
    mesh = generate("fur", {"strands": 50, "segments": 3, "sides": 4}, "x")
    assert mesh.num_triangles == 2 + 50 * 3 * 4 * 2
    assert mesh.vertices[:, 1].min() >= -0.004  # only the strands' root rings dip by their radius


def test_gradient_noise_is_bounded_and_seeded():
    points = np.random.default_rng(0).uniform(-50, 50, (20_000, 3))
    n = gradient_noise(points, 1)
    assert np.abs(n).max() <= 1.0 and n.std() > 0.1
    np.testing.assert_array_equal(n, gradient_noise(points, 1))
    assert not np.allclose(n, gradient_noise(points, 2))


@pytest.mark.parametrize(
    ("name", "params", "field", "problem"),
    [
        ("spiral", {}, "objects[1].shape.generator", "unknown procedural generator 'spiral'"),
        (
            "displaced_sphere",
            {"resolution": 2},
            "objects[1].shape.params.resolution",
            "greater than or equal",
        ),
        ("fur", {"strands": "many"}, "objects[1].shape.params.strands", "valid integer"),
        ("fractal_tree", {"leaf_colour": 1}, "objects[1].shape.params.leaf_colour", "Extra inputs"),
        (
            "fractal_tree",
            {"parts": "leaves", "leaves_per_tip": 0},
            "objects[1].shape.params",
            "leaves_per_tip",
        ),
    ],
)
def test_bad_generator_or_params_name_the_field(name, params, field, problem):
    with pytest.raises(SceneError, match=problem) as caught:
        generate(name, params, "objects[1].shape")
    assert caught.value.field == field
