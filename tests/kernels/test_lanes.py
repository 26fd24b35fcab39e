"""The lane builds of the shading kernels (``kernels.lanes``): the lane-wise 2^x and log
of the CPU's float32 build against float64, and the one-pixel-per-thread build (the
CUDA path, ``lanes`` = 1) run on the CPU against the twin, so that both builds of the
one source are tested on a machine without a GPU.

The rest of the kernel suite runs the CPU's lane build (``CPU_LANES`` pixels per thread),
its odd image widths (7, 9, 13) through the zero-padded last lane group.
"""

# No ``from __future__ import annotations`` here: Warp reads the test kernel's annotations.
import pytest
import torch
import warp as wp

import kernels
from kernels import _autograd
from kernels._warp import ensure_init
from kernels.lanes import CPU_LANES, build_lanes
from kernels.reference import UNIT_ROUNDOFF

#: 2^x of the float32 lane build (degree-6 fit, ``kernels.lanes.EXP2_COEFFS``): the fit's
#: own error is 1.6 u on a dense grid, Horner's rounding and the exponent scaling add
#: ~1 u (measured: 1.7 u over [-12.6, 0]); 4 u bounds it with room, as libm's exp2f
#: (~1 u) would be.
EXP2_ULPS = 4.0
#: log of the float32 lane build, relative to max(|log x|, 1): the atanh series' rounding
#: (~1 u of log m) plus the exponent term's (e ln 2, ~0.5 u of the result); measured
#: 1.85 u over [1, 1e30] (torch's float32 log: 1.2 u).
LOG_ULPS = 4.0


@pytest.fixture(scope="module")
def lane_math():
    """``f(x) -> (2^x, log x)`` through the float32 lane build's snippets."""
    ensure_init()
    ln = build_lanes(wp.float32, CPU_LANES)
    lane = ln.L

    @wp.kernel(module="test_lanes_math", enable_backward=False)
    def lane_math_kernel(x: wp.array(dtype=lane), e: wp.array(dtype=lane), lg: wp.array(dtype=lane)):
        t = wp.tid()
        e[t] = ln.exp2(x[t])
        lg[t] = ln.log(x[t])

    def run(x: torch.Tensor):
        n = x.numel()
        e, lg = torch.empty(n), torch.empty(n)

        def view(t):
            return wp.from_torch(t.view(-1, CPU_LANES), dtype=lane)

        wp.launch(lane_math_kernel, dim=n // CPU_LANES, inputs=[view(x)], outputs=[view(e), view(lg)], device="cpu")
        return e, lg

    return run


def test_lane_exp2_over_the_fresnel_exponent_range(lane_math):
    # (FRESNEL_A v.h + FRESNEL_B) v.h for v.h in [0, 1] spans [-12.54, 0].
    x = torch.linspace(-12.6, 0.0, 1 << 16, dtype=torch.float64).float()
    got, _ = lane_math(x)
    exact = 2.0 ** x.double()
    err = ((got.double() - exact).abs() / exact).max().item()
    assert err <= EXP2_ULPS * UNIT_ROUNDOFF[torch.float32], err


def test_lane_log_over_the_loss_ratio_range(lane_math):
    # The fused loss takes log(prod max / prod min) >= 1; 1e30 is beyond any ratio of
    # its three-term products.
    x = torch.exp(torch.linspace(0.0, 69.0, 1 << 16, dtype=torch.float64)).float()
    x[:CPU_LANES] = 1.0
    _, got = lane_math(x)
    exact = torch.log(x.double())
    err = ((got.double() - exact).abs() / exact.abs().clamp_min(1.0)).max().item()
    assert err <= LOG_ULPS * UNIT_ROUNDOFF[torch.float32], err
    assert (got[:CPU_LANES] == 0).all()


@pytest.fixture
def one_pixel_per_thread(monkeypatch):
    """Run every shading launch through the ``lanes`` = 1 build, as CUDA does."""
    monkeypatch.setattr(_autograd, "_lanes", lambda device: 1)


@pytest.mark.parametrize("b,h,w,k", [(2, 7, 13, 3), (1, 5, 32, 2)])
def test_one_pixel_build_forward_and_vjp(
    b, h, w, k, dtype, one_pixel_per_thread, make_maps, make_positions, assert_render_accurate, assert_vjp_accurate
):
    maps = make_maps(b, h, w, dtype=dtype)
    light = make_positions((b, k), dtype=dtype, seed=2)
    camera = make_positions((b, k), dtype=dtype, seed=3)
    assert_render_accurate(kernels.render(*maps, light, camera), maps, light, camera, "lanes=1")
    inputs = [t.clone().requires_grad_(i < 4) for i, t in enumerate([*maps, light, camera])]
    cot = torch.randn((b, k, 3, h, w), generator=torch.Generator().manual_seed(5), dtype=torch.float64).to(dtype)
    assert_vjp_accurate(inputs, cot, n_sum=k)


def test_lane_builds_agree(make_maps, make_positions, monkeypatch, assert_close_to_max):
    """Both builds of the one source, float64 (where the lane build's libm calls are the
    one-pixel build's): forward, map gradients and the fused loss's map gradients."""
    maps = make_maps(2, 6, 21, dtype=torch.float64)
    light = make_positions((2, 3), dtype=torch.float64, seed=2)
    camera = make_positions((2, 3), dtype=torch.float64, seed=3)
    target = kernels.render(*make_maps(2, 6, 21, dtype=torch.float64, seed=9), light, camera).detach()

    def run():
        xs = [t.clone().requires_grad_() for t in maps]
        out = kernels.render(*xs, light, camera)
        out.backward(torch.ones_like(out))
        ys = [t.clone().requires_grad_() for t in maps]
        loss = kernels.rendering_loss(*ys, target, light, camera)
        loss.backward()
        return [out.detach(), loss.detach(), *(x.grad for x in xs), *(y.grad for y in ys)]

    lanes = run()
    monkeypatch.setattr(_autograd, "_lanes", lambda device: 1)
    one = run()
    for i, (a, e) in enumerate(zip(lanes, one)):
        assert_close_to_max(a, e, 1e-13, f"output {i}")
