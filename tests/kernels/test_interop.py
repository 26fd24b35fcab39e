"""Torch <-> Warp interop: zero-copy views, in-place outputs, the Warp traps of its torch
interop notes (never alias grad_output, fresh gradient buffers), non-contiguous inputs,
and the CPU thread split (results independent of DGRSISE_KERNEL_THREADS).
"""

from __future__ import annotations

import pytest
import torch
import warp as wp

import kernels
from kernels import _warp, reference
from kernels.brdf import FRESNEL_A, FRESNEL_B
from kernels.reference import UNIT_ROUNDOFF

#: Position gradients of a B=1 launch split over image rows, float32, relative to the
#: largest entry: each row chunk sums its light/camera gradient over its own pixels, so
#: the total is summed in a different order than with one thread (a few float32 ulps).
SUM_ORDER_RTOL_F32 = 1e-5


@pytest.fixture
def render_inputs(make_maps, make_positions):
    """Factory: ``render_inputs(b, h, w, k, device=)`` -> [diffuse, normal, roughness,
    specular, light [B, K, 3], camera [B, K, 3]], all float32 leaves requiring grad."""

    def build(b=2, h=5, w=6, k=3, device="cpu"):
        maps = make_maps(b, h, w, device=device, requires_grad=True)
        light = make_positions((b, k), device=device, seed=2, requires_grad=True)
        camera = make_positions((b, k), device=device, seed=3, requires_grad=True)
        return [*maps, light, camera]

    return build


# --------------------------------------------------------------------------- zero copy
def test_wp_array_is_a_zero_copy_view(dtype, device):
    _warp.ensure_init()
    t = torch.rand(2, 3, 4, 5, dtype=dtype, device=device)
    a = _warp.wp_array(t)
    assert a.ptr == t.data_ptr() and tuple(a.shape) == tuple(t.shape)
    view = t[1:]  # a contiguous view at an offset into the same storage
    assert _warp.wp_array(view).ptr == view.data_ptr()
    # Writes through the Warp view land in the tensor.
    a.zero_()
    wp.synchronize()  # Warp may write on its own CUDA stream
    assert float(t.abs().max()) == 0.0


#: Fresnel weights w = 2^x, x = (a v.h + b) v.h in [-12.5, 0], float32 against float64 on
#: the same positions, per element: v.h errs by <= ~15u (h within 8u and v within 4u of
#: their directions, render_rtol's docstring, plus the dot's 3u), |dx / d(v.h)| =
#: |2a v.h + b| <= 18.1, and x's own rounding <= 3u |x| <= 37.5u: x within ~310u, so w
#: within ln 2 * 310u ~ 215u relative; 220u.
FRESNEL_RTOL = 220 * UNIT_ROUNDOFF[torch.float32]


def test_render_saves_inputs_without_copies_and_writes_output_in_place(render_inputs):
    inputs = render_inputs()
    out = kernels.render(*inputs)
    saved = out.grad_fn.saved_tensors
    for name, t, s in zip(("diffuse", "normal", "roughness", "specular"), inputs, saved):
        assert s.data_ptr() == t.data_ptr(), f"{name} was copied"
    assert saved[4].data_ptr() == inputs[4].data_ptr()  # [B, K, 3] light: already contiguous
    assert saved[6].data_ptr() == out.data_ptr()  # the kernel wrote the returned tensor itself


def test_fresnel_weights_are_kept_only_for_the_map_gradient_path(render_inputs):
    d, n, r, s, light, camera = [t.detach() for t in render_inputs(b=2, h=5, w=7)]
    # Positions need a gradient: the generated-adjoint path, nothing extra kept.
    out = kernels.render(d.requires_grad_(), n, r, s, light.clone().requires_grad_(), camera)
    assert out.grad_fn.saved_tensors[-1] is None
    # Maps only: the forward keeps w = 2^((a v.h + b) v.h) per pixel and light.
    out = kernels.render(d, n, r, s, light, camera)
    fresnel = out.grad_fn.saved_tensors[-1]
    b, k = out.shape[:2]
    assert fresnel.shape == (b * k, 5, 7)
    x = reference.plane_points(5, 7, 4.0, dtype=torch.float64)
    lh = light.double()[..., None, None] - x
    cv = camera.double()[..., None, None] - x
    l, v = lh / lh.norm(dim=2, keepdim=True), cv / cv.norm(dim=2, keepdim=True)
    h = (l + v) / (l + v).norm(dim=2, keepdim=True)
    vdh = (v * h).sum(2).clamp_min(0)
    expected = torch.exp2((FRESNEL_A * vdh + FRESNEL_B) * vdh).flatten(0, 1)
    torch.testing.assert_close(fresnel.double(), expected, rtol=FRESNEL_RTOL, atol=0)


def test_no_fresnel_buffer_under_no_grad(render_inputs, monkeypatch):
    # Maps with requires_grad, rendered under torch.no_grad(): no backward can follow, so
    # the forward must not allocate the [B*K, H, W] buffer.
    from kernels import _autograd

    d, n, r, s, light, camera = [t.detach() for t in render_inputs(b=2, h=5, w=7)]
    kept = []
    original = _autograd._fresnel_buffer
    monkeypatch.setattr(_autograd, "_fresnel_buffer", lambda *a: kept.append(original(*a)) or kept[-1])
    with torch.no_grad():
        kernels.render(d.requires_grad_(), n, r, s, light, camera)
    kernels.render(d, n, r, s, light, camera)
    assert kept[0] is None and kept[1] is not None


def test_translate_saves_inputs_without_copies():
    feats = torch.randn(2, 4, 6, 6, requires_grad=True)
    offs = torch.tensor([[0.3, -0.4], [1.2, 0.7]], requires_grad=True)
    out = kernels.translate(feats, offs)
    saved = out.grad_fn.saved_tensors
    assert saved[0].data_ptr() == feats.data_ptr() and saved[1].data_ptr() == offs.data_ptr()
    assert saved[2].data_ptr() == out.data_ptr()


def test_non_contiguous_inputs_give_the_same_result(render_inputs):
    d, n, r, s, light, camera = [t.detach() for t in render_inputs(b=2, h=6, w=5)]
    as_cl = [t.contiguous(memory_format=torch.channels_last) for t in (d, n, r, s)]
    assert not as_cl[0].is_contiguous()
    out = kernels.render(*as_cl, light, camera)
    torch.testing.assert_close(out, kernels.render(d, n, r, s, light, camera), rtol=0, atol=0)
    # A transposed view of the feature map is shifted like its contiguous copy.
    f = torch.randn(2, 3, 7, 7).transpose(2, 3)
    offs = torch.tensor([[0.5, 1.0], [-1.5, 0.25]])
    torch.testing.assert_close(kernels.translate(f, offs), kernels.translate(f.contiguous(), offs), rtol=0, atol=0)


# --------------------------------------------------------------------------- Warp traps
def test_backward_leaves_grad_output_untouched_and_returns_fresh_buffers(device, render_inputs):
    inputs = render_inputs(device=device)
    out = kernels.render(*inputs)
    cot = torch.randn(out.shape, generator=torch.Generator().manual_seed(0)).to(device)
    cot_before = cot.clone()
    grads = torch.autograd.grad(out, inputs, cot)
    assert torch.equal(cot, cot_before), "Warp consumed torch's grad_output"
    ptrs = {t.data_ptr() for t in inputs} | {out.data_ptr(), cot.data_ptr()}
    assert all(g.data_ptr() not in ptrs for g in grads)

    feats = torch.randn(2, 3, 5, 5, device=device, requires_grad=True)
    offs = torch.tensor([[0.3, 0.6], [-0.2, 1.4]], device=device, requires_grad=True)
    shifted = kernels.translate(feats, offs)
    cot = torch.randn(shifted.shape, generator=torch.Generator().manual_seed(1)).to(device)
    cot_before = cot.clone()
    torch.autograd.grad(shifted, [feats, offs], cot)
    assert torch.equal(cot, cot_before)


def test_backward_twice_with_retain_graph_is_identical(render_inputs):
    """The saved output adjoint is not consumed: a second backward gives the same grads."""
    inputs = render_inputs()
    out = kernels.render(*inputs)
    cot = torch.randn(out.shape, generator=torch.Generator().manual_seed(2))
    first = torch.autograd.grad(out, inputs, cot, retain_graph=True)
    second = torch.autograd.grad(out, inputs, cot)
    for a, b in zip(first, second):
        assert torch.equal(a, b)


# --------------------------------------------------------------------------- threads
def test_cpu_threads_reads_the_environment_at_call_time(monkeypatch):
    monkeypatch.setenv(_warp.THREADS_ENV, "1")
    assert _warp.cpu_threads() == 1
    monkeypatch.setenv(_warp.THREADS_ENV, "3")
    assert _warp.cpu_threads() == 3
    monkeypatch.delenv(_warp.THREADS_ENV)
    assert _warp.cpu_threads() >= 1


def _everything(b: int, render_inputs, make_maps):
    """Forward values and gradients of every kernel-backed function on one fixed input."""
    inputs = render_inputs(b=b, h=9, w=7, k=4)
    out = kernels.render(*inputs)
    cot = torch.randn(out.shape, generator=torch.Generator().manual_seed(5))
    results = {"render": out.detach()}
    for i, g in enumerate(torch.autograd.grad(out, inputs, cot)):
        results[f"render.grad{i}"] = g
    target = kernels.render(*make_maps(b, 9, 7, seed=9), inputs[4].detach(), inputs[5].detach())
    loss = kernels.rendering_loss(*inputs[:4], target, *inputs[4:])
    results["rendering_loss"] = loss.detach()
    for i, g in enumerate(torch.autograd.grad(loss, inputs)):
        results[f"rendering_loss.grad{i}"] = g
    feats = torch.randn(b, 3, 6, 6, generator=torch.Generator().manual_seed(6)).requires_grad_()
    offs = torch.tensor([[0.4, -0.6]] * b, requires_grad=True)
    shifted = kernels.translate(feats, offs)
    results["translate"] = shifted.detach()
    results["translate.grads"] = torch.cat(
        [g.flatten() for g in torch.autograd.grad(shifted.square().sum(), [feats, offs])]
    )
    x = out.detach().requires_grad_()
    for name in ("log_l1_loss", "mse_loss"):
        value = getattr(kernels, name)(x, target)
        results[name] = value.detach()
        results[f"{name}.grad"] = torch.autograd.grad(value, [x])[0]
    return results


@pytest.mark.parametrize("b", [1, 3])
@pytest.mark.parametrize("threads", [None, "3"])
def test_thread_count_does_not_change_results(threads, b, monkeypatch, render_inputs, make_maps, assert_close_to_max):
    """One thread vs the default (all cores) and vs 3: forward values and map gradients are
    bit-identical (chunks write disjoint outputs). Position gradients are too when the
    batch is split; a row split (B=1) sums them in another order."""
    monkeypatch.setenv(_warp.THREADS_ENV, "1")
    single = _everything(b, render_inputs, make_maps)
    if threads is None:
        monkeypatch.delenv(_warp.THREADS_ENV)
    else:
        monkeypatch.setenv(_warp.THREADS_ENV, threads)
    multi = _everything(b, render_inputs, make_maps)
    for key, value in single.items():
        position_grad = key.endswith(("grad4", "grad5"))
        if b == 1 and position_grad:
            assert_close_to_max(multi[key], value, SUM_ORDER_RTOL_F32, key)
        else:
            assert torch.equal(multi[key], value), key
