"""BSDF sampling against evaluation, direction by direction (as Mitsuba's own test suite checks it).

- Chi-square goodness of fit: directions drawn by `sample_bsdf` are binned on a (theta, phi) grid
  and compared with the counts `eval_bsdf`'s pdf predicts (integrated per bin by Gauss-Legendre).
  Samples the pdf does not cover (delta lobes, rejected samples) form one more cell whose expected count
  is the pdf's missing mass. Cells expected to hold fewer than 5 samples are pooled; a sample in a cell
  of expected count 0 fails outright. Every case must reach p > 0.01 / (number of cases) (Bonferroni).
- The pdf and weight `sample_bsdf` returns are `eval_bsdf`'s pdf and f |cos| / pdf for the same direction.
- Delta lobes: mirror and Snell directions, their weights, and how often each is chosen.
"""

import numpy as np
import pytest
from scipy import stats

import workers.render.bsdfs  # noqa: F401  (registers the built-in families)
from workers.render.bsdf import SurfaceBatch, bsdf_code, eval_bsdf, register_material, sample_bsdf
from workers.render.bsdfs.diffuse import Diffuse
from workers.render.bsdfs.plastic import coat
from workers.render.microfacet import fresnel_dielectric
from workers.render.sampling import INV_PI

SAMPLES = 200_000
THETA_BINS, PHI_BINS = 40, 80
NODES = 6  # Gauss-Legendre nodes per bin and axis
MIN_EXPECTED = 5.0
BASE = (0.7, 0.5, 0.3)

CASES = [
    *(("diffuse", 0.0, theta, False) for theta in (10, 70)),
    *(("conductor", alpha, theta, False) for alpha in (0.1, 0.3, 0.7) for theta in (10, 50, 80)),
    *(("plastic", alpha, theta, False) for alpha in (0.0, 0.1, 0.3, 0.7) for theta in (10, 50, 80)),
    *(
        ("dielectric", alpha, theta, inside)
        for alpha in (0.1, 0.3, 0.7)
        for theta in (10, 50, 80)
        for inside in (False, True)
    ),
]
P_THRESHOLD = 0.01 / (len(CASES) + 1)  # Bonferroni over this module's chi-square tests


def surface(kind: str, alpha: float, n: int, ior: float = 1.5) -> SurfaceBatch:
    base = (1.0, 1.0, 1.0) if kind == "dielectric" else BASE
    return SurfaceBatch(
        np.full(n, bsdf_code(kind), np.int8), np.tile(base, (n, 1)), np.full(n, alpha), np.full(n, ior)
    )


def incident(theta_deg: float, n: int, inside: bool = False) -> np.ndarray:
    t = np.radians(theta_deg)
    return np.tile([np.sin(t), 0.0, -np.cos(t) if inside else np.cos(t)], (n, 1))


def cell_integrals(s: SurfaceBatch, theta: float, inside: bool, cells: np.ndarray, split: int):
    """The pdf's integral over (theta, phi) cells (d omega = sin theta d theta d phi), each split into
    split x split parts of NODES x NODES Gauss-Legendre points; and which cells its support's edge crosses."""
    x, w = np.polynomial.legendre.leggauss(NODES)
    at = ((np.arange(split)[:, None] * 2 + 1 + x[None, :]) / (2 * split)).ravel()  # within a cell, in [0, 1]
    weight = np.tile(w, split) / (2 * split)
    d_theta, d_phi = np.pi / THETA_BINS, 2 * np.pi / PHI_BINS
    t = ((cells // PHI_BINS)[:, None] + at[None, :]) * d_theta
    p = ((cells % PHI_BINS)[:, None] + at[None, :]) * d_phi
    m = len(at)
    t = np.broadcast_to(t[:, :, None], (len(cells), m, m)).ravel()
    p = np.broadcast_to(p[:, None, :], (len(cells), m, m)).ravel()
    wi = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=1)
    _, pdf = eval_bsdf(s.take(np.zeros(len(wi), np.int64)), incident(theta, len(wi), inside), wi)
    pdf = pdf.reshape(len(cells), m * m)
    integrals = (pdf * np.sin(t).reshape(len(cells), m * m)) @ np.outer(weight, weight).ravel()
    return integrals * d_theta * d_phi, (pdf == 0).any(axis=1) & (pdf > 0).any(axis=1)


def expected_counts(s: SurfaceBatch, theta: float, inside: bool) -> np.ndarray:
    """SAMPLES x the pdf's integral per cell; cells the support's edge crosses are integrated 8 x finer."""
    cells = np.arange(THETA_BINS * PHI_BINS)
    integrals, edge = cell_integrals(s, theta, inside, cells, split=1)
    integrals[edge] = cell_integrals(s, theta, inside, cells[edge], split=8)[0]
    return SAMPLES * integrals


def observed_counts(wi: np.ndarray, covered: np.ndarray) -> np.ndarray:
    theta = np.arccos(np.clip(wi[:, 2], -1.0, 1.0))
    theta_bin = np.clip((theta / np.pi * THETA_BINS).astype(int), 0, THETA_BINS - 1)
    phi = np.arctan2(wi[:, 1], wi[:, 0]) % (2 * np.pi)
    phi_bin = np.clip((phi / (2 * np.pi) * PHI_BINS).astype(int), 0, PHI_BINS - 1)
    cells = (theta_bin * PHI_BINS + phi_bin)[covered]
    return np.bincount(cells, minlength=THETA_BINS * PHI_BINS).astype(float)


def chi_square_p_value(observed: np.ndarray, expected: np.ndarray) -> float:
    """Pearson's test with cells of small expected count pooled (Mitsuba's `chi2_test` procedure)."""
    if np.any((expected <= 0) & (observed > 0)):
        return 0.0
    order = np.argsort(expected)
    observed, expected = observed[order], expected[order]
    # Pool every cell below MIN_EXPECTED, then more cells (ascending) until the pool reaches it.
    pooled = int(np.searchsorted(expected, MIN_EXPECTED))
    total = np.cumsum(expected)
    if pooled and total[pooled - 1] < MIN_EXPECTED:
        pooled = min(int(np.searchsorted(total, MIN_EXPECTED)) + 1, len(expected))
    o, e = observed[pooled:], expected[pooled:]
    if pooled:
        o, e = np.append(o, observed[:pooled].sum()), np.append(e, expected[:pooled].sum())
    statistic = np.sum((o - e) ** 2 / e)
    return float(stats.chi2.sf(statistic, len(o) - 1))


def sampling_p_value(s: SurfaceBatch, theta: float, inside: bool, seed: int) -> float:
    rng = np.random.default_rng(seed)
    batch = s.take(np.zeros(SAMPLES, np.int64))
    wi, _, pdf, delta, _ = sample_bsdf(
        batch, incident(theta, SAMPLES, inside), rng.random((SAMPLES, 2)), rng.random(SAMPLES)
    )
    covered = (pdf > 0) & ~delta
    expected = expected_counts(s, theta, inside)
    observed = observed_counts(wi, covered)
    # Delta and rejected samples: what the pdf's integral leaves over.
    observed = np.append(observed, SAMPLES - covered.sum())
    expected = np.append(expected, max(SAMPLES - expected.sum(), 0.0))
    return chi_square_p_value(observed, expected)


@pytest.mark.parametrize(("kind", "alpha", "theta", "inside"), CASES)
def test_sampled_directions_follow_the_evaluated_pdf(kind, alpha, theta, inside):
    p = sampling_p_value(
        surface(kind, alpha, 1), theta, inside, seed=CASES.index((kind, alpha, theta, inside))
    )
    assert p > P_THRESHOLD, f"chi-square p = {p:.2e}"


class _MislabelledDiffuse(Diffuse):
    """Cosine-weighted samples reported with the uniform hemisphere's pdf: a wrong pdf to catch."""

    def eval(self, s, wo, wi):
        f_cos, pdf = super().eval(s, wo, wi)
        return f_cos, np.where(pdf > 0, 0.5 * INV_PI, 0.0)


def test_chi_square_rejects_a_pdf_that_is_not_the_samplers():
    register_material("test_mislabelled_diffuse")(_MislabelledDiffuse)
    p = sampling_p_value(surface("test_mislabelled_diffuse", 0.0, 1), 30, False, seed=0)
    assert p < P_THRESHOLD


@pytest.mark.parametrize(("kind", "alpha", "theta", "inside"), CASES)
def test_sample_pdf_and_weight_are_evals(kind, alpha, theta, inside):
    """For non-delta samples: pdf = eval's pdf, weight = eval's f |cos| / pdf; rejected samples weigh 0."""
    n = 20_000
    rng = np.random.default_rng(5)
    s = surface(kind, alpha, n)
    wo = incident(theta, n, inside)
    wi, weight, pdf, delta, _ = sample_bsdf(s, wo, rng.random((n, 2)), rng.random(n))
    f_cos, eval_pdf = eval_bsdf(s, wo, wi)
    kept = ~delta & (pdf > 0)
    np.testing.assert_allclose(pdf[kept], eval_pdf[kept], rtol=1e-9)
    np.testing.assert_allclose(weight[kept], f_cos[kept] / eval_pdf[kept, None], rtol=1e-9)
    assert np.all(weight[~delta & (pdf == 0)] == 0)


# --------------------------------------------------------------------------- delta lobes

N_DELTA = 100_000


def mirror(wo: np.ndarray) -> np.ndarray:
    return wo * np.array([-1.0, -1.0, 1.0])


@pytest.mark.parametrize("theta", [0, 35, 80])
def test_smooth_conductor_mirrors_with_its_colour(theta):
    rng = np.random.default_rng(6)
    s = surface("conductor", 0.0, N_DELTA)
    s.base[:] = BASE
    wo = incident(theta, N_DELTA)
    wi, weight, pdf, delta, _ = sample_bsdf(s, wo, rng.random((N_DELTA, 2)), rng.random(N_DELTA))
    assert delta.all() and (pdf == 0).all()
    np.testing.assert_allclose(wi, mirror(wo), atol=1e-12)
    np.testing.assert_allclose(weight, np.tile(BASE, (N_DELTA, 1)), rtol=1e-12)
    f_cos, eval_pdf = eval_bsdf(s, wo, wi)
    assert (f_cos == 0).all() and (eval_pdf == 0).all()  # delta lobes are never evaluated


def binomial_ok(successes: int, n: int, p: float) -> bool:
    return stats.binomtest(successes, n, p).pvalue > 1e-4


@pytest.mark.parametrize("inside", [False, True])
@pytest.mark.parametrize("theta", [0, 30, 60, 85])
def test_smooth_dielectric_reflects_with_fresnel_and_refracts_by_snell(theta, inside):
    ior = 1.5
    rng = np.random.default_rng(7)
    s = surface("dielectric", 0.0, N_DELTA, ior)
    wo = incident(theta, N_DELTA, inside)
    wi, weight, pdf, delta, _ = sample_bsdf(s, wo, rng.random((N_DELTA, 2)), rng.random(N_DELTA))
    assert delta.all() and (pdf == 0).all()
    cos_o = np.cos(np.radians(theta)) * (-1 if inside else 1)
    f, _, eta_ti = fresnel_dielectric(np.array([cos_o]), np.array([ior]))
    reflected = wi[:, 2] * wo[:, 2] > 0
    assert binomial_ok(int(reflected.sum()), N_DELTA, float(f[0]))
    np.testing.assert_allclose(wi[reflected], mirror(wo[reflected]), atol=1e-12)
    np.testing.assert_allclose(weight[reflected], 1.0, rtol=1e-12)
    if f[0] < 1:
        t = wi[~reflected]
        sin_o, sin_t = np.sin(np.radians(theta)), np.hypot(t[:, 0], t[:, 1])
        np.testing.assert_allclose(sin_t, sin_o * eta_ti[0], atol=1e-12)  # Snell
        assert (t[:, 0] <= 1e-12).all() and np.allclose(t[:, 1], 0.0)  # opposite side of the normal
        np.testing.assert_allclose(np.linalg.norm(t, axis=1), 1.0, atol=1e-12)
        np.testing.assert_allclose(weight[~reflected], eta_ti[0] ** 2, rtol=1e-12)  # radiance / eta^2


@pytest.mark.parametrize("theta", [0, 45, 80])
def test_smooth_plastic_coat_is_chosen_as_often_as_its_weight_says(theta):
    rng = np.random.default_rng(8)
    s = surface("plastic", 0.0, N_DELTA)
    wo = incident(theta, N_DELTA)
    wi, weight, _, delta, _ = sample_bsdf(s, wo, rng.random((N_DELTA, 2)), rng.random(N_DELTA))
    f = float(fresnel_dielectric(np.array([np.cos(np.radians(theta))]), np.array([1.5]))[0][0])
    p_coat = np.clip(f / (f + (1 - f) * np.mean(BASE)), 0.05, 1.0)
    assert binomial_ok(int(delta.sum()), N_DELTA, p_coat)
    np.testing.assert_allclose(wi[delta], mirror(wo[delta]), atol=1e-12)
    np.testing.assert_allclose(weight[delta], f / p_coat, rtol=1e-12)


def test_smooth_white_plastic_returns_all_energy():
    """A smooth coat over a white base: albedo F + (1 - F) exactly (module docstring of plastic.py)."""
    n = 400_000
    rng = np.random.default_rng(9)
    s = surface("plastic", 0.0, n)
    s.base[:] = 1.0
    _, weight, _, _, _ = sample_bsdf(s, incident(40, n), rng.random((n, 2)), rng.random(n))
    mean, err = weight.mean(0), weight.std(0) / np.sqrt(n)
    assert np.all(np.abs(mean - 1.0) < 4 * err + 1e-4), (mean, err)
    assert coat(0.0, 1.5).internal_reflectance == pytest.approx(0.5963, abs=1e-4)
