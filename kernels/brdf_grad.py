"""Hand-written adjoint of ``brdf.point_light_radiance`` with respect to the maps.

Warp's generated adjoint of the render kernel replays the K-light loop, keeps every
intermediate and accumulates the light/camera gradients with one atomic add per pixel
and light; on the CPU that made forward+backward barely faster than eager torch. Most
callers (training, refinement) want gradients to the four maps only: this function gives
them in closed form, one thread per pixel, no atomics. The generated adjoint stays the
path whenever light or camera positions need gradients (``kernels._autograd``).

Derivatives (notation of ``kernels.brdf``; u = dL/d radiance, s = 1/dist^2 or 1,
us = u * intensity * s, D v = D * vis, w = 2^((a v.h + b) v.h)):

    radiance = (rho_d (1 - F0) / pi + F D v) (n.l) intensity s,   F = F0 + (1 - F0) w
    dL/d rho_d = us (1 - F0) (n.l) / pi
    dL/d F0    = us (-rho_d / pi + (1 - w) D v) (n.l)
    dL/d(D v)  = (n.l) sum_c us_c F_c
    dD/dn      = -2 a2 / (pi d^3) dd/dn,  dd/dn = 2 (a2 - 1) (n.h) h + 2 |h|^2 n
    dD/d alpha = 2 alpha (|n x h|^2 - a2 (n.h)^2) / (pi d^3)
    dvis/d(n.l) = -vis (1 - k) / A,  dvis/dk = -vis ((1 - n.l) / A + (1 - n.v) / B)
    with d = a2 (n.h)^2 + |n x h|^2 (``brdf.ggx_denominator``), A = (n.l)(1 - k) + k,
    B = (n.v)(1 - k) + k, k = alpha / 2. The |h|^2 n term of dd/dn (from |n x h|^2) is
    along n, so the normalisation's projection (``normalize_grad``) removes it up to the
    1e-12 epsilon; it is kept so that the gradient is that of what the forward computes.
    Where n.h <= 0, d = 1 and D passes no gradient.

Clamped dot products and the roughness floor pass gradient where the input is at or
above the bound, as torch's ``clamp_min`` does (``kernels.reference``).
"""

from functools import cache
from types import SimpleNamespace

import warp as wp

from kernels.brdf import INV_PI, NORMALIZE_EPS, PI, build_brdf

__all__ = ["build_brdf_grad"]


@cache
def build_brdf_grad(F, lanes: int = 1) -> SimpleNamespace:
    """Warp functions of the map gradients for scalar type ``F`` and ``lanes`` pixels per
    thread (``kernels.lanes``; same expressions for every lane count)."""
    brdf = build_brdf(F, lanes)
    ln = brdf.ln
    L, V, V3F = ln.L, ln.V, ln.V3F

    @wp.func
    def pass_mask(x: L):
        # 1 where clamp_min(x, 0) passes gradient (x >= 0), else 0.
        return ln.select_ge(x, L(F(0.0)), L(F(1.0)), L(F(0.0)))

    @wp.func
    def log_l1_cotangent(x: L, y: L, eps: F, g: L):
        # d/dx of g |log(x + eps) - log(y + eps)|, with sign(0) = 0 as in torch. log is
        # increasing, so the sign of the log difference is that of x - y: no log needed.
        zero = L(F(0.0))
        one = L(F(1.0))
        sign = ln.select_gt(x, y, one, zero) - ln.select_gt(y, x, one, zero)
        return ln.div(ln.mul(g, sign), x + L(eps))

    @wp.func
    def radiance_and_map_grads(
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
        w: L,
        u: V,
        log_l1: int,
        target: V,
        eps: F,
    ):
        """Map gradients of one light's radiance at one pixel (lane group), for unit
        normal ``n``.

        The cotangent of the radiance is ``u`` (``log_l1`` = 0), or, for the fused
        rendering loss (``log_l1`` = 1), that of ``u[0] * sum_c |log(x_c + eps) -
        log(target_c + eps)|``, formed here from the radiance x computed on the way.
        ``w``: the Fresnel weight the forward pass computed (``brdf.fresnel_weight``;
        positions only, so reused rather than recomputed: exp2 was ~15% of this function).
        Returns (radiance, dL/d rho_d, dL/d F0, dL/d roughness, dL/d n)."""
        zero = L(F(0.0))
        one_l = L(F(1.0))
        to_light = ln.from_point(light_pos, p)
        dist2 = ln.dot(to_light, to_light) + L(F(NORMALIZE_EPS))
        l = ln.shrink(to_light, ln.sqrt(dist2))
        v = brdf.safe_normalize(ln.from_point(camera_pos, p))
        h = brdf.safe_normalize(l + v)
        ndl_raw = ln.dot(n, l)
        ndv_raw = ln.dot(n, v)
        ndh_raw = ln.dot(n, h)
        ndl = wp.max(ndl_raw, zero)
        ndv = wp.max(ndv_raw, zero)
        ndh = wp.max(ndh_raw, zero)
        sin2 = brdf.ggx_sin2(n, h, ndh_raw)
        r = wp.max(rough, L(rough_floor))
        alpha = ln.mul(r, r)
        k = alpha * F(0.5)
        a2 = ln.mul(alpha, alpha)
        dd = brdf.ggx_denominator(ndh, sin2, a2)
        d = ln.div(a2, ln.mul(dd * F(PI), dd))
        one = V(F(1.0))
        fr = f0 + ln.scale(one - f0, w)
        big_a = ln.mul(ndl, one_l - k) + k
        big_b = ln.mul(ndv, one_l - k) + k
        # Reciprocals computed once and reused below (divisions dominate this function).
        inv_a = ln.div(one_l, big_a)
        inv_b = ln.div(one_l, big_b)
        vis = ln.mul(inv_a, inv_b) * F(0.25)
        dv = ln.mul(d, vis)
        diffuse = wp.cw_mul(rho_d, one - f0) * F(INV_PI)
        # Same expression order as brdf.point_light_radiance: the fused loss's gradient
        # sees the very radiance its forward pass saw.
        radiance = ln.tint(ln.scale(diffuse + ln.scale(fr, dv), ndl), intensity)
        sc = one_l
        if inverse_square != 0:
            radiance = ln.shrink(radiance, dist2)
            sc = ln.div(one_l, dist2)
        cot = u
        if log_l1 != 0:
            cot = ln.vec3(
                log_l1_cotangent(radiance[0], target[0], eps, u[0]),
                log_l1_cotangent(radiance[1], target[1], eps, u[0]),
                log_l1_cotangent(radiance[2], target[2], eps, u[0]),
            )
        us = ln.scale(ln.tint(cot, intensity), sc)
        g_rho = ln.scale(wp.cw_mul(us, one - f0), ndl * F(INV_PI))
        g_f0 = ln.scale(wp.cw_mul(us, rho_d * F(-INV_PI) + ln.scale(one - ln.vec3(w, w, w), dv)), ndl)
        g_dv = ln.mul(ndl, ln.dot(us, fr))
        g_d = ln.mul(g_dv, vis)
        g_vis = ln.mul(g_dv, d)
        g_vis_vis = ln.mul(g_vis, vis)
        g_ndl = ln.mul(
            ln.dot(us, diffuse + ln.scale(fr, dv)) - ln.mul(ln.mul(g_vis_vis, one_l - k), inv_a), pass_mask(ndl_raw)
        )
        g_ndv = ln.mul(ln.mul(ln.mul(-g_vis_vis, one_l - k), inv_b), pass_mask(ndv_raw))
        inv_dd3 = ln.div(one_l, ln.mul(ln.mul(dd * F(PI), dd), dd))
        # dD/dd = -2 a2 / (pi d^3), times the two parts of dd/dn (docstring); zero where
        # n.h <= 0 (d = 1 there).
        g_dd = ln.mul(ln.mul(g_d * F(-2.0), a2), inv_dd3)
        g_dd = ln.select_gt(ndh_raw, zero, g_dd, zero)
        g_ndh = ln.mul(ln.mul(g_dd * F(2.0), ndh), a2 - one_l)
        g_radial = ln.mul(g_dd * F(2.0), ln.dot(h, h))
        # d - 2 a2 (n.h)^2 written as |n x h|^2 - a2 (n.h)^2: no cancellation against 1.
        g_alpha = ln.mul(ln.mul(ln.mul(g_d * F(2.0), alpha), sin2 - ln.mul(ln.mul(a2, ndh), ndh)), inv_dd3)
        g_alpha -= ln.mul(g_vis_vis, ln.mul(one_l - ndl, inv_a) + ln.mul(one_l - ndv, inv_b)) * F(0.5)
        g_rough = ln.mul(g_alpha * F(2.0), r)
        g_rough = ln.select_ge(rough, L(rough_floor), g_rough, zero)
        # (v.h, hence w, depends on the positions only: no map gradient flows through it.)
        g_n = ln.scale(l, g_ndl) + ln.scale(v, g_ndv) + ln.scale(h, g_ndh) + ln.scale(n, g_radial)
        return radiance, g_rho, g_f0, g_rough, g_n

    @wp.func
    def normalize_grad(m: V, g_n: V):
        """Gradient w.r.t. the raw normal m of a gradient w.r.t. n = m / sqrt(m.m + eps)."""
        r = ln.sqrt(ln.dot(m, m) + L(F(NORMALIZE_EPS)))
        n = ln.shrink(m, r)
        return ln.shrink(g_n - ln.scale(n, ln.dot(n, g_n)), r)

    return SimpleNamespace(V3=V3F, radiance_and_map_grads=radiance_and_map_grads, normalize_grad=normalize_grad)
