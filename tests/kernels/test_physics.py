"""Physics of the rendering kernel, after mitsuba3's BRDF tests: finite and non-negative at
grazing angles and extreme roughness, reciprocity, GGX normalisation, F(0) = F0 (up to
the spherical-Gaussian Fresnel's residual), energy at most 1, batched equals looped,
determinism.

Several tests turn the kernel into a BRDF probe: a 1x1 image puts its only pixel at the
plane's centre (the origin), so a light or camera at R * d, with inverse_square off and
intensity 1, gives exactly the direction d; the kernel's output is then f * (n.l).
"""

from __future__ import annotations

import math

import pytest
import torch

import kernels
from kernels import reference
from kernels.brdf import FRESNEL_A, FRESNEL_B, NORMALIZE_EPS

#: Reciprocity and closed-form checks in float64: rounding of the same expressions, plus
#: the 1e-12 epsilon under the normalising square roots (relative ~1e-14 at |x| ~ 4).
PHYS_RTOL_F64 = 1e-10
#: Schlick's Fresnel with the spherical-Gaussian exponent (SPEC section 2) is not exactly
#: F0 at normal incidence: F(v.h = 1) = F0 + (1 - F0) 2^(FRESNEL_A + FRESNEL_B), a
#: residual of 1.7e-4 (1 - F0) that the approximation carries by design (Karis 2013).
FRESNEL_NORMAL_RESIDUAL = 2.0 ** (FRESNEL_A + FRESNEL_B)
#: GGX normalisation int D(h) (n.h) dw_h = 1 by the trapezoid rule in s = sin^2(theta_h)
#: on 4,000 log-spaced nodes: measured error <= 6e-6 for roughness in [0.15, 1].
NDF_QUAD_TOL = 1e-4
#: Directional albedo by the midpoint rule on a 128 x 256 (theta, phi) grid over the
#: light hemisphere: differs from a 512 x 1024 grid by <= 4e-4 for roughness >= 0.3.
ENERGY_QUAD_TOL = 2e-3
#: Distance of the probe's lights and cameras from the pixel at the origin: any distance
#: gives the direction exactly; at 1e4 the 1e-12 NORMALIZE_EPS under the square root
#: (against |x|^2 = 1e8) is below float64 resolution, so l and v are exactly unit.
FAR = 1.0e4
#: Batched vs looped position gradients, float32, relative to the largest entry: row-split
#: chunks of a B=1 launch sum their partial light/camera gradients (n = H*W = 72 terms
#: here) in another order than one batch-split launch. Each order errs by <= (n - 1) u
#: sum |t_i|, and sum |t_i| ~ sqrt(n) |sum t_i| with random-sign cotangents (conftest's
#: VJP model): the two within 2 n^1.5 u = 7.3e-5.
SUM_ORDER_RTOL_F32 = 2 * (9 * 8) ** 1.5 * 2.0**-24


def _probe_maps(roughness: float, f0: float = 1.0, diffuse: float = 0.0, dtype=torch.float64):
    """One flat pixel (n = +z) with uniform maps."""
    n = torch.zeros(1, 3, 1, 1, dtype=dtype)
    n[:, 2] = 1
    return (
        torch.full((1, 3, 1, 1), diffuse, dtype=dtype),
        n,
        torch.full((1, 1, 1, 1), roughness, dtype=dtype),
        torch.full((1, 3, 1, 1), f0, dtype=dtype),
    )


def _direction(theta_deg: float, phi_deg: float = 0.0) -> torch.Tensor:
    t, p = math.radians(theta_deg), math.radians(phi_deg)
    return torch.tensor([math.sin(t) * math.cos(p), math.sin(t) * math.sin(p), math.cos(t)], dtype=torch.float64)


# --------------------------------------------------------------------------- robustness
@pytest.mark.parametrize("preset", ["dgrsise", "materialgan"])
def test_finite_and_non_negative_at_grazing_angles_and_extreme_roughness(preset, dtype, make_maps):
    b, h, w = 4, 5, 6
    maps = make_maps(b, h, w, dtype=dtype)
    rough = maps[2].detach().clone()
    rough[0], rough[1] = 0.0, 1.0  # below the floor (clamped) and the top of the range
    rough[2, :, ::2] = kernels.get_preset(preset).roughness_floor  # exactly at the floor
    maps[2] = rough
    maps[1][3] = torch.tensor([1.0, 0.0, 0.0], dtype=dtype)[:, None, None]  # normals in the plane
    maps = [m.requires_grad_() for m in maps]
    light = torch.tensor(
        [[1e3, 0.0, 1e-3], [0.0, -1e3, 1e-3], [2.0, 2.0, 1e-3], [0.0, 0.0, 4.0]], dtype=dtype, requires_grad=True
    )
    camera = torch.tensor(
        [[-1e3, 5.0, 1e-3], [1e3, 0.0, 1e-3], [0.0, 0.0, 4.0], [3.0, -1.0, 1e-3]], dtype=dtype, requires_grad=True
    )
    out = kernels.render(*maps, light, camera, preset=preset)
    assert bool(torch.isfinite(out).all()) and bool((out >= 0).all())
    assert float(out.detach().max()) > 0
    grads = torch.autograd.grad(out.sum(), [*maps, light, camera])
    for name, g in zip(("diffuse", "normal", "roughness", "specular", "light_pos", "camera_pos"), grads):
        assert bool(torch.isfinite(g).all()), name


def test_light_below_the_surface_gives_zero():
    maps = _probe_maps(0.5, f0=0.5, diffuse=0.8)
    out = kernels.render(
        *maps, torch.tensor([[0.0, 0.0, -4.0]], dtype=torch.float64), torch.tensor([0.0, 0.0, 4.0], dtype=torch.float64)
    )
    assert float(out.abs().max()) == 0.0


# --------------------------------------------------------------------------- reciprocity
def test_reciprocity_of_the_kernel(make_maps, make_positions):
    """f(l, v) = f(v, l): radiance / (n.l I) is unchanged when light and camera swap."""
    dtype = torch.float64
    maps = make_maps(2, 6, 7, dtype=dtype, seed=3)
    light = make_positions((2, 3), dtype=dtype, seed=4)
    camera = make_positions((2, 3), dtype=dtype, seed=5)
    out = kernels.render(*maps, light, camera)
    swapped = kernels.render(*maps, camera, light)
    lvh = kernels.lvh_maps(light, camera, (6, 7))
    n = (maps[1] / maps[1].norm(dim=1, keepdim=True))[:, None]  # [B, 1, 3, H, W]
    n_dot_l = (n * lvh[:, :, 0:3]).sum(2, keepdim=True)
    n_dot_v = (n * lvh[:, :, 3:6]).sum(2, keepdim=True)
    lit = ((n_dot_l > 0.05) & (n_dot_v > 0.05)).expand_as(out)  # away from the n.l = 0 clamp
    assert float(lit.double().mean()) > 0.9
    intensity = kernels.get_preset("dgrsise").intensity[0]
    f = out / (n_dot_l * intensity)
    f_swapped = swapped / (n_dot_v * intensity)
    torch.testing.assert_close(f[lit], f_swapped[lit], rtol=PHYS_RTOL_F64, atol=0)


def test_reciprocity_of_the_reference_brdf():
    g = torch.Generator().manual_seed(0)
    m = 4096

    def unit_upper(k):
        x = torch.randn(3, k, generator=g, dtype=torch.float64)
        x[2] = x[2].abs() + 0.2
        return x / x.norm(dim=0, keepdim=True)

    n, l, v = unit_upper(m), unit_upper(m), unit_upper(m)
    rho, f0 = torch.rand(3, m, generator=g, dtype=torch.float64), torch.rand(3, m, generator=g, dtype=torch.float64)
    rough = 0.15 + 0.85 * torch.rand(1, m, generator=g, dtype=torch.float64)
    n_dot_l, n_dot_v = (n * l).sum(0), (n * v).sum(0)
    keep = (n_dot_l > 0.05) & (n_dot_v > 0.05)
    args = [t[:, None] for t in (n, l, v, rho, f0, rough)]  # vectors on dim -3: [3, 1, m]
    f_lv = reference.cook_torrance(*args, 0.0993)[:, 0] / n_dot_l
    args[1], args[2] = args[2], args[1]
    f_vl = reference.cook_torrance(*args, 0.0993)[:, 0] / n_dot_v
    torch.testing.assert_close(f_lv[:, keep], f_vl[:, keep], rtol=PHYS_RTOL_F64, atol=0)


# --------------------------------------------------------------------------- Fresnel, NDF
@pytest.mark.parametrize("roughness", [0.3, 0.5, 1.0])
@pytest.mark.parametrize("f0,diffuse", [(0.0, 0.0), (0.04, 0.0), (0.5, 0.7), (1.0, 0.3)])
def test_normal_incidence_gives_f0(roughness, f0, diffuse):
    """Light = camera straight above the pixel: n = l = v = h, so D = 1 / (pi alpha^2),
    the visibility term is 1/4 and F(v.h = 1) = F0 up to the SG approximation's residual.

    The kernel normalises n, l, v and h as x / sqrt(|x|^2 + NORMALIZE_EPS); at this
    configuration that moves n.h off 1 by ~6e-13, so the closed form below applies the
    same normalisation to the scalars along z before evaluating D, F and the visibility of
    SPEC section 2. D's denominator is alpha^2 (n.h)^2 + |n x h|^2 as in ``kernels.brdf``,
    with n x h = 0 here (both along z): the textbook (n.h)^2 (alpha^2 - 1) + 1 would count
    the epsilon's 1 - (n.h)^2 ~ 1e-12 as a tilt and amplify it by 2 / alpha^2."""
    maps = _probe_maps(roughness, f0=f0, diffuse=diffuse)
    z = 4.0
    above = torch.tensor([[0.0, 0.0, z]], dtype=torch.float64)
    out = float(kernels.render(*maps, above, above[0], intensity=1.0)[0, 0, 0, 0, 0])

    def unit(x):  # z component of the kernel's safe_normalize of (0, 0, x)
        return x / math.sqrt(x * x + NORMALIZE_EPS)

    n_z = unit(1.0)
    l_z = z / math.sqrt(z * z + NORMALIZE_EPS)
    h_z = unit(2 * l_z)
    n_dot_h, n_dot_l, v_dot_h = n_z * h_z, n_z * l_z, l_z * h_z
    alpha = roughness**2
    a2, k = alpha**2, alpha / 2
    ndf = a2 / (math.pi * (a2 * n_dot_h**2 + 0.0) ** 2)  # |n x h|^2 = 0
    fresnel = f0 + (1 - f0) * 2.0 ** ((FRESNEL_A * v_dot_h + FRESNEL_B) * v_dot_h)
    visibility = 0.25 / (n_dot_l * (1 - k) + k) ** 2
    expected = (diffuse * (1 - f0) / math.pi + fresnel * ndf * visibility) * n_dot_l
    assert math.isclose(out, expected, rel_tol=PHYS_RTOL_F64), (out, expected)
    # Up to the epsilon, D = 1 / (pi alpha^2) and F = F0 within the SG residual.
    assert math.isclose(ndf, 1 / (math.pi * a2), rel_tol=1e-9)
    assert abs(fresnel - f0) <= FRESNEL_NORMAL_RESIDUAL * (1 - f0) + 1e-15


@pytest.mark.parametrize("roughness", [0.15, 0.3, 0.6, 1.0])
def test_ggx_ndf_is_normalised(roughness):
    """int D(h) (n.h) dw_h = 1. The kernel is probed with light = camera = h on the
    hemisphere (F0 = 1 makes F = 1), and D is recovered by dividing out the visibility."""
    s = torch.cat(
        [torch.zeros(1, dtype=torch.float64), torch.logspace(-10, math.log10(1 - 1e-6), 4000, dtype=torch.float64)]
    )
    h = torch.stack([s.sqrt(), torch.zeros_like(s), (1 - s).sqrt()], -1)  # s = sin^2(theta_h)
    out = kernels.render(*_probe_maps(roughness), h * FAR, h * FAR, intensity=1.0, inverse_square=False)
    c, k = h[:, 2], roughness**2 / 2
    ndf = out[0, :, 0, 0, 0] * 4 * (c * (1 - k) + k) ** 2 / c  # radiance = D F G/(4 nl nv) nl
    # int D cos dw = 2 pi int D mu dmu = pi int D ds.
    integral = math.pi * float(torch.trapezoid(ndf, s))
    assert abs(integral - 1.0) <= NDF_QUAD_TOL, integral


# --------------------------------------------------------------------------- energy
def _hemisphere(n_theta: int = 128, n_phi: int = 256):
    """Midpoint grid over the upper hemisphere's half y >= 0 (the view lies in the xz
    plane, so the integrand is symmetric in y): directions [N, 3] and weights [N]."""
    th = (torch.arange(n_theta, dtype=torch.float64) + 0.5) / n_theta * (math.pi / 2)
    ph = (torch.arange(n_phi, dtype=torch.float64) + 0.5) / n_phi * math.pi
    t, p = torch.meshgrid(th, ph, indexing="ij")
    dirs = torch.stack([t.sin() * p.cos(), t.sin() * p.sin(), t.cos()], -1).reshape(-1, 3)
    weights = (t.sin() * (math.pi / 2 / n_theta) * (math.pi / n_phi) * 2).reshape(-1)
    return dirs, weights


@pytest.mark.parametrize("roughness", [0.3, 0.6, 1.0])
@pytest.mark.parametrize("view_deg", [0.0, 45.0, 75.0])
def test_white_specular_albedo_at_most_one(roughness, view_deg):
    """int f (n.l) dw_l <= 1 for F0 = 1, no diffuse; the kernel and the reference BRDF
    give the same quadrature."""
    dirs, weights = _hemisphere()
    view = _direction(view_deg)
    out = kernels.render(*_probe_maps(roughness), dirs * FAR, view * FAR, intensity=1.0, inverse_square=False)
    albedo = float((out[0, :, 0, 0, 0] * weights).sum())
    # The kernel's normal is (0, 0, 1) / sqrt(1 + NORMALIZE_EPS); give the reference the same.
    n = torch.tensor([0.0, 0.0, 1.0 / math.sqrt(1.0 + NORMALIZE_EPS)], dtype=torch.float64)[:, None, None]
    ones, zeros = torch.ones(3, 1, 1, dtype=torch.float64), torch.zeros(3, 1, 1, dtype=torch.float64)
    f_cos = reference.cook_torrance(
        n,
        dirs.T[:, None],
        view[:, None, None],
        zeros,
        ones,
        torch.full((1, 1, 1), roughness, dtype=torch.float64),
        0.0993,
    )
    albedo_ref = float((f_cos[0, 0] * weights).sum())
    assert math.isclose(albedo, albedo_ref, rel_tol=PHYS_RTOL_F64), (albedo, albedo_ref)
    assert 0.2 < albedo <= 1.0 + ENERGY_QUAD_TOL, albedo


# --------------------------------------------------------------------------- batching, determinism
def _grads(maps, light, camera, cot):
    inputs = [m.detach().clone().requires_grad_() for m in maps] + [
        light.detach().clone().requires_grad_(),
        camera.detach().clone().requires_grad_(),
    ]
    out = kernels.render(*inputs)
    return out.detach(), torch.autograd.grad(out, inputs, cot)


@pytest.mark.parametrize("threads", ["1", "2"])
def test_batched_equals_looped(threads, monkeypatch, make_maps, make_positions, assert_close_to_max):
    """render on B=3 equals three B=1 calls bit for bit (forward and map gradients); with one
    thread the position gradients too, with two they differ only in summation order."""
    monkeypatch.setenv("DGRSISE_KERNEL_THREADS", threads)
    maps = make_maps(3, 9, 8, seed=21)
    light = make_positions((3, 4), seed=22)
    camera = make_positions((3, 4), seed=23)
    cot = torch.randn(3, 4, 3, 9, 8, generator=torch.Generator().manual_seed(24))
    out, grads = _grads(maps, light, camera, cot)
    for i in range(3):
        out_i, grads_i = _grads([m[i : i + 1] for m in maps], light[i : i + 1], camera[i : i + 1], cot[i : i + 1])
        torch.testing.assert_close(out[i : i + 1], out_i, rtol=0, atol=0)
        for j, (g, g_i) in enumerate(zip(grads, grads_i)):
            if j < 4 or threads == "1":
                torch.testing.assert_close(g[i : i + 1], g_i, rtol=0, atol=0)
            else:
                assert_close_to_max(g_i, g[i : i + 1], SUM_ORDER_RTOL_F32, f"grad {j}")


@pytest.mark.parametrize("b", [1, 3])
def test_deterministic_forward_and_backward(b, make_maps, make_positions):
    maps = make_maps(b, 11, 10, seed=31)
    light = make_positions((b, 5), seed=32)
    camera = make_positions((5,), seed=33)
    cot = torch.randn(b, 5, 3, 11, 10, generator=torch.Generator().manual_seed(34))
    out_a, grads_a = _grads(maps, light, camera, cot)
    out_b, grads_b = _grads(maps, light, camera, cot)
    assert torch.equal(out_a, out_b)
    for g_a, g_b in zip(grads_a, grads_b):
        assert torch.equal(g_a, g_b)
