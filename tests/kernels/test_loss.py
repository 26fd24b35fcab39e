"""Kernel losses against their references: rendering_loss (fused render + log-L1),
log_l1_loss, mse_loss, map_rendering_loss; float64 gradcheck; the accuracy of the
two-stage reduction over millions of float32 terms; sample_loss_lights' geometry.
"""

from __future__ import annotations

import math

import pytest
import torch

import kernels
from kernels import reference

#: Loss values, float32: per-element float32 rounding (log and products), then a sum
#: accumulated in float64 -> a few ulps of float32 relative to the mean.
LOSS_RTOL_F32 = 1e-5
#: Loss values, float64.
LOSS_RTOL_F64 = 1e-12
#: VJP, float32, relative to the largest gradient entry: per the kernels issue, float32
#: cancellation near specular peaks (the log-L1 gradient divides by x + eps).
VJP_RTOL_F32 = 1e-3
#: VJP, float64.
VJP_RTOL_F64 = 1e-10
#: Accuracy of a float32 mean over ~4M terms against the exact value: the two-stage
#: reduction (float64 row accumulators, float64 sum of partials) leaves only the
#: per-element float32 rounding (~6e-8); a single float32 accumulator would be off ~1e-2.
REDUCTION_RTOL = 1e-6

LOSS_RTOL = {torch.float32: LOSS_RTOL_F32, torch.float64: LOSS_RTOL_F64}
VJP_RTOL = {torch.float32: VJP_RTOL_F32, torch.float64: VJP_RTOL_F64}
NAMES = ("diffuse", "normal", "roughness", "specular", "light_pos", "camera_pos")


@pytest.fixture
def loss_scene(make_maps, make_positions):
    """Factory: ``loss_scene(B, H, W, K, ...)`` -> (maps, light [B, K, 3], camera [K, 3], target)."""

    def build(b, h, w, k, *, dtype=torch.float32, device="cpu", requires_grad=True, seed=0):
        maps = make_maps(b, h, w, dtype=dtype, device=device, seed=seed, requires_grad=requires_grad)
        light = make_positions((b, k), dtype=dtype, device=device, seed=seed + 2, requires_grad=requires_grad)
        camera = make_positions((k,), dtype=dtype, device=device, seed=seed + 3, requires_grad=requires_grad)
        # Targets: another material under the same lights, so |log x - log y| is never at its kink.
        with torch.no_grad():
            other = make_maps(b, h, w, dtype=dtype, device=device, seed=seed + 100)
            target = kernels.render(*other, light, camera)
        return maps, light, camera, target

    return build


# --------------------------------------------------------------------------- rendering loss
@pytest.mark.parametrize("positions_grad", [True, False], ids=["adjoint", "maps-only"])
@pytest.mark.parametrize("b", [1, 3])
@pytest.mark.parametrize("preset", ["dgrsise", "materialgan"])
def test_rendering_loss_matches_reference(
    preset, b, positions_grad, dtype, device, loss_scene, assert_close_to_max, assert_grad_alive
):
    maps, light, camera, target = loss_scene(b, 7, 13, 4, dtype=dtype, device=device)
    if not positions_grad:
        light, camera = light.detach(), camera.detach()
    kw = {"preset": preset, "plane_size": 4.0}
    loss = kernels.rendering_loss(*maps, target, light, camera, **kw)
    ref = reference.rendering_loss(*maps, target, light, camera, **kw)
    assert loss.shape == () and loss.dtype == dtype
    assert_close_to_max(loss, ref, LOSS_RTOL[dtype], "loss")
    inputs = [*maps, light, camera] if positions_grad else list(maps)
    for name, g, r in zip(NAMES, torch.autograd.grad(loss, inputs), torch.autograd.grad(ref, inputs)):
        assert_close_to_max(g, r, VJP_RTOL[dtype], name)
        assert_grad_alive(g, r, name)


def test_rendering_loss_equals_log_l1_of_render(loss_scene, assert_close_to_max):
    """The fused kernel is log_l1_loss(render(...), target), never storing the rendering."""
    maps, light, camera, target = loss_scene(2, 5, 6, 3, dtype=torch.float64, requires_grad=False)
    fused = kernels.rendering_loss(*maps, target, light, camera, eps=0.05)
    unfused = kernels.log_l1_loss(kernels.render(*maps, light, camera), target, eps=0.05)
    assert_close_to_max(fused, unfused, LOSS_RTOL_F64)


@pytest.mark.parametrize("positions_grad", [True, False], ids=["adjoint", "maps-only"])
def test_rendering_loss_gradcheck_float64(positions_grad, loss_scene):
    maps, light, camera, target = loss_scene(2, 3, 4, 2, dtype=torch.float64, seed=20)
    if positions_grad:
        fn, inputs = (lambda *a: kernels.rendering_loss(*a[:4], target, *a[4:])), (*maps, light, camera)
    else:
        light, camera = light.detach(), camera.detach()
        fn, inputs = (lambda *a: kernels.rendering_loss(*a, target, light, camera)), tuple(maps)
    assert torch.autograd.gradcheck(fn, inputs, eps=1e-6, atol=1e-7, rtol=1e-5)


# --------------------------------------------------------------------------- image losses
def _pair(shape, *, dtype=torch.float32, device="cpu"):
    g = torch.Generator().manual_seed(5)
    x = torch.rand(shape, generator=g, dtype=torch.float64) * 2
    y = torch.rand(shape, generator=g, dtype=torch.float64) * 2
    return x.to(dtype=dtype, device=device).requires_grad_(), y.to(dtype=dtype, device=device)


@pytest.mark.parametrize("shape", [(7,), (3, 5), (2, 3, 4, 9), (1, 1, 1), (2, 1031)], ids=str)
@pytest.mark.parametrize("name", ["log_l1_loss", "mse_loss"])
def test_image_losses_match_reference(name, shape, dtype, device, assert_close_to_max, assert_grad_alive):
    x, y = _pair(shape, dtype=dtype, device=device)
    loss = getattr(kernels, name)(x, y)
    ref = getattr(reference, name)(x, y)
    assert loss.shape == () and loss.dtype == dtype
    assert_close_to_max(loss, ref, LOSS_RTOL[dtype], name)
    (g,), (r,) = torch.autograd.grad(loss, [x]), torch.autograd.grad(ref, [x])
    assert_close_to_max(g, r, VJP_RTOL[dtype], f"{name} grad")
    assert_grad_alive(g, r, name)


def test_log_l1_loss_custom_eps(assert_close_to_max):
    x, y = _pair((4, 6), dtype=torch.float64)
    assert_close_to_max(kernels.log_l1_loss(x, y, eps=0.3), reference.log_l1_loss(x, y, eps=0.3), LOSS_RTOL_F64)


@pytest.mark.parametrize("name", ["log_l1_loss", "mse_loss"])
def test_image_losses_gradcheck_float64(name):
    x, y = _pair((2, 3, 5), dtype=torch.float64)
    fn = getattr(kernels, name)
    assert torch.autograd.gradcheck(lambda a: fn(a, y), (x,), eps=1e-6, atol=1e-7, rtol=1e-5)


def test_losses_take_no_gradient_to_the_target():
    x, y = _pair((3, 4), dtype=torch.float64)
    y.requires_grad_()
    for fn in (kernels.log_l1_loss, kernels.mse_loss):
        gx, gy = torch.autograd.grad(fn(x, y), [x, y], allow_unused=True)
        assert gy is None or float(gy.abs().max()) == 0.0
        assert float(gx.abs().max()) > 0


@pytest.mark.parametrize("shape", [(4 * 1024 * 1024,), (4, 4, 512, 512), (2, 2, 1024, 1024)], ids=str)
def test_mean_over_millions_of_float32_terms_is_accurate(shape):
    """A constant difference makes every rounding error of a naive float32 sum add up; the
    two-stage reduction must still give the exact mean to REDUCTION_RTOL."""
    x = torch.full(shape, 0.3)
    y = torch.full(shape, 0.2)
    d = float(x[(0,) * len(shape)]) - float(y[(0,) * len(shape)])  # the float32 values, exactly
    mse = float(kernels.mse_loss(x, y))
    assert abs(mse - d * d) <= REDUCTION_RTOL * d * d, (mse, d * d)
    exact = abs(math.log(float(x.flatten()[0]) + kernels.LOG_EPS) - math.log(float(y.flatten()[0]) + kernels.LOG_EPS))
    log_l1 = float(kernels.log_l1_loss(x, y))
    assert abs(log_l1 - exact) <= REDUCTION_RTOL * exact, (log_l1, exact)


def test_mse_gradient_over_millions_of_terms():
    x = torch.full((2, 2, 1024, 1024), 0.3, requires_grad=True)
    y = torch.full((2, 2, 1024, 1024), 0.2)
    (g,) = torch.autograd.grad(kernels.mse_loss(x, y), [x])
    d = float(x.detach()[0, 0, 0, 0]) - float(y[0, 0, 0, 0])
    expected = 2 * d / x.numel()
    assert abs(float(g.min()) - expected) <= REDUCTION_RTOL * expected
    assert abs(float(g.max()) - expected) <= REDUCTION_RTOL * expected


# --------------------------------------------------------------------------- map rendering loss
def test_map_rendering_loss_is_rendering_loss_of_rendered_targets(make_maps, make_positions, assert_close_to_max):
    pred = make_maps(2, 6, 6, dtype=torch.float64, seed=1, requires_grad=True)
    target = make_maps(2, 6, 6, dtype=torch.float64, seed=2)
    light = make_positions((2, 3), dtype=torch.float64, seed=3)
    camera = make_positions((3,), dtype=torch.float64, seed=4)
    loss = kernels.map_rendering_loss(pred, target, light, camera)
    ref = reference.rendering_loss(*pred, reference.render(*target, light, camera), light, camera)
    assert_close_to_max(loss, ref, LOSS_RTOL_F64)
    for name, g, r in zip(NAMES, torch.autograd.grad(loss, pred), torch.autograd.grad(ref, pred)):
        assert_close_to_max(g, r, VJP_RTOL_F64, name)


def test_map_rendering_loss_samples_lights_deterministically(make_maps):
    pred = make_maps(2, 5, 5, seed=1)
    target = make_maps(2, 5, 5, seed=2)
    a = kernels.map_rendering_loss(pred, target, generator=torch.Generator().manual_seed(3))
    b = kernels.map_rendering_loss(pred, target, generator=torch.Generator().manual_seed(3))
    same = kernels.map_rendering_loss(pred, pred, generator=torch.Generator().manual_seed(3))
    assert float(a) == float(b) and float(a) > 0
    assert float(same) == 0.0


@pytest.mark.parametrize("plane_size", [4.0, 17.0])
def test_sample_loss_lights_geometry(plane_size):
    light, camera = kernels.sample_loss_lights(
        64,
        plane_size=plane_size,
        n_diffuse=3,
        n_specular=6,
        generator=torch.Generator().manual_seed(0),
        dtype=torch.float64,
    )
    assert light.shape == camera.shape == (64, 9, 3) and light.dtype == torch.float64
    assert bool((light[..., 2] > 0).all()) and bool((camera[..., 2] > 0).all())
    # Specular configurations: the mirror point of light and camera lies on the plane.
    m = kernels.mirror_point(light[:, 3:], camera[:, 3:])
    assert float(m.abs().max()) <= 0.75 * plane_size / 2 + 1e-9  # centres drawn in 75% of the plane
    again = kernels.sample_loss_lights(
        64, plane_size=plane_size, generator=torch.Generator().manual_seed(0), dtype=torch.float64
    )
    torch.testing.assert_close(again[0], light, rtol=0, atol=0)
