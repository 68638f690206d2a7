"""Training data of the `lod` kind (Weier et al. 2023, Sec. 5): voxel and LoD sampling, boundary segments,
and the appearance estimator of Eq. 3 against analytic integrals.

For one diffuse plane of albedo rho crossing a voxel, Eq. 3 is exact in closed form: the numerator
integrates T over the plane's visible part, the denominator is that part's projected area, so
phi(w_o, w_i) = rho / pi |w_i . n| when w_i lies on w_o's side of the plane and 0 otherwise, whatever the
plane's position and tilt. A checkerboard albedo whose squares tile the voxel's cross-section exactly
gives the mean of the two albedos, with genuine sample variance (which p_o hits which square).
"""

from __future__ import annotations

import numpy as np
import pytest

from workers.models.lod import sampling
from workers.models.lod.grid import LodGrid
from workers.models.lod.sampling import (
    RR_MAX_SURVIVAL,
    asset_tracer,
    boundary_pairs,
    box_exit,
    first_asset_hits,
    sample_voxels,
    throughput_estimates,
)
from workers.models.lod.segments import roulette_survivors
from workers.scene.format.spec import (
    BoxShape,
    CheckerTexture,
    ConstantBackground,
    Diffuse,
    RectangleShape,
    SceneObject,
    SceneSpec,
    Transform,
)
from workers.scene.geometry.compile import compile_scene

ALBEDO = (0.8, 0.5, 0.2)
CHI2_2DOF_P1E4 = 18.42  # the chi-square critical value at p = 1e-4 for 2 degrees of freedom


def unit(v) -> np.ndarray:
    v = np.asarray(v, float)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def one_voxel(lo=-1.0, extent=2.0) -> LodGrid:
    """A grid of a single voxel [lo, lo + extent]^3."""
    return LodGrid(np.full(3, lo), extent, [1], [np.zeros(1, np.int64)])


def scene_of(*objects: SceneObject, reflectance=ALBEDO):
    spec = SceneSpec(
        materials={"m": Diffuse(reflectance=reflectance)},
        objects=list(objects),
        environment=ConstantBackground(),
    )
    return compile_scene(spec)


def plane(name="plane", rotate=(0.0, 0.0, 0.0), translate=(0.0, 0.0, 0.0), size=4.0) -> SceneObject:
    """A square of side 2 x size in z = 0 (before rotation), facing +z."""
    transform = Transform(scale=size, rotate=rotate, translate=translate)
    return SceneObject(name=name, shape=RectangleShape(), material="m", transform=transform)


def normal_of(rotate) -> np.ndarray:
    return Transform(rotate=rotate).to_matrix()[:3, :3] @ np.array([0.0, 0.0, 1.0])


def fixed_pairs(grid, n, wo, rng, grow=0.0):
    return boundary_pairs(
        grid, np.zeros(n, np.int64), np.zeros((n, 3), np.int64), rng, grow, np.tile(wo, (n, 1))
    )


def assert_mean_within_standard_errors(values: np.ndarray, expected: np.ndarray, k: float = 4.0):
    mean = values.mean(0)
    standard_error = values.std(0, ddof=1) / np.sqrt(len(values))
    tolerance = k * standard_error + 1e-6 * np.abs(expected) + 1e-12  # albedos are float32
    assert np.all(np.abs(mean - expected) <= tolerance), (mean, expected, standard_error)


# --------------------------------------------------------------------------- boundary pairs


def test_boundary_pairs_lie_on_the_grown_box_along_minus_wo():
    rng = np.random.default_rng(21)
    grid = LodGrid(np.array([-1.0, 0.5, 2.0]), 3.0, [8, 4], [np.zeros(1, np.int64)] * 2)
    n = 5000
    level = rng.integers(2, size=n)
    cells = rng.integers(0, 4, (n, 3))
    grow = 0.005
    pairs = boundary_pairs(grid, level, cells, rng, grow)
    size = grid.extent / np.asarray(grid.resolutions)[level][:, None]
    lo = grid.lo + cells * size - grow * size
    hi = lo + (1 + 2 * grow) * size
    np.testing.assert_allclose(pairs.lo, lo)
    np.testing.assert_allclose(pairs.hi, hi)
    np.testing.assert_allclose(np.linalg.norm(pairs.wo, axis=1), 1.0)
    eps = 1e-9 * size
    # p_o on a face of the grown box that faces w_o (w_o . n_face > 0), p_i on the boundary, inside.
    on_hi, on_lo = pairs.p_o == hi, pairs.p_o == lo
    assert np.all((on_hi | on_lo).sum(1) == 1)
    assert np.all(pairs.wo[on_hi] > 0) and np.all(pairs.wo[on_lo] < 0)
    for p in (pairs.p_o, pairs.p_i):
        assert np.all((p >= lo - eps) & (p <= hi + eps))
    assert np.all(np.any((np.abs(pairs.p_i - lo) < eps) | (np.abs(pairs.p_i - hi) < eps), axis=1))
    # p_i - p_o is parallel to -w_o, of the recorded length, and the segment spans the box.
    delta = pairs.p_i - pairs.p_o
    np.testing.assert_allclose(delta, -pairs.length[:, None] * pairs.wo, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(delta, axis=1), pairs.length)
    assert np.all(pairs.length > 0)
    np.testing.assert_allclose(box_exit(lo, hi, pairs.p_o, -pairs.wo), pairs.length)
    # `take` keeps the rows together.
    part = pairs.take(np.array([3, 1]))
    assert np.array_equal(part.p_i, pairs.p_i[[3, 1]]) and np.array_equal(part.hi, pairs.hi[[3, 1]])


def test_faces_are_chosen_in_proportion_to_projected_area():
    rng = np.random.default_rng(22)
    n = 30000
    wo = unit([0.2, -0.5, 0.84])
    pairs = fixed_pairs(one_voxel(), n, wo, rng)
    on_face = (pairs.p_o == pairs.hi) | (pairs.p_o == pairs.lo)
    counts = on_face.sum(0)
    assert counts.sum() == n
    expected = n * np.abs(wo) / np.abs(wo).sum()
    chi2 = float(((counts - expected) ** 2 / expected).sum())
    assert chi2 < CHI2_2DOF_P1E4, (counts, expected)
    # p_o is uniform on its face: the other coordinates' means and variances are those of U(-1, 1).
    x_face = pairs.p_o[on_face[:, 0]]
    assert np.all(x_face[:, 0] == 1.0)  # w_o . x > 0: the +x face
    for axis in (1, 2):
        values = x_face[:, axis]
        assert abs(values.mean()) < 4 * np.sqrt(1 / 3 / len(values))
        assert values.var() == pytest.approx(1 / 3, rel=0.05)


def test_segment_density_is_uniform_inside_the_voxel():
    """Isotropic lines through a convex box spend a share of their length in a sub-box equal to its share of
    the volume (Crofton): 1/8 for the central half-size cube. Uniform points on two random faces give more
    weight to the middle and would fail (Fig. 12a)."""
    rng = np.random.default_rng(23)
    n = 40000
    pairs = boundary_pairs(one_voxel(), np.zeros(n, np.int64), np.zeros((n, 3), np.int64), rng, 0.0)
    inner_lo, inner_hi = np.full(3, -0.5), np.full(3, 0.5)
    d = -pairs.wo
    with np.errstate(divide="ignore", invalid="ignore"):
        t0 = (inner_lo - pairs.p_o) / d
        t1 = (inner_hi - pairs.p_o) / d
    near = np.where(d != 0, np.minimum(t0, t1), -np.inf).max(1)
    far = np.where(d != 0, np.maximum(t0, t1), np.inf).min(1)
    inside = np.clip(far, 0, pairs.length) - np.clip(near, 0, pairs.length)
    share = np.clip(inside, 0, None).sum() / pairs.length.sum()
    assert share == pytest.approx(1 / 8, abs=0.006)
    # and the mean chord of a cube of side 2 is 4 V / S = 4 * 8 / 24 (Cauchy).
    assert pairs.length.mean() == pytest.approx(4 / 3, rel=0.01)


# --------------------------------------------------------------------------- voxel and LoD sampling


def sparse_grid() -> LodGrid:
    """A 3-level grid whose LoD-0 voxels cluster unevenly: the coarse voxels hold 1 to 8 children."""
    rng = np.random.default_rng(24)
    occupied = np.zeros((8, 8, 8), bool)
    occupied[0:2, 0:2, 0:2] = True  # one full coarse voxel (8 children)
    occupied[4, 4, 4] = True  # a lonely child
    occupied[rng.integers(0, 8, 12), rng.integers(0, 8, 12), rng.integers(0, 8, 12)] = True
    keys = [np.flatnonzero(occupied.reshape(-1))]
    for r in (4, 2):
        occupied = occupied.reshape(r, 2, r, 2, r, 2).any(axis=(1, 3, 5))
        keys.append(np.flatnonzero(occupied.reshape(-1)))
    return LodGrid(np.zeros(3), 1.0, [8, 4, 2], keys)


def test_sample_voxels_uses_the_ancestor_rule_with_uniform_levels():
    grid = sparse_grid()
    rng = np.random.default_rng(25)
    n = 60000
    level, cells = sample_voxels(grid, n, rng)
    # Level frequencies uniform.
    counts = np.bincount(level, minlength=3)
    chi2 = float(((counts - n / 3) ** 2 / (n / 3)).sum())
    assert chi2 < CHI2_2DOF_P1E4, counts
    fine = grid.cells(0)
    for lv in range(3):
        chosen = cells[level == lv]
        keys = grid.key(lv, chosen)
        assert np.isin(keys, grid.keys[lv]).all()  # only occupied voxels of that level
        # Each voxel in proportion to its occupied LoD-0 descendants (ancestor = cell >> shift).
        children = np.bincount(
            np.searchsorted(grid.keys[lv], grid.key(lv, fine >> grid.shifts[lv])),
            minlength=len(grid.keys[lv]),
        )
        expected = len(chosen) * children / children.sum()
        observed = np.bincount(np.searchsorted(grid.keys[lv], keys), minlength=len(grid.keys[lv]))
        chi2 = float(((observed - expected) ** 2 / expected).sum())
        dof = len(expected) - 1
        assert chi2 < dof + 6 * np.sqrt(2 * dof) + 10, (lv, observed, expected)  # far below p = 1e-4
    # The full coarse voxel (8 children) against the one holding (4, 4, 4) at LoD 1.
    at1 = cells[level == 1]
    ratio = np.all(at1 == [0, 0, 0], axis=1).sum() / np.all(at1 == [2, 2, 2], axis=1).sum()
    lonely_children = np.all(fine >> 1 == [2, 2, 2], axis=1).sum()
    assert lonely_children < 8
    assert ratio == pytest.approx(8.0 / lonely_children, rel=0.25)


# --------------------------------------------------------------------------- appearance estimator


@pytest.mark.parametrize(
    ("rotate", "offset"),
    [((0.0, 0.0, 0.0), 0.0), ((0.0, 0.0, 0.0), 0.37), ((31.0, -23.0, 0.0), 0.1)],
    ids=["axis-aligned", "axis-aligned-off-centre", "tilted"],
)
def test_one_diffuse_plane_gives_rho_over_pi_cos(rotate, offset):
    normal = normal_of(rotate)
    scene = scene_of(plane(rotate=rotate, translate=tuple(offset * normal)))
    tracer = asset_tracer(scene, ["plane"])
    rng = np.random.default_rng(26)
    n = 6000
    wo = unit([0.3, -0.4, 0.85])
    pairs = fixed_pairs(one_voxel(), n, wo, rng)
    occluded, hits = first_asset_hits(tracer, pairs)
    # The acceptance rate is the plane's projected area inside the voxel over the voxel's (Eq. 3's
    # denominator); for the axis-aligned plane 4 |w_o . z| / (4 (|x| + |y| + |z|)).
    if rotate == (0.0, 0.0, 0.0):
        expected_rate = abs(wo[2]) / np.abs(wo).sum()
        assert occluded.mean() == pytest.approx(expected_rate, abs=4 * np.sqrt(expected_rate / n))
    assert 0.2 < occluded.mean() < 0.8
    rows = np.flatnonzero(occluded)
    same_side = unit(np.where(np.sign(wo @ normal) == 1, 1, -1) * normal + np.array([0.4, 0.1, -0.2]))
    for wi_direction, expected_cos in ((same_side, abs(same_side @ normal)), (unit(-same_side), 0.0)):
        wi = np.tile(wi_direction, (len(rows), 1))
        values = throughput_estimates(tracer, pairs.take(rows), hits.take(rows), wi, rng, max_bounces=64)
        assert values.shape == (len(rows), 3) and np.isfinite(values).all() and (values >= 0).all()
        expected = np.asarray(ALBEDO) / np.pi * expected_cos
        assert_mean_within_standard_errors(values, expected)
    # Nothing occluded: nothing to estimate, and no rows are needed at all.
    empty = throughput_estimates(tracer, pairs.take(rows[:0]), hits.take(rows[:0]), np.zeros((0, 3)), rng, 8)
    assert empty.shape == (0, 3)


def test_checkerboard_plane_averages_its_albedos_over_the_voxel():
    # UVs span the square of side 8: a checker of scale 16 has squares of 0.5, tiling [-1, 1]^2 4 x 4.
    checker = CheckerTexture(color0=(0.9, 0.6, 0.3), color1=(0.1, 0.2, 0.3), scale=16.0)
    scene = scene_of(plane(), reflectance=checker)
    tracer = asset_tracer(scene, ["plane"])
    rng = np.random.default_rng(27)
    n = 8000
    wo = unit([-0.5, 0.2, -0.7])
    pairs = fixed_pairs(one_voxel(), n, wo, rng)
    occluded, hits = first_asset_hits(tracer, pairs)
    rows = np.flatnonzero(occluded)
    wi_direction = unit([0.1, 0.6, -0.5])  # on w_o's side (z < 0)
    wi = np.tile(wi_direction, (len(rows), 1))
    values = throughput_estimates(tracer, pairs.take(rows), hits.take(rows), wi, rng, max_bounces=64)
    mean_albedo = (np.asarray(checker.color0) + np.asarray(checker.color1)) / 2
    expected = mean_albedo / np.pi * abs(wi_direction[2])
    assert values[:, 0].std() > 0.1 * expected[0]  # the estimates genuinely vary ...
    assert_mean_within_standard_errors(values, expected)  # ... around the analytic mean


def test_higher_orders_are_unbiased_under_russian_roulette(monkeypatch):
    """Floor and wall meeting in a right-angle corner through the voxel: light bounces between them, so the
    estimate has terms beyond the first vertex. Albedo-based Russian roulette with survival capped at 0.95
    or at 0.3 must give the same expectation (the weights divide by the survival), and that expectation
    is not zero."""
    scene = scene_of(plane("floor"), plane("wall", rotate=(0.0, 90.0, 0.0)))
    tracer = asset_tracer(scene, ["floor", "wall"])
    rng = np.random.default_rng(30)
    n = 20000
    pairs = boundary_pairs(one_voxel(), np.zeros(n, np.int64), np.zeros((n, 3), np.int64), rng, 0.0)
    occluded, hits = first_asset_hits(tracer, pairs)
    rows = np.flatnonzero(occluded)
    pairs, hits = pairs.take(rows), hits.take(rows)
    wi = unit(rng.normal(size=(len(rows), 3)))
    first = throughput_estimates(tracer, pairs, hits, wi, np.random.default_rng(1), max_bounces=1)
    higher = {}
    for cap in (0.95, 0.3):
        monkeypatch.setattr(sampling, "RR_MAX_SURVIVAL", cap)
        values = throughput_estimates(tracer, pairs, hits, wi, np.random.default_rng(2), max_bounces=64)
        # The first vertex does not depend on the random numbers: what differs is the higher orders.
        higher[cap] = (values - first)[:, 0]
    a, b = higher[0.95], higher[0.3]
    se_a, se_b = a.std() / np.sqrt(len(a)), b.std() / np.sqrt(len(b))
    assert a.mean() > 8 * se_a  # about a sixth of the red throughput bounces more than once
    assert abs(a.mean() - b.mean()) < 4 * np.hypot(se_a, se_b), (a.mean(), b.mean(), se_a, se_b)


def test_shadow_rays_are_blocked_inside_the_voxel():
    """Paths entering the 0.01 gap between two parallel planes from the voxel's side: every vertex is in the
    gap, where the shadow ray towards w_i = +-z meets the other plane before the voxel's boundary (a
    slanted w_i could leave through a side face near it), and the path leaves the gap only through the
    voxel's boundary: every estimate is exactly 0."""
    scene = scene_of(plane("a"), plane("b", translate=(0.0, 0.0, 0.01)))
    tracer = asset_tracer(scene, ["a", "b"])
    rng = np.random.default_rng(31)
    pairs = fixed_pairs(one_voxel(), 2000, unit([1.0, 0.3, -0.002]), rng)
    pairs.p_o[:, 2] = rng.uniform(0.0005, 0.0095, 2000)
    pairs.p_o[:, 0] = 1.0  # the +x face
    occluded, hits = first_asset_hits(tracer, pairs)
    rows = np.flatnonzero(occluded)
    assert len(rows) > 300
    for wi_direction in ([0.0, 0.0, 1.0], [0.0, 0.0, -1.0]):
        wi = np.tile(unit(wi_direction), (len(rows), 1))
        values = throughput_estimates(tracer, pairs.take(rows), hits.take(rows), wi, rng, max_bounces=64)
        assert np.array_equal(values, np.zeros_like(values))


def test_paths_trapped_between_close_planes_stay_finite():
    """Two parallel planes of albedo 1, 0.002 voxel apart, reaching beyond the voxel: paths entering the gap
    bounce hundreds of times (Russian roulette at 0.95 only) or hit max_voxel_bounces; with a plane lying
    exactly on the voxel's face too, where segments start on geometry."""
    scene = scene_of(
        plane("a", translate=(0.0, 0.0, 0.0)),
        plane("b", translate=(0.0, 0.0, 0.004)),
        plane("on_face", translate=(0.0, 0.0, -1.0)),
        reflectance=(1.0, 1.0, 1.0),
    )
    tracer = asset_tracer(scene, ["a", "b", "on_face"])
    rng = np.random.default_rng(28)
    n = 3000
    pairs = boundary_pairs(one_voxel(), np.zeros(n, np.int64), np.zeros((n, 3), np.int64), rng, 0.005)
    # Also segments entering the gap edge-on from the sides.
    grazing = fixed_pairs(one_voxel(), 500, unit([1.0, 0.3, 0.0005]), rng)
    grazing.p_o[:, 2] = rng.uniform(0.0, 0.004, 500)
    grazing.p_i[:, 2] = grazing.p_o[:, 2]
    for p in (pairs, grazing):
        occluded, hits = first_asset_hits(tracer, p)
        rows = np.flatnonzero(occluded)
        assert len(rows) > 0
        wi = unit(rng.normal(size=(len(rows), 3)))
        for max_bounces in (1, 2, 64):
            values = throughput_estimates(tracer, p.take(rows), hits.take(rows), wi, rng, max_bounces)
            assert np.isfinite(values).all() and (values >= 0).all()
            assert values.max() > 0


def test_closed_box_inside_the_voxel():
    """A closed box of albedo 1 filling most of the voxel: every estimate is finite and non-negative, and a
    convex box reflects once (f cos of the first hit exactly: rho / pi |w_i . n| on w_o's side)."""
    box = SceneObject(name="box", shape=BoxShape(), material="m", transform=Transform(scale=0.8))
    scene = scene_of(box, reflectance=(1.0, 1.0, 1.0))
    tracer = asset_tracer(scene, ["box"])
    rng = np.random.default_rng(29)
    n = 4000
    pairs = boundary_pairs(one_voxel(), np.zeros(n, np.int64), np.zeros((n, 3), np.int64), rng, 0.0)
    occluded, hits = first_asset_hits(tracer, pairs)
    rows = np.flatnonzero(occluded)
    wi = unit(rng.normal(size=(len(rows), 3)))
    values = throughput_estimates(tracer, pairs.take(rows), hits.take(rows), wi, rng, 64)
    assert np.isfinite(values).all() and (values >= 0).all()
    hit_points = pairs.p_o[rows] - hits.t[rows, None] * pairs.wo[rows]
    face = np.argmax(np.abs(hit_points), axis=1)
    normal = np.zeros((len(rows), 3))
    normal[np.arange(len(rows)), face] = np.sign(hit_points[np.arange(len(rows)), face])
    expected = np.maximum((wi * normal).sum(1), 0.0) / np.pi  # the box's outward face, seen from outside
    np.testing.assert_allclose(values[:, 0], expected, atol=1e-6)


def test_roulette_undoes_the_radiance_scaling_of_a_refraction():
    """A smooth refraction into glass (weight 1/eta^2 = 0.44, eta 1.5) loses no energy: the path survives
    with the cap 0.95 (not 0.44) and carries beta x 0.44 / 0.95; a reflection (eta 1) of albedo 0.44
    survives with 0.44, as before."""
    n = 10_000
    u = (np.arange(n) + 0.5) / n
    for eta, survival in ((1.5, RR_MAX_SURVIVAL), (1.0, 1 / 1.5**2)):
        beta = np.ones((n, 3))
        keep = roulette_survivors(beta, np.full((n, 3), 1 / 1.5**2), np.full(n, eta), u, RR_MAX_SURVIVAL)
        assert len(keep) == round(survival * n)
        np.testing.assert_allclose(beta[keep], 1 / 1.5**2 / survival, rtol=1e-12)
