"""kernels.translate (sub-pixel feature shift, edge clamp) against its reference, its exact
integer-shift behaviour, and the highlight geometry (mirror_point, highlight_offsets) of
SPEC section 3, including a check that the translated highlight lands where the renderer
puts it.
"""

from __future__ import annotations

import pytest
import torch

import kernels
from kernels import reference
from kernels.reference import UNIT_ROUNDOFF

#: Geometry is closed-form in float64: a few ulps.
GEOM_ATOL = 1e-12
#: highlight_offsets in float32 on dyadic positions (1.0625, 4.0): the mirror point
#: 0.53125, the shift and the 16 pixels per unit are exact, so the offset is exactly 8.5
#: (measured: 0 error); 1e-5, ~10 ulps of 8.5, leaves room for a mirror-point formula
#: whose intermediate (a ratio of heights) is not dyadic.
OFFSET_ATOL_F32 = 1e-5


def translate_rtol(dtype: torch.dtype, feats: torch.Tensor, offsets: torch.Tensor) -> float:
    """Bound on max |translate error| / max |features| in ``dtype``: the source coordinate
    j - dx (and i - dy) is rounded by <= u (max(H, W) + max |offset|), an error that the
    fractional weight carries onto |f(x1) - f(x0)| <= 2 max |f| per axis; three lerps of
    two roundings each add 6u."""
    u = UNIT_ROUNDOFF[dtype]
    coord = u * (max(feats.shape[-2:]) + float(offsets.detach().abs().max()))
    return 2 * 2 * coord + 6 * u


def translate_vjp_rtol(dtype: torch.dtype, feats: torch.Tensor, offsets: torch.Tensor) -> float:
    """Bound on the VJP errors relative to the largest entry: the forward's per-term bound
    and 4u for the <= 4 taps a feature gradient sums, plus n^1.5 u for an offset gradient,
    a float32 sum of n = C H W terms with random-sign cotangents (conftest's VJP model)."""
    n = feats[0].numel()
    return translate_rtol(dtype, feats, offsets) + UNIT_ROUNDOFF[dtype] * (4 + n**1.5)


#: Fractional offsets away from integers (and from the clamp boundaries of the 4x5 /
#: 6x9 maps used below), so finite differences never straddle a bilinear kink.
FRACTIONAL_OFFSETS = [[0.37, -1.23], [2.6, 0.45], [-0.71, 1.82]]


def _features(b, c, h, w, *, dtype=torch.float32, device="cpu", seed=0, requires_grad=False):
    g = torch.Generator().manual_seed(seed)
    f = torch.randn((b, c, h, w), generator=g, dtype=torch.float64).to(dtype=dtype, device=device)
    return f.requires_grad_() if requires_grad else f


def _offsets(b, *, dtype=torch.float32, device="cpu", requires_grad=False):
    o = torch.tensor(FRACTIONAL_OFFSETS[:b], dtype=dtype, device=device)
    return o.requires_grad_() if requires_grad else o


def _shift_exact(features: torch.Tensor, dx: int, dy: int) -> torch.Tensor:
    """out(i, j) = features(clamp(i - dy), clamp(j - dx)): a roll with edge clamp."""
    _, _, h, w = features.shape
    rows = (torch.arange(h) - dy).clamp(0, h - 1)
    cols = (torch.arange(w) - dx).clamp(0, w - 1)
    return features[:, :, rows][:, :, :, cols]


# --------------------------------------------------------------------------- translate
@pytest.mark.parametrize("b", [1, 3])
def test_forward_and_vjp_match_reference(b, dtype, device, assert_close_to_max, assert_grad_alive):
    """float64: kernel against twin within twice the bounds; float32: kernel and float32
    twin each against the float64 twin on the same inputs."""
    feats = _features(b, 5, 6, 9, dtype=dtype, device=device, requires_grad=True)
    offs = _offsets(b, dtype=dtype, device=device, requires_grad=True)
    fwd_rtol, vjp_rtol = translate_rtol(dtype, feats, offs), translate_vjp_rtol(dtype, feats, offs)
    cot = torch.randn(feats.shape, generator=torch.Generator().manual_seed(3), dtype=torch.float64)

    def run(fn, f, o, c):
        out = fn(f, o)
        return out, torch.autograd.grad(out, (f, o), c)

    out, grads = run(kernels.translate, feats, offs, cot.to(dtype=dtype, device=device))
    assert out.shape == feats.shape
    twin, twin_grads = run(reference.translate, feats, offs, cot.to(dtype=dtype, device=device))
    if dtype == torch.float64:
        assert_close_to_max(out, twin, 2 * fwd_rtol, "forward")
        for name, g, r in zip(("features", "offsets"), grads, twin_grads):
            assert_close_to_max(g, r, 2 * vjp_rtol, name)
            assert_grad_alive(g, r, name)
        return
    f64, o64 = (t.detach().double().requires_grad_() for t in (feats, offs))
    exact, exact_grads = run(reference.translate, f64, o64, cot.to(device=device))
    for what, value, gs in (("kernel", out, grads), ("reference", twin, twin_grads)):
        assert_close_to_max(value.double(), exact, fwd_rtol, f"{what} forward")
        for name, g, e in zip(("features", "offsets"), gs, exact_grads):
            assert_close_to_max(g.double(), e, vjp_rtol, f"{what} {name}")
            assert_grad_alive(g, e, name)


def test_gradcheck_float64():
    feats = _features(2, 3, 4, 5, dtype=torch.float64, seed=4, requires_grad=True)
    offs = _offsets(2, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(kernels.translate, (feats, offs), eps=1e-6, atol=1e-7, rtol=1e-5)


@pytest.mark.parametrize("dx,dy", [(0, 0), (2, 0), (0, -3), (-4, 1), (3, 5), (20, -20)])
def test_integer_offsets_are_a_clamped_roll(dx, dy):
    """Integer shifts move content exactly (no blending); uncovered borders repeat the edge."""
    feats = _features(2, 4, 7, 8)
    offs = torch.tensor([[float(dx), float(dy)]] * 2)
    out = kernels.translate(feats, offs)
    torch.testing.assert_close(out, _shift_exact(feats, dx, dy), rtol=0, atol=0)
    # Where the shifted map is covered, it equals torch.roll.
    h, w = feats.shape[2:]
    rows = slice(max(dy, 0), h + min(dy, 0))
    cols = slice(max(dx, 0), w + min(dx, 0))
    rolled = torch.roll(feats, (dy, dx), dims=(2, 3))
    torch.testing.assert_close(out[:, :, rows, cols], rolled[:, :, rows, cols], rtol=0, atol=0)
    if 0 < dx < w:  # the first dx columns repeat the (shifted) column 0
        torch.testing.assert_close(out[..., :dx], out[..., dx : dx + 1].expand_as(out[..., :dx]), rtol=0, atol=0)


def test_zero_offset_is_identity(dtype):
    feats = _features(3, 6, 5, 4, dtype=dtype)
    out = kernels.translate(feats, torch.zeros(3, 2, dtype=dtype))
    torch.testing.assert_close(out, feats, rtol=0, atol=0)


def test_half_pixel_offset_averages_neighbours():
    feats = _features(1, 2, 4, 6, dtype=torch.float64)
    out = kernels.translate(feats, torch.tensor([[0.5, 0.0]], dtype=torch.float64))
    expected = 0.5 * (feats[..., 1:] + feats[..., :-1])
    torch.testing.assert_close(out[..., 1:], expected, rtol=0, atol=GEOM_ATOL)


# --------------------------------------------------------------------------- geometry
def test_mirror_point_equal_heights_is_midpoint():
    cam = torch.tensor([1.0, 1.0, 5.0], dtype=torch.float64)
    light = torch.tensor([3.0, -1.0, 5.0], dtype=torch.float64)
    torch.testing.assert_close(
        kernels.mirror_point(light, cam), torch.tensor([2.0, 0.0], dtype=torch.float64), rtol=0, atol=GEOM_ATOL
    )


def test_mirror_point_is_where_reflection_angles_match():
    """At m the angles of incidence and reflection are equal: c_z / |c_xy - m| = p_z / |p_xy - m|."""
    cam = torch.tensor([0.5, -0.3, 4.0], dtype=torch.float64)
    light = torch.tensor([-2.0, 1.5, 7.0], dtype=torch.float64)
    m = kernels.mirror_point(light, cam)
    tan_c = cam[2] / (cam[:2] - m).norm()
    tan_p = light[2] / (light[:2] - m).norm()
    torch.testing.assert_close(tan_c, tan_p, rtol=0, atol=GEOM_ATOL)


@pytest.mark.parametrize("plane_size,size", [(4.0, (64, 64)), (2.0, (32, 48))])
def test_highlight_offsets_x_right_and_y_up(plane_size, size):
    h, w = size
    cam = torch.tensor([0.0, 0.0, 4.0], dtype=torch.float64)
    lights = torch.tensor([[2.0, 0.0, 4.0], [0.0, 2.0, 4.0]], dtype=torch.float64)
    offs = kernels.highlight_offsets(lights, cam, plane_size, size)
    # Mirror point x = 1 plane unit -> dx = w / plane_size pixels; +y (up) -> negative rows.
    expected = torch.tensor([[w / plane_size, 0.0], [0.0, -h / plane_size]], dtype=torch.float64)
    torch.testing.assert_close(offs, expected, rtol=0, atol=GEOM_ATOL)


def test_highlight_offsets_are_relative_to_the_camera():
    cam = torch.tensor([1.0, -1.0, 4.0], dtype=torch.float64)
    light = torch.tensor([1.0, -1.0, 6.0], dtype=torch.float64)  # straight above the camera
    torch.testing.assert_close(
        kernels.highlight_offsets(light, cam, 4.0, (16, 16)),
        torch.zeros(2, dtype=torch.float64),
        rtol=0,
        atol=GEOM_ATOL,
    )


def test_translated_highlight_lands_where_the_renderer_puts_it():
    """Shifting a collocated-light rendering by highlight_offsets moves its mirror peak to the
    peak of the rendering under the target light (renderer and geometry agree on axes)."""
    size, plane = 64, 4.0
    d, s = torch.zeros(1, 3, size, size), torch.ones(1, 3, size, size)
    n = torch.zeros(1, 3, size, size)
    n[:, 2] = 1
    r = torch.full((1, 1, size, size), 0.15)
    cam = torch.tensor([0.0, 0.0, 4.0])
    # Mirror point (0.53125, -0.53125) is the centre of pixel (row 40, col 40).
    target_light = torch.tensor([1.0625, -1.0625, 4.0])
    lights = torch.stack([cam, target_light])
    img = kernels.render(d, n, r, s, lights, cam)[0, :, 0]  # [2, H, W]; red channel
    offs = kernels.highlight_offsets(target_light, cam, plane, (size, size))
    torch.testing.assert_close(offs, torch.tensor([8.5, 8.5]), rtol=0, atol=OFFSET_ATOL_F32)
    moved = kernels.translate(img[:1, None], offs[None])[0, 0]

    def peak(x):
        return divmod(int(x.argmax()), size)

    assert peak(img[1]) == (40, 40)
    pi, pj = peak(moved)
    assert abs(pi - 40) <= 1 and abs(pj - 40) <= 1, (pi, pj)
