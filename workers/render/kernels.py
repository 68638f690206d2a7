"""Scalar building blocks of the compiled path-tracing kernels: frames, warps, GGX, Fresnel and MIS for one
shading point, called from the per-bounce kernels over wavefront arrays (`workers.render.wavefront`,
`workers.render.lights`, the BSDF families of `workers.render.bsdfs`).

Precision: arithmetic is float64 throughout. These kernels are scalar code, where float32 buys no speed,
and the quantities that need float64 (ray origins offset by 2e-5 of the coordinates, the pixel sums,
GGX at alpha near 1e-4, whose D reaches 1e7) pass through all of them. Embree alone sees float32.

Conventions are those of the NumPy helpers of `workers.render.sampling` and `workers.render.microfacet`
(local frame z = normal); vectors are passed as three floats and returned as tuples.
Compiled with `cache=True` (paid once per machine) and `fastmath=False`, so results do not depend on
how the compiler vectorises a loop, and `nogil=True` kernels run in parallel from the renderer's threads.
The helpers are plain compiled functions, which LLVM inlines into their callers (`scalar` below).
Numba's on-disk cache checks only the timestamp of the file a kernel is defined in, not of the helpers it
links in from here; `workers.render.jit` keys the whole cache on every kernel source, so an edit here
recompiles its users.
"""

from __future__ import annotations

import math

from llvmlite import ir
from numba import types
from numba.extending import intrinsic

from workers.render.jit import njit

INV_PI = 1.0 / math.pi
ALPHA_MIN = 1e-4  # as `workers.render.microfacet.ALPHA_MIN`

# Not Numba's IR-level inline="always": LLVM inlines these anyway. Measured without it (one thread,
# alternating rounds): same images bit for bit, render CPU time within noise; first render on an empty
# cache (CPU s, 5 rounds, median ratio) cornell_glossy 0.92x, env_lit_objects 0.88x, cornell_box 1.0x.
scalar = njit(cache=True, nogil=True, fastmath=False)


@scalar
def frame(nx, ny, nz):
    """Tangents (s, t) completing a unit normal to a right-handed frame (Duff et al. 2017)."""
    sign = 1.0 if nz >= 0 else -1.0
    a = -1.0 / (sign + nz)
    b = nx * ny * a
    return (1.0 + sign * nx * nx * a, sign * b, -sign * nx), (b, sign + ny * ny * a, -ny)


@scalar
def dot3(ax, ay, az, bx, by, bz):
    return ax * bx + ay * by + az * bz


@scalar
def normalized(x, y, z):
    n = max(math.sqrt(x * x + y * y + z * z), 1e-30)
    return x / n, y / n, z / n


@scalar
def safe_sqrt(x):
    return math.sqrt(max(x, 0.0))


@scalar
def cosine_hemisphere(u0, u1):
    """Malley's method on the polar disk map."""
    r = math.sqrt(u0)
    phi = 2.0 * math.pi * u1
    return r * math.cos(phi), r * math.sin(phi), safe_sqrt(1.0 - u0)


@scalar
def uniform_sphere(u0, u1):
    """A uniform direction on the unit sphere (the same operations as `sampling.square_to_uniform_sphere`)."""
    z = 1.0 - 2.0 * u0
    r = safe_sqrt(1.0 - z * z)
    phi = 2.0 * math.pi * u1
    return r * math.cos(phi), r * math.sin(phi), z


@scalar
def power_heuristic(pdf_a, pdf_b):
    """Veach's power heuristic (beta 2); 0 when both pdfs are 0, finite when they are infinite."""
    a2 = min(pdf_a, 1e150) ** 2
    b2 = min(pdf_b, 1e150) ** 2
    denom = a2 + b2
    return a2 / denom if denom > 0 else 0.0


@scalar
def ggx_d(mz, alpha):
    """GGX normal distribution D(m); zero below the surface."""
    if mz <= 0:
        return 0.0
    a2 = alpha * alpha
    denom = mz * mz * (a2 - 1.0) + 1.0
    return a2 / (math.pi * max(denom * denom, 1e-300))


@scalar
def smith_g1(vz, v_m, alpha):
    """Smith masking for GGX of direction v (cosine vz, v.m = v_m); zero when v sees a facet's back."""
    if v_m * vz <= 0:
        return 0.0
    cos2 = vz * vz
    tan2 = max(1.0 - cos2, 0.0) / max(cos2, 1e-300)
    return 2.0 / (1.0 + math.sqrt(1.0 + alpha * alpha * tan2))


@scalar
def visible_normal_pdf(wo_z, wo_m, mz, alpha):
    """Density over microfacet normals of `visible_normal` (solid angle of m)."""
    return smith_g1(wo_z, wo_m, alpha) * max(wo_m, 0.0) * ggx_d(mz, alpha) / max(abs(wo_z), 1e-300)


@scalar
def visible_normal(wx, wy, wz, alpha, u0, u1):
    """A microfacet normal distributed as the normals wo sees (Heitz 2018); wz > 0."""
    vx, vy, vz = alpha * wx, alpha * wy, wz
    n = max(math.sqrt(vx * vx + vy * vy + vz * vz), 1e-300)
    vx, vy, vz = vx / n, vy / n, vz / n
    lensq = vx * vx + vy * vy
    if lensq > 1e-14:
        inv = 1.0 / math.sqrt(lensq)
        t1x, t1y, t1z = -vy * inv, vx * inv, 0.0
    else:
        t1x, t1y, t1z = 1.0, 0.0, 0.0
    t2x, t2y, t2z = vy * t1z - vz * t1y, vz * t1x - vx * t1z, vx * t1y - vy * t1x
    r = math.sqrt(u0)
    phi = 2.0 * math.pi * u1
    p1 = r * math.cos(phi)
    p2 = r * math.sin(phi)
    s = 0.5 * (1.0 + vz)
    p2 = (1.0 - s) * safe_sqrt(1.0 - p1 * p1) + s * p2
    p3 = safe_sqrt(1.0 - p1 * p1 - p2 * p2)
    hx = p1 * t1x + p2 * t2x + p3 * vx
    hy = p1 * t1y + p2 * t2y + p3 * vy
    hz = p1 * t1z + p2 * t2z + p3 * vz
    mx, my, mz = alpha * hx, alpha * hy, max(hz, 1e-12)
    n = math.sqrt(mx * mx + my * my + mz * mz)
    return mx / n, my / n, mz / n


@scalar
def fresnel_dielectric(cos_i, eta):
    """Unpolarised Fresnel reflectance at cosine `cos_i` (sign says the side), eta interior / exterior:
    (F, cos_t signed opposite to cos_i, eta_ti the relative index in the direction of travel)."""
    eta_it = eta if cos_i >= 0 else 1.0 / eta
    eta_ti = 1.0 / eta_it
    c = abs(cos_i)
    cos_t2 = 1.0 - eta_ti * eta_ti * (1.0 - c * c)
    cos_t = safe_sqrt(cos_t2)
    if cos_t2 <= 0:
        f = 1.0
    else:
        rs = (c - eta_it * cos_t) / max(c + eta_it * cos_t, 1e-300)
        rp = (eta_it * c - cos_t) / max(eta_it * c + cos_t, 1e-300)
        f = min(max(0.5 * (rs * rs + rp * rp), 0.0), 1.0)
    return f, (-cos_t if cos_i >= 0 else cos_t), eta_ti


@scalar
def reflect(wx, wy, wz, mx, my, mz):
    c = 2.0 * (wx * mx + wy * my + wz * mz)
    return c * mx - wx, c * my - wy, c * mz - wz


@scalar
def search_right(cdf, u):
    """np.searchsorted(cdf, u, side="right"): the number of entries <= u (binary search)."""
    lo, hi = 0, len(cdf)
    while lo < hi:
        mid = (lo + hi) // 2
        if cdf[mid] <= u:
            lo = mid + 1
        else:
            hi = mid
    return lo


@scalar
def guided_search(cdf, guide, u):
    """`search_right(cdf, u)` started from a guide table, guide[j] = search_right(cdf, j / len(guide))
    (Chen and Asau's cutpoints): with as many cutpoints as entries the answer is about one entry away, so
    a search costs two memory loads instead of log2 len(cdf) dependent ones (the large tables of an
    environment map's rows miss the cache). Scans both ways, so rounding of u * len(guide) cannot err."""
    return search_from(cdf, guide_start(guide, u), u)


@scalar
def guide_start(guide, u):
    """The guide's cutpoint for u: where `guided_search` starts (the one load of the guide table)."""
    return guide[min(int(u * len(guide)), len(guide) - 1)]


@scalar
def search_from(cdf, i, u):
    """`search_right(cdf, u)` by scanning both ways from entry i."""
    while i > 0 and cdf[i - 1] > u:
        i -= 1
    while i < len(cdf) and cdf[i] <= u:
        i += 1
    return i


@intrinsic
def prefetch(typingctx, array, flat_index):
    """Start loading the cache line of element `flat_index` of a C-contiguous array (LLVM's prefetch: read,
    high locality); it changes no value and cannot fault. Kernels whose rows each read a random place of a
    large table prefetch the places of a block of rows before reading any, so the misses overlap."""
    if not isinstance(array, types.Array) or not isinstance(flat_index, types.Integer):
        return None

    def codegen(context, builder, signature, args):
        data = context.make_array(array)(context, builder, args[0]).data
        index = context.cast(builder, args[1], signature.args[1], types.intp)
        byte_ptr, i32 = ir.PointerType(ir.IntType(8)), ir.IntType(32)
        fn = builder.module.declare_intrinsic(  # named for llvmlite's pointer type (p0i8 or p0)
            "llvm.prefetch", [byte_ptr], ir.FunctionType(ir.VoidType(), [byte_ptr, i32, i32, i32])
        )
        builder.call(fn, [builder.bitcast(builder.gep(data, [index]), byte_ptr), i32(0), i32(3), i32(1)])
        return context.get_dummy_value()

    return types.void(array, flat_index), codegen
