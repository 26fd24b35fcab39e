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
def build_brdf_grad(F) -> SimpleNamespace:
    """Warp functions of the map gradients for scalar type ``F``."""
    brdf = build_brdf(F)
    V3 = brdf.V3

    @wp.func
    def pass_mask(x: F):
        # 1 where clamp_min(x, 0) passes gradient (x >= 0), else 0.
        return wp.where(x >= F(0.0), F(1.0), F(0.0))

    @wp.func
    def log_l1_cotangent(x: F, y: F, eps: F, g: F):
        # d/dx of g |log(x + eps) - log(y + eps)|, with sign(0) = 0 as in torch. log is
        # increasing, so the sign of the log difference is that of x - y: no log needed.
        diff = x - y
        sign = wp.where(diff > F(0.0), F(1.0), wp.where(diff < F(0.0), F(-1.0), F(0.0)))
        return g * sign / (x + eps)

    @wp.func
    def radiance_and_map_grads(
        p: V3,
        light_pos: V3,
        camera_pos: V3,
        n: V3,
        rho_d: V3,
        f0: V3,
        rough: F,
        intensity: V3,
        inverse_square: int,
        rough_floor: F,
        w: F,
        u: V3,
        log_l1: int,
        target: V3,
        eps: F,
    ):
        """Map gradients of one light's radiance at one pixel, for unit normal ``n``.

        The cotangent of the radiance is ``u`` (``log_l1`` = 0), or, for the fused
        rendering loss (``log_l1`` = 1), that of ``u[0] * sum_c |log(x_c + eps) -
        log(target_c + eps)|``, formed here from the radiance x computed on the way.
        ``w``: the Fresnel weight the forward pass computed (``brdf.fresnel_weight``;
        positions only, so reused rather than recomputed: exp2 was ~15% of this function).
        Returns (radiance, dL/d rho_d, dL/d F0, dL/d roughness, dL/d n)."""
        to_light = light_pos - p
        dist2 = wp.dot(to_light, to_light) + F(NORMALIZE_EPS)
        l = to_light / wp.sqrt(dist2)
        v = brdf.safe_normalize(camera_pos - p)
        h = brdf.safe_normalize(l + v)
        ndl_raw = wp.dot(n, l)
        ndv_raw = wp.dot(n, v)
        ndh_raw = wp.dot(n, h)
        ndl = wp.max(ndl_raw, F(0.0))
        ndv = wp.max(ndv_raw, F(0.0))
        ndh = wp.max(ndh_raw, F(0.0))
        sin2 = brdf.ggx_sin2(n, h, ndh_raw)
        r = wp.max(rough, rough_floor)
        alpha = r * r
        k = alpha * F(0.5)
        a2 = alpha * alpha
        dd = brdf.ggx_denominator(ndh, sin2, a2)
        d = a2 / (F(PI) * dd * dd)
        one = V3(F(1.0), F(1.0), F(1.0))
        fr = f0 + (one - f0) * w
        big_a = ndl * (F(1.0) - k) + k
        big_b = ndv * (F(1.0) - k) + k
        # Reciprocals computed once and reused below (divisions dominate this function).
        inv_a = F(1.0) / big_a
        inv_b = F(1.0) / big_b
        vis = inv_a * inv_b * F(0.25)
        dv = d * vis
        diffuse = wp.cw_mul(rho_d, one - f0) * F(INV_PI)
        # Same expression order as brdf.point_light_radiance: the fused loss's gradient
        # sees the very radiance its forward pass saw.
        radiance = wp.cw_mul((diffuse + fr * dv) * ndl, intensity)
        sc = F(1.0)
        if inverse_square != 0:
            radiance = radiance / dist2
            sc = F(1.0) / dist2
        cot = u
        if log_l1 != 0:
            cot = V3(
                log_l1_cotangent(radiance[0], target[0], eps, u[0]),
                log_l1_cotangent(radiance[1], target[1], eps, u[0]),
                log_l1_cotangent(radiance[2], target[2], eps, u[0]),
            )
        us = wp.cw_mul(cot, intensity) * sc
        g_rho = wp.cw_mul(us, one - f0) * (ndl * F(INV_PI))
        g_f0 = wp.cw_mul(us, rho_d * F(-INV_PI) + (one - V3(w, w, w)) * dv) * ndl
        g_dv = ndl * wp.dot(us, fr)
        g_d = g_dv * vis
        g_vis = g_dv * d
        g_vis_vis = g_vis * vis
        g_ndl = (wp.dot(us, diffuse + fr * dv) - g_vis_vis * (F(1.0) - k) * inv_a) * pass_mask(ndl_raw)
        g_ndv = -g_vis_vis * (F(1.0) - k) * inv_b * pass_mask(ndv_raw)
        inv_dd3 = F(1.0) / (F(PI) * dd * dd * dd)
        # dD/dd = -2 a2 / (pi d^3), times the two parts of dd/dn (docstring); zero where
        # n.h <= 0 (d = 1 there).
        g_dd = g_d * F(-2.0) * a2 * inv_dd3 * wp.where(ndh_raw > F(0.0), F(1.0), F(0.0))
        g_ndh = g_dd * F(2.0) * ndh * (a2 - F(1.0))
        g_radial = g_dd * F(2.0) * wp.dot(h, h)
        # d - 2 a2 (n.h)^2 written as |n x h|^2 - a2 (n.h)^2: no cancellation against 1.
        g_alpha = g_d * F(2.0) * alpha * (sin2 - a2 * ndh * ndh) * inv_dd3
        g_alpha -= g_vis_vis * ((F(1.0) - ndl) * inv_a + (F(1.0) - ndv) * inv_b) * F(0.5)
        g_rough = g_alpha * F(2.0) * r * wp.where(rough >= rough_floor, F(1.0), F(0.0))
        # (v.h, hence w, depends on the positions only: no map gradient flows through it.)
        g_n = l * g_ndl + v * g_ndv + h * g_ndh + n * g_radial
        return radiance, g_rho, g_f0, g_rough, g_n

    @wp.func
    def normalize_grad(m: V3, g_n: V3):
        """Gradient w.r.t. the raw normal m of a gradient w.r.t. n = m / sqrt(m.m + eps)."""
        r = wp.sqrt(wp.dot(m, m) + F(NORMALIZE_EPS))
        n = m / r
        return (g_n - n * wp.dot(n, g_n)) / r

    return SimpleNamespace(V3=V3, radiance_and_map_grads=radiance_and_map_grads, normalize_grad=normalize_grad)
