"""Procedural generators: deterministic per seed, valid meshes, consistent normals, clear parameter errors."""

import numpy as np
import pytest

from workers.scene.format.errors import SceneError
from workers.scene.format.spec import Structure
from workers.scene.generators.catalogue import GENERATORS, generate
from workers.scene.generators.mesoscale import MATERIAL_KINDS, MesoscaleSlabParams, local_strands
from workers.scene.generators.procedural import gradient_noise
from workers.scene.geometry.shapes import check_mesh

SMALL = {
    "ground_plane": {},
    "fractal_tree": {"depth": 4},
    "displaced_sphere": {"resolution": 24},
    "fur": {"strands": 200},
    "menger_sponge": {"level": 2},
    "hollow_box": {},
    "thin_wall_rooms": {"cells_x": 2, "cells_y": 1, "cells_z": 2},
    "mesoscale_slab": {"tiles": 1, "structure": {"density": 5.0}},
    "mesoscale_base": {"tiles": 1},
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


# --------------------------------------------------------------------------- test assets for the `lod` kind


def merged(mesh):
    """A trimesh of the mesh's triangles; trimesh welds the copies of a corner that carry other normals."""
    import trimesh

    return trimesh.Trimesh(mesh.vertices, mesh.faces)


def duplicate_triangles(mesh) -> int:
    corners = np.sort(np.round(mesh.vertices[mesh.faces], 9).view("f8,f8,f8").reshape(-1, 3), axis=1)
    return len(corners) - len(np.unique(corners, axis=0))


def menger_squares(level: int) -> int:
    """Unit squares of a level-n sponge: 20 level-(n - 1) sponges glued at 48 faces of 8^(n - 1) squares."""
    squares = 6
    for n in range(level):
        squares = 20 * squares - 48 * 8**n
    return squares


def test_menger_sponge_triangle_counts():
    assert [2 * menger_squares(n) for n in range(5)] == [12, 144, 2_112, 36_096, 672_768]
    for level in (2, 3, 4):
        assert generate("menger_sponge", {"level": level}, "x").num_triangles == 2 * menger_squares(level)


@pytest.mark.parametrize("level", [0, 1, 2, 3])
def test_menger_sponge_is_one_closed_surface_without_inner_faces(level):
    size = 2.0
    mesh = generate("menger_sponge", {"level": level, "size": size}, "x")
    closed = merged(mesh)
    assert closed.is_watertight and closed.is_winding_consistent and closed.is_volume
    # faces between touching cubes are gone: the area is that of the outer squares only, and none repeats
    cell = size / 3**level
    assert closed.area == pytest.approx(menger_squares(level) * cell**2)
    assert closed.volume == pytest.approx((20 / 27) ** level * size**3)
    assert duplicate_triangles(mesh) == 0
    # it rests on y = 0, centred on the y axis
    np.testing.assert_allclose(closed.bounds, [[-1, 0, -1], [1, 2, 1]], atol=1e-12)


def test_menger_sponge_center_moves_it():
    mesh = generate("menger_sponge", {"level": 1, "center": [1, 2, 3]}, "x")
    np.testing.assert_allclose(mesh.vertices.min(axis=0), [0.5, 1.5, 2.5])
    np.testing.assert_allclose(mesh.vertices.max(axis=0), [1.5, 2.5, 3.5])


def fibonacci_directions(n: int) -> np.ndarray:
    i = np.arange(n) + 0.5
    y = 1 - 2 * i / n
    r = np.sqrt(1 - y * y)
    phi = np.pi * (1 + 5**0.5) * i
    return np.stack([r * np.cos(phi), y, r * np.sin(phi)], axis=1)


def triangles(mesh):
    return mesh.vertices[mesh.faces]


def test_hollow_box_cavity_is_sealed_by_an_inward_surface():
    from workers.render.embree import RayScene

    size, thickness = 2.0, 0.02
    mesh = generate("hollow_box", {"size": size, "thickness": thickness}, "x")
    closed = merged(mesh)
    assert mesh.num_triangles == 24 and closed.is_watertight and closed.is_winding_consistent
    assert closed.body_count == 2
    assert closed.volume == pytest.approx(size**3 - (size - 2 * thickness) ** 3)  # the inner cube faces in
    centre = np.array([0.0, size / 2, 0.0])
    normals = geometric_normals(mesh)
    rays = RayScene(triangles(mesh))
    directions = fibonacci_directions(4096)
    hits = rays.intersect(np.tile(centre, (len(directions), 1)), directions)
    assert hits.found.all()  # no ray leaves the cavity
    assert (np.einsum("ij,ij->i", normals[hits.prim], directions) < 0).all()  # the inner surface faces in
    inner = size / 2 - thickness
    np.testing.assert_allclose(hits.t, inner / np.abs(directions).max(axis=1), rtol=1e-5)
    # from outside, rays towards the centre meet the outward outer surface first
    outside = centre + 3.0 * directions
    hits = rays.intersect(outside, -directions)
    assert hits.found.all() and (np.einsum("ij,ij->i", normals[hits.prim], -directions) < 0).all()
    np.testing.assert_allclose(hits.t, 3.0 - (size / 2) / np.abs(directions).max(axis=1), rtol=1e-5)


def test_thin_wall_rooms_is_closed_small_and_deterministic():
    mesh = generate("thin_wall_rooms", {}, "x")
    assert mesh.num_triangles < 50_000
    closed = merged(mesh)
    assert closed.is_watertight and closed.is_winding_consistent and closed.is_volume
    assert duplicate_triangles(mesh) == 0
    np.testing.assert_allclose(closed.bounds, [[-1, 0, -1], [1, 1, 1]], atol=1e-12)
    normals = mesh.normals
    assert (np.abs(normals).max(axis=1) == 1.0).all()  # axis-aligned faces only
    other = generate("thin_wall_rooms", {"seed": 1}, "x")
    assert not (other.vertices.shape == mesh.vertices.shape and np.allclose(other.vertices, mesh.vertices))
    largest = generate("thin_wall_rooms", {"cells_x": 6, "cells_y": 6, "cells_z": 6}, "x")
    assert merged(largest).is_watertight and largest.num_triangles < 100_000


def test_thin_wall_rooms_walls_are_thin_slabs():
    from workers.render.embree import RayScene

    t = 0.02
    mesh = generate("thin_wall_rooms", {"jitter": 0.0, "thickness": t, "windows": 1.0, "doors": 1.0}, "x")
    rays = RayScene(triangles(mesh))
    # along +x beside the window and door bands of the first row of rooms: every wall is crossed
    origin, direction = np.array([[-2.0, 0.25, -1 + (0.5 + 0.35) * 2 / 3]]), np.array([[1.0, 0.0, 0.0]])
    crossings = []
    for _ in range(10):
        hits = rays.intersect(origin, direction)
        if not hits.found[0]:
            break
        origin = origin + (hits.t[0] + 1e-4) * direction
        crossings.append(origin[0, 0] - 1e-4)
    third = 1 / 3
    expected = [-1, -1 + t, -third - t / 2, -third + t / 2, third - t / 2, third + t / 2, 1 - t, 1]
    np.testing.assert_allclose(crossings, expected, atol=1e-5)


@pytest.mark.parametrize(("windows", "escape"), [(0.0, False), (1.0, True)])
def test_thin_wall_rooms_windows_are_the_only_openings(windows, escape):
    from workers.render.embree import RayScene

    params = {"seed": 2, "windows": windows, "doors": 1.0, "cells_x": 2, "cells_y": 1, "cells_z": 2}
    mesh = generate("thin_wall_rooms", params, "x")
    rays = RayScene(triangles(mesh))
    directions = fibonacci_directions(4096)
    room_centre = np.array([-0.5, 0.25, -0.5])
    hits = rays.intersect(np.tile(room_centre, (len(directions), 1)), directions)
    assert (~hits.found).any() == escape


@pytest.mark.parametrize(
    ("name", "params", "field", "problem"),
    [
        ("menger_sponge", {"level": 6}, "o.params.level", "less than or equal to 5"),
        ("menger_sponge", {"size": 0}, "o.params.size", "greater than 0"),
        ("menger_sponge", {"centre": [0, 0, 0]}, "o.params.centre", "Extra inputs"),
        ("hollow_box", {"size": 1.0, "thickness": 0.5}, "o.params.thickness", "less than size / 2"),
        ("thin_wall_rooms", {"thickness": 0.1}, "o.params.thickness", "at most a tenth"),
        ("thin_wall_rooms", {"cells_x": 0}, "o.params.cells_x", "greater than or equal to 1"),
        ("thin_wall_rooms", {"windows": 1.5}, "o.params.windows", "less than or equal to 1"),
    ],
)
def test_lod_asset_params_are_checked(name, params, field, problem):
    with pytest.raises(SceneError, match=problem) as caught:
        generate(name, params, "o")
    assert caught.value.field == field


def test_lod_builtin_scenes_compile_with_named_assets():
    from workers.render.embree import RayScene
    from workers.scene.generators.builtin import BUILTIN_SCENES
    from workers.scene.geometry.compile import compile_scene

    names = {"menger_sponge": "sponge", "thin_walls": "rooms", "closed_box": "box"}
    for scene, asset in names.items():
        compiled = compile_scene(BUILTIN_SCENES[scene]())
        assert asset in [o.name for o in compiled.objects]
    # closed_box: one sealed box, no other light than the environment, the camera inside the cavity
    spec = compiled.spec
    assert [o.name for o in compiled.objects] == ["box"] and not spec.lights
    assert spec.environment.type == "constant" and spec.environment.radiance == (6.0, 4.0, 2.0)
    camera = np.array(spec.camera.position)
    directions = fibonacci_directions(1024)
    hits = RayScene(compiled.positions).intersect(np.tile(camera, (len(directions), 1)), directions)
    assert hits.found.all()
    assert (np.einsum("ij,ij->i", compiled.geometric_normals[hits.prim], directions) < 0).all()


@pytest.mark.parametrize("material", MATERIAL_KINDS)
def test_mesoscale_structure_parameters_move_every_family_their_way(material):
    """Strands, blades and loops alike: longer reach higher, denser are more per tile, curlier reach
    farther sideways from their roots; and the slab's neighbouring tiles repeat the centre one."""
    rng = lambda: np.random.default_rng(0)  # noqa: E731

    def strands(**structure):
        centers, _ = local_strands(rng(), 400, material, Structure(**structure))
        return centers

    assert strands(length=0.9)[..., 2].max(1).mean() > 1.5 * strands(length=0.5)[..., 2].max(1).mean()
    sideways = [np.linalg.norm(strands(curliness=c)[..., :2], axis=-1).max(1).mean() for c in (0.0, 1.0)]
    assert sideways[1] > 1.2 * sideways[0], sideways
    params = {"material": material, "tiles": 3, "tile": 1.0, "seed": 4}
    sparse = MesoscaleSlabParams(**params, structure={"density": 10.0})
    assert MesoscaleSlabParams(**params, structure={"density": 40.0}).strands_per_tile() > 3 * (
        sparse.strands_per_tile()
    )
    mesh = generate("mesoscale_slab", params | {"structure": {"density": 10.0}}, "x")
    per_tile = len(mesh.vertices) // 9
    tiles = mesh.vertices.reshape(9, per_tile, 3)
    for k in range(1, 9):
        shift = tiles[k] - tiles[0]
        assert np.allclose(shift, shift[0], atol=1e-9) and np.allclose(shift[0, 1], 0.0)
