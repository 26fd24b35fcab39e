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
from kernels.reference import UNIT_ROUNDOFF, render_rtol

#: Rendering-loss values: each term |log(x + eps) - log(y + eps)| moves by at most the
#: relative error of x + eps (render_rtol's per-element terms) plus the rounding of two
#: float32 logs of values in [eps, ~20] (1 + |ln 0.01| ~ 5.6u each) and a difference:
#: 12u on top of render_rtol; the mean of such terms errs by no more than the largest.
LOSS_LOG_ULPS = 12
#: Image-loss values (log_l1_loss, mse_loss) on _pair's data, in units of u: a log-L1 term
#: errs by <= 12u absolute (above), against a mean |term| >= 0.1 on U[0, 2] pairs: 120u;
#: an MSE term by <= 3u relative; plus a float32 mean of n <= 2062 terms by pairwise
#: summation (the twin's), <= log2(n) u ~ 11u. 200u covers both.
IMAGE_LOSS_ULPS = 200
#: Image-loss gradients, per element, in units of u: g / N / (x + eps) (log-L1) or
#: 2 g (x - y) / N (MSE) are <= 4 roundings of 1u each; 8u for an implementation that
#: forms a reciprocal separately.
IMAGE_VJP_ULPS = 8
#: Accuracy of a float32 mean over ~4M terms against the exact value: the two-stage
#: reduction (float64 row accumulators, float64 sum of partials) leaves only the
#: per-element float32 rounding (<= 3u ~ 1.8e-7 here); a single float32 accumulator would
#: be off ~1e-2.
REDUCTION_RTOL = 1e-6

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
    preset, b, positions_grad, dtype, device, loss_scene, assert_close_to_max, assert_grad_alive, vjp_rtol
):
    """float64: kernel against twin within twice the bounds; float32: kernel and float32
    twin each against the float64 twin on the same inputs, within the bounds."""
    h, w = 7, 13
    maps, light, camera, target = loss_scene(b, h, w, 4, dtype=dtype, device=device)
    if not positions_grad:
        light, camera = light.detach(), camera.detach()
    kw = {"preset": preset, "plane_size": 4.0}
    u = UNIT_ROUNDOFF[dtype]
    rough = max(float(maps[2].detach().min()), kernels.get_preset(preset).roughness_floor)
    loss_rtol = render_rtol(dtype, rough) + LOSS_LOG_ULPS * u
    # Longest sum: the [K, 3] camera gradient sums over the batch and the pixels.
    grad_rtol = vjp_rtol(dtype, rough, b * h * w)

    def value_and_grads(fn, ms, tgt, lt, cm):
        inputs = [*ms, lt, cm] if positions_grad else list(ms)
        loss = fn(*ms, tgt, lt, cm, **kw)
        return loss, torch.autograd.grad(loss, inputs)

    loss, grads = value_and_grads(kernels.rendering_loss, maps, target, light, camera)
    assert loss.shape == () and loss.dtype == dtype
    twin, twin_grads = value_and_grads(reference.rendering_loss, maps, target, light, camera)
    if dtype == torch.float64:
        assert_close_to_max(loss, twin, 2 * loss_rtol, "loss")
        for name, g, r in zip(NAMES, grads, twin_grads):
            assert_close_to_max(g, r, 2 * grad_rtol, name)
            assert_grad_alive(g, r, name)
        return

    def f64(t):
        return t.detach().double().requires_grad_(t.requires_grad)

    exact, exact_grads = value_and_grads(
        reference.rendering_loss, [f64(m) for m in maps], target.double(), f64(light), f64(camera)
    )
    for what, value, gs in (("kernel", loss, grads), ("reference", twin, twin_grads)):
        assert_close_to_max(value.double(), exact, loss_rtol, f"{what} loss")
        for name, g, e in zip(NAMES, gs, exact_grads):
            assert_close_to_max(g.double(), e, grad_rtol, f"{what} {name}")
            assert_grad_alive(g, e, name)


def test_rendering_loss_equals_log_l1_of_render(loss_scene, assert_close_to_max):
    """The fused kernel is log_l1_loss(render(...), target), never storing the rendering."""
    maps, light, camera, target = loss_scene(2, 5, 6, 3, dtype=torch.float64, requires_grad=False)
    fused = kernels.rendering_loss(*maps, target, light, camera, eps=0.05)
    unfused = kernels.log_l1_loss(kernels.render(*maps, light, camera), target, eps=0.05)
    # The fused kernel renders with the same expressions: only the logs and the sum's
    # order differ, a few float64 ulps of each term.
    assert_close_to_max(fused, unfused, LOSS_LOG_ULPS * UNIT_ROUNDOFF[torch.float64])


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
    """Kernel and twin, each against the twin in float64 on the same inputs."""
    x, y = _pair(shape, dtype=dtype, device=device)
    u = UNIT_ROUNDOFF[dtype]
    x64 = x.detach().double().requires_grad_()
    exact = getattr(reference, name)(x64, y.double())
    (exact_grad,) = torch.autograd.grad(exact, [x64])
    for fn in (getattr(kernels, name), getattr(reference, name)):
        loss = fn(x, y)
        assert loss.shape == () and loss.dtype == dtype
        assert_close_to_max(loss.double(), exact, IMAGE_LOSS_ULPS * u, f"{name} {fn.__module__}")
        (g,) = torch.autograd.grad(loss, [x])
        assert_close_to_max(g.double(), exact_grad, IMAGE_VJP_ULPS * u, f"{name} {fn.__module__} grad")
        assert_grad_alive(g, exact_grad, name)


def test_log_l1_loss_custom_eps(assert_close_to_max):
    x, y = _pair((4, 6), dtype=torch.float64)
    out, ref = kernels.log_l1_loss(x, y, eps=0.3), reference.log_l1_loss(x, y, eps=0.3)
    assert_close_to_max(out, ref, 2 * IMAGE_LOSS_ULPS * UNIT_ROUNDOFF[torch.float64])


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
def test_map_rendering_loss_is_rendering_loss_of_rendered_targets(
    make_maps, make_positions, assert_close_to_max, vjp_rtol
):
    pred = make_maps(2, 6, 6, dtype=torch.float64, seed=1, requires_grad=True)
    target = make_maps(2, 6, 6, dtype=torch.float64, seed=2)
    light = make_positions((2, 3), dtype=torch.float64, seed=3)
    camera = make_positions((3,), dtype=torch.float64, seed=4)
    loss = kernels.map_rendering_loss(pred, target, light, camera)
    ref = reference.rendering_loss(*pred, reference.render(*target, light, camera), light, camera)
    rough = max(
        min(float(pred[2].detach().min()), float(target[2].min())), kernels.get_preset("dgrsise").roughness_floor
    )
    f64 = torch.float64
    # Both sides float64, each within the bounds: twice them apart.
    assert_close_to_max(loss, ref, 2 * (render_rtol(f64, rough) + LOSS_LOG_ULPS * UNIT_ROUNDOFF[f64]))
    for name, g, r in zip(NAMES, torch.autograd.grad(loss, pred), torch.autograd.grad(ref, pred)):
        assert_close_to_max(g, r, 2 * vjp_rtol(f64, rough, 3), name)  # sums over 3 lights


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
