"""Warp launch shells for feature translation and image losses.

Losses are reduced in two stages: one thread per row accumulates its row in a local
float64 variable and writes one partial sum; torch then sums the partials in float64. A
single float32 atomic accumulator over millions of elements loses about 1% (measured
here); a float32 row accumulator still loses ~4e-6 relative over 1024-element rows.
"""

from functools import cache
from types import SimpleNamespace

import warp as wp

from kernels.brdf import build_brdf

__all__ = ["build_image_kernels"]


@cache
def build_image_kernels(F) -> SimpleNamespace:
    """Translation and loss kernels for scalar type ``F`` (wp.float32 or wp.float64)."""
    brdf = build_brdf(F)
    V3 = brdf.V3
    module = f"dgrsise_image_{wp.types.type_repr(F)}"

    @wp.kernel(module=module)
    def translate_kernel(
        features: wp.array4d(dtype=F),
        offsets: wp.array2d(dtype=F),
        b_offset: int,
        out: wp.array4d(dtype=F),
    ):
        # out(i, j) = features(i - dy, j - dx), bilinear; samples outside the map take
        # the nearest edge value (clamped coordinates), as SPEC section 3 asks.
        bb, i, j = wp.tid()
        b = bb + b_offset
        height = features.shape[2]
        width = features.shape[3]
        sx = wp.clamp(F(j) - offsets[b, 0], F(0.0), F(width - 1))
        sy = wp.clamp(F(i) - offsets[b, 1], F(0.0), F(height - 1))
        x0 = wp.min(int(wp.floor(sx)), width - 1)
        y0 = wp.min(int(wp.floor(sy)), height - 1)
        x1 = wp.min(x0 + 1, width - 1)
        y1 = wp.min(y0 + 1, height - 1)
        fx = sx - F(x0)
        fy = sy - F(y0)
        for c in range(features.shape[1]):
            top = (F(1.0) - fx) * features[b, c, y0, x0] + fx * features[b, c, y0, x1]
            bottom = (F(1.0) - fx) * features[b, c, y1, x0] + fx * features[b, c, y1, x1]
            out[b, c, i, j] = (F(1.0) - fy) * top + fy * bottom

    @wp.kernel(module=module)
    def log_l1_rows_kernel(
        x: wp.array2d(dtype=F), y: wp.array2d(dtype=F), eps: F, r_offset: int, partial: wp.array1d(dtype=F)
    ):
        r = wp.tid() + r_offset
        s = wp.float64(0.0)  # float64 row accumulator: see the module docstring
        for c in range(x.shape[1]):
            s += wp.float64(wp.abs(wp.log(x[r, c] + eps) - wp.log(y[r, c] + eps)))
        partial[r] = F(s)

    @wp.kernel(module=module)
    def mse_rows_kernel(x: wp.array2d(dtype=F), y: wp.array2d(dtype=F), r_offset: int, partial: wp.array1d(dtype=F)):
        r = wp.tid() + r_offset
        s = wp.float64(0.0)  # float64 row accumulator: see the module docstring
        for c in range(x.shape[1]):
            d = x[r, c] - y[r, c]
            s += wp.float64(d * d)
        partial[r] = F(s)

    return SimpleNamespace(
        V3=V3,
        translate=translate_kernel,
        log_l1_rows=log_l1_rows_kernel,
        mse_rows=mse_rows_kernel,
        render_log_l1=build_render_log_l1_kernel(F, 1),
    )


@cache
def build_render_log_l1_kernel(F, lanes: int):
    """The fused rendering log-L1 kernel for scalar type ``F`` and ``lanes`` pixels per
    thread (``kernels.lanes``; forward-only for ``lanes`` > 1, as the render kernel)."""
    brdf = build_brdf(F, lanes)
    ln = brdf.ln
    V3, L = brdf.V3, brdf.L
    module = f"dgrsise_image_{wp.types.type_repr(F)}" + (f"_x{lanes}" if lanes > 1 else "")

    @wp.kernel(module=module, enable_backward=lanes == 1)
    def render_log_l1_kernel(
        diffuse: wp.array4d(dtype=L),
        normal: wp.array4d(dtype=L),
        roughness: wp.array4d(dtype=L),
        specular: wp.array4d(dtype=L),
        light: wp.array3d(dtype=F),
        camera: wp.array3d(dtype=F),
        intensity: V3,
        plane_size: F,
        inverse_square: int,
        rough_floor: F,
        width: int,
        b_offset: int,
        row_offset: int,
        target: wp.array4d(dtype=L),
        eps: F,
        store_fresnel: int,
        partial: wp.array3d(dtype=L),
        fresnel: wp.array3d(dtype=L),
    ):
        # Renders pixel (b, i, j) under the K lights and sums |log(x + eps) - log(y + eps)|
        # over lights and channels without storing the rendering (fused: no [B,K,3,H,W]);
        # fresnel: as in the render kernel.
        bb, ii, jq = wp.tid()
        b = bb + b_offset
        i = ii + row_offset
        num_lights = light.shape[1]
        p, rho_d, f0, m, rough = brdf.load_pixel(diffuse, normal, roughness, specular, b, i, jq, width, plane_size)
        n = brdf.safe_normalize(m)
        s = L(F(0.0))
        for k in range(num_lights):
            radiance, w = brdf.point_light_radiance(
                p,
                brdf.load_position(light, b, k),
                brdf.load_position(camera, b, k),
                n,
                rho_d,
                f0,
                rough,
                intensity,
                inverse_square,
                rough_floor,
            )
            row = b * num_lights + k
            if store_fresnel != 0:
                fresnel[row, i, jq] = w
            # sum_c |log(x_c + eps) - log(y_c + eps)| = log(prod_c max_c / prod_c min_c)
            # of a_c = x_c + eps, t_c = y_c + eps (|log(a / t)| = log(max / min)): one log
            # and one division per light instead of three each (the logs were the
            # costliest operations here). a_c, t_c > 0 are within [~1e-7, ~1e4], so the
            # products of three stay far from float32's range limits; the rounding of the
            # extra products is ~4 ulps of the log's argument, i.e. ~4u absolute on the
            # sum of three terms. On ties (a_c = t_c) max and min both pick t_c (the
            # second argument), so the generated adjoint passes x_c no gradient there, as
            # the twin's |.| does.
            num = L(F(1.0))
            den = L(F(1.0))
            for c in range(3):
                a = radiance[c] + L(eps)
                t = target[row, c, i, jq] + L(eps)
                num = ln.mul(num, wp.max(a, t))
                den = ln.mul(den, wp.min(a, t))
            s += ln.log(ln.div(num, den))
        partial[b, i, jq] = s

    return render_log_l1_kernel
