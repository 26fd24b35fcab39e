"""Cook-Torrance / GGX BRDF as Warp functions, built per scalar type (float32, float64).

Notation <-> paper (SPEC section 2; Karis 2013 "Real Shading in Unreal Engine 4" for
the Fresnel and Smith approximations; Deschaintre et al. 2018 for the SVBRDF model):

    n, l, v      unit normal, light and view directions (tangent space, z up)
    h            half vector normalize(l + v)
    rho_d        diffuse albedo ("diffuse" map), linear RGB
    F0           specular albedo ("specular" map), linear RGB
    r            roughness, clamped below at the preset's floor; alpha = r^2
    D(h)         GGX NDF     alpha^2 / (pi ((n.h)^2 (alpha^2 - 1) + 1)^2)
                 evaluated as alpha^2 / (pi (alpha^2 (n.h)^2 + |n x h|^2)^2)
    F(v, h)      Schlick with the spherical-Gaussian exponent
                 F0 + (1 - F0) 2^((-5.55473 (v.h) - 6.98316)(v.h))
    G1(c)        Smith-Schlick c / (c (1 - k) + k), k = alpha / 2
    f            rho_d (1 - F0) / pi + D F G1(n.l) G1(n.v) / (4 (n.l)(n.v))

The GGX denominator is evaluated as alpha^2 (n.h)^2 + |n x h|^2, with |n x h|^2 from
the cross product: equal to (n.h)^2 (alpha^2 - 1) + 1 for unit n and h, but that form
computes 1 - (n.h)^2 by cancellation, with an absolute error of a few float32 ulps of 1
(~1e-7, plus the unit-length error of n and h) against a denominator as small as
alpha^2 ~ 1e-4 at the roughness floor: up to ~1e-3 relative error in d and twice that in
D at the highlight peak. Each component of n x h is computed to within ~1 ulp of 1, so
|n x h|^2 = s^2 carries an absolute error of ~2 s ulp and the denominator a relative error
of at most ~ulp / alpha (largest at s ~ alpha): 1e-5 at the floor. Where n.h <= 0 the
clamped form gives d = 1, and so does this one (|n x h|^2 is replaced by 1 there).

The specular term is evaluated as D F / (4 (n.l (1-k) + k)(n.v (1-k) + k)): the same
value with the (n.l)(n.v) factors of G cancelled against the denominator, so it stays
finite at grazing angles without an epsilon (k >= floor^2 / 2 > 0). All dot products
are clamped at >= 0. ``kernels.reference`` evaluates exactly the same expressions.

Each function is written over lanes (``kernels.lanes``): ``build_brdf(F, 1)`` shades one
pixel per thread with plain Warp builtins (CUDA, Warp's generated adjoint),
``build_brdf(F, lanes)`` shades ``lanes`` consecutive pixels of a row per thread (the CPU),
from the same source. Products and quotients of lane scalars go through ``ln.mul`` /
``ln.div`` (one pixel: ``*`` and ``/``; several: component-wise), lane 3-vectors are
scaled by a lane scalar with ``ln.scale`` / ``ln.shrink``.
"""

import math
from functools import cache
from types import SimpleNamespace

import warp as wp

from kernels.lanes import build_lanes

__all__ = ["build_brdf", "FRESNEL_A", "FRESNEL_B", "NORMALIZE_EPS"]

#: Spherical-Gaussian Fresnel exponent coefficients (Karis 2013, eq. 5 approximation).
FRESNEL_A = -5.55473
FRESNEL_B = -6.98316
#: Added under the square root of every normalisation: keeps normalize() and its
#: gradient finite for zero-length vectors (1e-12 is far below any real |x|^2 here).
NORMALIZE_EPS = 1e-12
PI = math.pi
INV_PI = 1.0 / math.pi


@cache
def build_brdf(F, lanes: int = 1) -> SimpleNamespace:
    """Warp functions of the BRDF for scalar type ``F`` (wp.float32 or wp.float64) and
    ``lanes`` pixels per thread (``kernels.lanes``)."""
    ln = build_lanes(F, lanes)
    L, V, V3F = ln.L, ln.V, ln.V3F
    shared = _position_funcs(F)

    @wp.func
    def safe_normalize(x: V):
        return ln.shrink(x, ln.sqrt(ln.dot(x, x) + L(F(NORMALIZE_EPS))))

    @wp.func
    def ggx_sin2(n: V, h: V, n_dot_h_raw: L):
        """|n x h|^2 (= 1 - (n.h)^2 for unit vectors, without its cancellation near the
        highlight), or 1 where n.h <= 0, the value 1 - (clamped n.h)^2 takes there."""
        c = ln.cross(n, h)
        return ln.select_gt(n_dot_h_raw, L(F(0.0)), ln.dot(c, c), L(F(1.0)))

    @wp.func
    def ggx_denominator(n_dot_h: L, sin2_nh: L, a2: L):
        """d = alpha^2 (n.h)^2 + |n x h|^2 of D = alpha^2 / (pi d^2); ``n_dot_h`` clamped."""
        return ln.mul(ln.mul(a2, n_dot_h), n_dot_h) + sin2_nh

    @wp.func
    def ggx_ndf(n_dot_h: L, sin2_nh: L, alpha: L):
        """GGX D for clamped n.h and ``sin2_nh`` = ``ggx_sin2(n, h, n.h)``."""
        a2 = ln.mul(alpha, alpha)
        d = ggx_denominator(n_dot_h, sin2_nh, a2)
        return ln.div(a2, ln.mul(d * F(PI), d))

    @wp.func
    def fresnel_weight(v_dot_h: L):
        """w of F = F0 + (1 - F0) w. It depends on the positions only, not on the maps,
        so the map gradient kernels can reuse the forward's (``point_light_radiance``)."""
        return ln.exp2(ln.mul(v_dot_h * F(FRESNEL_A) + L(F(FRESNEL_B)), v_dot_h))

    @wp.func
    def fresnel_schlick_sg(f0: V, w: L):
        return f0 + ln.scale(V(F(1.0)) - f0, w)

    @wp.func
    def smith_schlick_g1_over_c(c: L, k: L):
        # G1(c) / c = 1 / (c (1 - k) + k): the c cancels with the 4 (n.l)(n.v) denominator.
        return ln.div(L(F(1.0)), ln.mul(c, L(F(1.0)) - k) + k)

    @wp.func
    def cook_torrance(n: V, l: V, v: V, rho_d: V, f0: V, rough: L, rough_floor: F):
        """BRDF times cosine, f * (n.l), for unit n, l, v; returns (linear RGB, the
        Fresnel weight w)."""
        zero = L(F(0.0))
        h = safe_normalize(l + v)
        n_dot_l = wp.max(ln.dot(n, l), zero)
        n_dot_v = wp.max(ln.dot(n, v), zero)
        n_dot_h_raw = ln.dot(n, h)
        n_dot_h = wp.max(n_dot_h_raw, zero)
        v_dot_h = wp.max(ln.dot(v, h), zero)
        r = wp.max(rough, L(rough_floor))
        alpha = ln.mul(r, r)
        k = alpha * F(0.5)
        d = ggx_ndf(n_dot_h, ggx_sin2(n, h, n_dot_h_raw), alpha)
        w = fresnel_weight(v_dot_h)
        fr = fresnel_schlick_sg(f0, w)
        vis = ln.mul(smith_schlick_g1_over_c(n_dot_l, k), smith_schlick_g1_over_c(n_dot_v, k)) * F(0.25)
        diffuse = wp.cw_mul(rho_d, V(F(1.0)) - f0) * F(INV_PI)
        return ln.scale(diffuse + ln.scale(fr, ln.mul(d, vis)), n_dot_l), w

    @wp.func
    def load_rgb(a: wp.array4d(dtype=L), b: int, i: int, jq: int):
        """Channels 0-2 of lane group jq of row i of batch item b of a ``[B, C, H, W]``
        array (viewed as ``[B, C, H, W / lanes]`` lane groups)."""
        return ln.vec3(a[b, 0, i, jq], a[b, 1, i, jq], a[b, 2, i, jq])

    @wp.func
    def plane_point(i: int, columns: L, height: int, width: int, plane_size: F):
        """Plane position of the centres of pixels (i, columns) (SPEC section 2; row 0 is +y)."""
        x = ((columns + L(F(0.5))) / F(width) - L(F(0.5))) * plane_size
        y = -((F(i) + F(0.5)) / F(height) - F(0.5)) * plane_size
        return ln.vec3(x, L(y), L(F(0.0)))

    @wp.func
    def load_pixel(
        diffuse: wp.array4d(dtype=L),
        normal: wp.array4d(dtype=L),
        roughness: wp.array4d(dtype=L),
        specular: wp.array4d(dtype=L),
        b: int,
        i: int,
        jq: int,
        width: int,
        plane_size: F,
    ):
        """Lane group jq (pixels (i, jq * lanes + q)) of batch item b, shared by every
        shading kernel: returns (plane points, diffuse, specular, raw normals as stored,
        roughness). ``width``: the image width (the arrays may be padded to whole lane
        groups)."""
        columns = L(F(jq * lanes)) + wp.static(ln.iota)
        p = plane_point(i, columns, diffuse.shape[2], width, plane_size)
        return (
            p,
            load_rgb(diffuse, b, i, jq),
            load_rgb(specular, b, i, jq),
            load_rgb(normal, b, i, jq),
            roughness[b, 0, i, jq],
        )

    @wp.func
    def point_light_radiance(
        p: V,
        light_pos: V3F,
        camera_pos: V3F,
        n: V,
        rho_d: V,
        f0: V,
        rough: L,
        intensity: V3F,
        inverse_square: int,
        rough_floor: F,
    ):
        """Linear radiance leaving plane points p towards the camera, lit by a point light,
        and the Fresnel weight w (``fresnel_weight``)."""
        to_light = ln.from_point(light_pos, p)
        dist2 = ln.dot(to_light, to_light) + L(F(NORMALIZE_EPS))
        l = ln.shrink(to_light, ln.sqrt(dist2))
        v = safe_normalize(ln.from_point(camera_pos, p))
        f_cos, w = cook_torrance(n, l, v, rho_d, f0, rough, rough_floor)
        radiance = ln.tint(f_cos, intensity)
        if inverse_square != 0:
            radiance = ln.shrink(radiance, dist2)
        return radiance, w

    return SimpleNamespace(
        ln=ln,
        L=L,
        V=V,
        V3=V3F,
        lanes=lanes,
        load_position=shared.load_position,
        plane_point=plane_point,
        load_rgb=load_rgb,
        load_pixel=load_pixel,
        point_light_radiance=point_light_radiance,
        safe_normalize=safe_normalize,
        ggx_sin2=ggx_sin2,
        ggx_denominator=ggx_denominator,
        ggx_ndf=ggx_ndf,
        fresnel_weight=fresnel_weight,
        fresnel_schlick_sg=fresnel_schlick_sg,
        smith_schlick_g1_over_c=smith_schlick_g1_over_c,
        cook_torrance=cook_torrance,
    )


@cache
def _position_funcs(F) -> SimpleNamespace:
    """Lane-independent functions, defined once per scalar type (every lane build shares
    them: Warp tells functions of one name apart by argument types only)."""
    V3F = wp.types.vector(3, F)

    @wp.func
    def load_position(a: wp.array3d(dtype=F), b: int, k: int):
        """Position k of batch item b of a ``[B, K, 3]`` array."""
        return V3F(a[b, k, 0], a[b, k, 1], a[b, k, 2])

    return SimpleNamespace(load_position=load_position)
