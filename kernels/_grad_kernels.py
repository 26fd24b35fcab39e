"""Warp launch shells of the hand-written map gradients (``kernels.brdf_grad``).

Same launch geometry and argument prefix as the forward shading kernels (one thread per
pixel (b, i, j), K lights in a loop, ``b_offset`` / ``row_offset`` chunks), so
``kernels._autograd`` launches them with the same chunked launcher. Every thread owns
its pixel of the four gradient maps: plain writes, no atomics. They are never
differentiated, so Warp generates no adjoint for them (less to compile). Built per lane
count like the render kernels (``kernels.lanes``).
"""

from functools import cache
from types import SimpleNamespace

import warp as wp

from kernels.brdf import build_brdf
from kernels.brdf_grad import build_brdf_grad

__all__ = ["build_grad_kernels"]


@cache
def build_grad_kernels(F, lanes: int = 1) -> SimpleNamespace:
    """Map-gradient kernels for scalar type ``F`` (wp.float32 or wp.float64) and ``lanes``
    pixels per thread."""
    brdf = build_brdf(F, lanes)
    grad = build_brdf_grad(F, lanes)
    V3, L, V = brdf.V3, brdf.L, brdf.V
    module = f"dgrsise_grad_{wp.types.type_repr(F)}" + (f"_x{lanes}" if lanes > 1 else "")

    @wp.func
    def store_grads(
        b: int,
        i: int,
        jq: int,
        m: V,
        g_rho: V,
        g_f0: V,
        g_rough: L,
        g_n: V,
        g_diffuse: wp.array4d(dtype=L),
        g_normal: wp.array4d(dtype=L),
        g_roughness: wp.array4d(dtype=L),
        g_specular: wp.array4d(dtype=L),
    ):
        g_m = grad.normalize_grad(m, g_n)
        for c in range(3):
            g_diffuse[b, c, i, jq] = g_rho[c]
            g_specular[b, c, i, jq] = g_f0[c]
            g_normal[b, c, i, jq] = g_m[c]
        g_roughness[b, 0, i, jq] = g_rough

    @wp.kernel(module=module, enable_backward=False)
    def render_maps_grad(
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
        fresnel: wp.array3d(dtype=L),
        grad_out: wp.array4d(dtype=L),
        g_diffuse: wp.array4d(dtype=L),
        g_normal: wp.array4d(dtype=L),
        g_roughness: wp.array4d(dtype=L),
        g_specular: wp.array4d(dtype=L),
    ):
        # grad_out: [B*K, 3, H, W] cotangent of the rendering; fresnel: [B*K, H, W] the
        # forward's Fresnel weights.
        bb, ii, jq = wp.tid()
        b = bb + b_offset
        i = ii + row_offset
        num_lights = light.shape[1]
        p, rho_d, f0, m, rough = brdf.load_pixel(diffuse, normal, roughness, specular, b, i, jq, width, plane_size)
        n = brdf.safe_normalize(m)
        zero = V(F(0.0))
        g_rho = zero
        g_f0 = zero
        g_n = zero
        g_rough = L(F(0.0))
        for k in range(num_lights):
            row = b * num_lights + k
            u = brdf.load_rgb(grad_out, row, i, jq)
            radiance, a_rho, a_f0, a_rough, a_n = grad.radiance_and_map_grads(
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
                fresnel[row, i, jq],
                u,
                0,
                zero,
                F(0.0),
            )
            g_rho += a_rho
            g_f0 += a_f0
            g_rough += a_rough
            g_n += a_n
        store_grads(b, i, jq, m, g_rho, g_f0, g_rough, g_n, g_diffuse, g_normal, g_roughness, g_specular)

    @wp.kernel(module=module, enable_backward=False)
    def render_log_l1_maps_grad(
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
        fresnel: wp.array3d(dtype=L),
        grad_partial: wp.array3d(dtype=L),
        g_diffuse: wp.array4d(dtype=L),
        g_normal: wp.array4d(dtype=L),
        g_roughness: wp.array4d(dtype=L),
        g_specular: wp.array4d(dtype=L),
    ):
        # grad_partial: [B, H, W] cotangent g of the per-pixel loss sums; the radiance's
        # own cotangent is formed inside radiance_and_map_grads from the recomputed
        # radiance (the forward pass is fused: nothing was stored).
        bb, ii, jq = wp.tid()
        b = bb + b_offset
        i = ii + row_offset
        num_lights = light.shape[1]
        p, rho_d, f0, m, rough = brdf.load_pixel(diffuse, normal, roughness, specular, b, i, jq, width, plane_size)
        n = brdf.safe_normalize(m)
        g = grad_partial[b, i, jq]
        zero = V(F(0.0))
        g_rho = zero
        g_f0 = zero
        g_n = zero
        g_rough = L(F(0.0))
        for k in range(num_lights):
            row = b * num_lights + k
            radiance, a_rho, a_f0, a_rough, a_n = grad.radiance_and_map_grads(
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
                fresnel[row, i, jq],
                brdf.ln.vec3(g, L(F(0.0)), L(F(0.0))),
                1,
                brdf.load_rgb(target, row, i, jq),
                eps,
            )
            g_rho += a_rho
            g_f0 += a_f0
            g_rough += a_rough
            g_n += a_n
        store_grads(b, i, jq, m, g_rho, g_f0, g_rough, g_n, g_diffuse, g_normal, g_roughness, g_specular)

    return SimpleNamespace(render=render_maps_grad, loss=render_log_l1_maps_grad)
