"""Region probes: rays start on the region's bounding sphere and point inside."""

import numpy as np

from workers.render.region_rays import rays_from_bounding_sphere

BOX = np.array([[-0.5, -1.0, 0.0], [0.5, 1.0, 0.25]])


def test_sphere_rays_start_on_the_circumscribed_sphere_and_head_inwards():
    o, d = rays_from_bounding_sphere(BOX, 20_000, np.random.default_rng(2))
    centre, radius = BOX.mean(0), 0.5 * np.linalg.norm(BOX[1] - BOX[0])
    np.testing.assert_allclose(np.linalg.norm(o - centre, axis=1), radius, rtol=1e-9)
    assert np.all(np.einsum("ij,ij->i", d, centre - o) > 0)
