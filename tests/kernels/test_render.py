"""kernels.render and kernels.lvh_maps against their pure-torch twins in kernels.reference:
forward values for every preset, override, broadcast shape, size, batch, light count and
dtype; random-cotangent VJPs for the four maps and both positions; float64 gradcheck;
gradients that are alive and point where the reference's do; the float32 error at the
roughness floor under the highlight.

Float32 results are held against the float64 twin on the same inputs, within the error
bound ``kernels.reference.render_rtol`` (and its VJP form in conftest.py), not against
the float32 twin with a tolerance measured on one CPU: rounding differs between CPUs
(FMA contraction, vector widths), the bound does not.
"""

from __future__ import annotations

import pytest
import torch

import kernels
from kernels import reference
from kernels._autograd import _shading_chunks
from kernels.reference import UNIT_ROUNDOFF

#: The two backward paths (hand-written map gradients, Warp's generated adjoint) are both
#: float64 evaluations of the same derivative, each within the VJP bound of the exact
#: value (conftest ``_vjp_rtol``: 2 x render_rtol(float64, 0.15) + 4^1.5 u ~ 5e-13, with
#: n_sum = 4 lights): 1e-12 relative to the largest entry covers twice that.
PATHS_RTOL_F64 = 1e-12
#: l, v and h against the twin, in units of the dtype's u: l and v are within ~4u of the
#: exact direction, h within ~8u (render_rtol's docstring), per component; kernel and twin
#: each, so at most 16u apart.
LVH_ULPS = 16
#: |l|, |v|, |h| - 1: x / sqrt(x.x + 1e-12) is within ~4u of unit length (three squares
#: summed, a square root, a division), the test's own norm adds ~3u: 8u in all, plus
#: 0.5e-12 / |x|^2 from the epsilon (|l + v| >= 1 here).
UNIT_ULPS = 8
UNIT_EPS_TERM = 0.5e-12
NAMES = ("diffuse", "normal", "roughness", "specular", "light_pos", "camera_pos")


@pytest.fixture
def scene(make_maps, make_positions):
    """Factory: ``scene(B, H, W, K, ...)`` -> (maps, light [B, K, 3], camera [B, K, 3])."""

    def build(b, h, w, k, *, dtype=torch.float32, device="cpu", plane_size=4.0, requires_grad=False):
        maps = make_maps(b, h, w, dtype=dtype, device=device, requires_grad=requires_grad)
        light = make_positions(
            (b, k), plane_size=plane_size, dtype=dtype, device=device, seed=2, requires_grad=requires_grad
        )
        camera = make_positions(
            (b, k), plane_size=plane_size, dtype=dtype, device=device, seed=3, requires_grad=requires_grad
        )
        return maps, light, camera

    return build


# --------------------------------------------------------------------------- forward
@pytest.mark.parametrize("preset", sorted(kernels.PRESETS))
def test_forward_matches_reference_for_every_preset(preset, dtype, device, scene, assert_render_accurate):
    plane = kernels.get_preset(preset).plane_size
    maps, light, camera = scene(2, 7, 13, 3, dtype=dtype, device=device, plane_size=plane)
    out = kernels.render(*maps, light, camera, preset=preset)
    assert out.shape == (2, 3, 3, 7, 13) and out.device.type == device
    assert_render_accurate(out, maps, light, camera, preset, preset=preset)
    assert bool((out >= 0).all())


@pytest.mark.parametrize(
    "overrides",
    [
        {"plane_size": 3.0},
        {"intensity": 2.5},
        {"intensity": (1.0, 2.0, 3.0)},
        {"inverse_square": True},
        {"roughness_floor": 0.4},
        {"plane_size": 6.0, "intensity": 10.0, "inverse_square": True},
    ],
    ids=lambda o: "-".join(o),
)
def test_forward_matches_reference_with_overrides(overrides, dtype, scene, assert_render_accurate):
    maps, light, camera = scene(2, 5, 6, 2, dtype=dtype)
    out = kernels.render(*maps, light, camera, **overrides)
    assert_render_accurate(out, maps, light, camera, str(overrides), **overrides)
    # The override changes the image (the test would be vacuous otherwise).
    assert not torch.equal(out, kernels.render(*maps, light, camera))


def test_preset_falloff_and_intensity_are_applied(scene):
    """materialgan = 1500 / d^2 per channel; an override back to dgrsise's values matches dgrsise."""
    maps, light, camera = scene(1, 4, 4, 2)
    mg = kernels.render(*maps, light, camera, preset="materialgan", plane_size=4.0)
    same = kernels.render(*maps, light, camera, preset="dgrsise", intensity=1500.0, inverse_square=True)
    torch.testing.assert_close(mg, same, rtol=0, atol=0)
    as_dgrsise = kernels.render(
        *maps, light, camera, preset="materialgan", plane_size=4.0, intensity=torch.pi, inverse_square=False
    )
    torch.testing.assert_close(as_dgrsise, kernels.render(*maps, light, camera), rtol=0, atol=0)


@pytest.mark.parametrize("b,h,w,k", [(1, 1, 1, 1), (1, 7, 13, 5), (3, 7, 13, 1), (3, 1, 1, 5), (3, 16, 9, 5)])
def test_forward_sizes_batches_and_light_counts(b, h, w, k, dtype, scene, assert_render_accurate):
    maps, light, camera = scene(b, h, w, k, dtype=dtype)
    out = kernels.render(*maps, light, camera)
    assert out.shape == (b, k, 3, h, w) and out.dtype == dtype
    assert_render_accurate(out, maps, light, camera, f"{b}x{h}x{w} K={k}")


def test_thread_split_paths_are_exercised():
    """With two threads (conftest), B=1 splits image rows and B>=2 splits the batch."""
    cpu = torch.device("cpu")
    assert _shading_chunks(1, 7, cpu) == ("rows", [(0, 4), (4, 3)])
    assert _shading_chunks(3, 7, cpu)[0] == "batch"


@pytest.mark.parametrize("light_shape", ["K3", "BK3"])
@pytest.mark.parametrize("camera_shape", ["3", "13", "K3", "BK3"])
def test_forward_broadcast_positions(
    light_shape, camera_shape, dtype, device, scene, make_positions, assert_render_accurate
):
    b, k = 3, 4
    maps, light_full, _ = scene(b, 5, 6, k, dtype=dtype, device=device)
    light = light_full[0] if light_shape == "K3" else light_full
    cam = torch.tensor([0.3, -0.2, 4.5], dtype=dtype, device=device)
    camera = {
        "3": cam,
        "13": cam[None],
        "K3": cam.expand(k, 3) + 0.1 * torch.arange(k, dtype=dtype, device=device)[:, None],
        "BK3": make_positions((b, k), dtype=dtype, device=device, seed=5),
    }[camera_shape]
    out = kernels.render(*maps, light, camera)
    assert_render_accurate(out, maps, light, camera, "broadcast")
    # Broadcasting is exactly the explicit [B, K, 3] expansion.
    explicit = kernels.render(*maps, light.expand(b, k, 3), camera.expand(b, k, 3))
    torch.testing.assert_close(out, explicit, rtol=0, atol=0)


# --------------------------------------------------------------------------- VJP
@pytest.mark.parametrize("positions_grad", [True, False], ids=["adjoint", "maps-only"])
@pytest.mark.parametrize("b", [1, 3])
def test_vjp_matches_reference(b, positions_grad, dtype, device, scene, assert_vjp_accurate):
    """Both backward paths: Warp's generated adjoint (positions need gradients) and the
    hand-written map gradients (they do not)."""
    h, w = 7, 13
    maps, light, camera = scene(b, h, w, 5, dtype=dtype, device=device, requires_grad=True)
    if not positions_grad:
        light, camera = light.detach(), camera.detach()
    cot = torch.randn((b, 5, 3, h, w), generator=torch.Generator().manual_seed(7), dtype=torch.float64)
    # Longest sum: a [B, K, 3] position gradient entry sums over the H * W pixels.
    assert_vjp_accurate([*maps, light, camera], cot.to(dtype=dtype, device=device), h * w)


def test_vjp_with_broadcast_positions(dtype, make_maps, make_positions, assert_vjp_accurate):
    """Gradients of broadcast positions ([K, 3] light, [3] camera) sum over the batch."""
    b, k, h, w = 3, 4, 6, 5
    maps = make_maps(b, h, w, dtype=dtype, requires_grad=True)
    light = make_positions((k,), dtype=dtype, seed=2, requires_grad=True)
    camera = torch.tensor([0.1, 0.2, 5.0], dtype=dtype, requires_grad=True)
    inputs = [*maps, light, camera]
    out = kernels.render(*inputs)
    grads = torch.autograd.grad(out.sum(), [light, camera])
    assert grads[0].shape == light.shape and grads[1].shape == camera.shape
    cot = torch.randn(out.shape, generator=torch.Generator().manual_seed(8), dtype=torch.float64).to(dtype)
    # Longest sum: the [3] camera gradient sums over batch, lights and pixels.
    assert_vjp_accurate(inputs, cot, b * k * h * w)


@pytest.mark.parametrize("positions_grad", [True, False], ids=["adjoint", "maps-only"])
@pytest.mark.parametrize("preset", ["dgrsise", "materialgan"])
def test_gradcheck_float64(preset, positions_grad, make_maps, make_positions):
    plane = kernels.get_preset(preset).plane_size
    maps = make_maps(2, 3, 4, dtype=torch.float64, seed=11, requires_grad=True)
    light = make_positions((2, 2), plane_size=plane, dtype=torch.float64, seed=12, requires_grad=positions_grad)
    camera = make_positions((2,), plane_size=plane, dtype=torch.float64, seed=13, requires_grad=positions_grad)

    if positions_grad:
        fn, inputs = (lambda *args: kernels.render(*args, preset=preset)), (*maps, light, camera)
    else:
        fn, inputs = (lambda *args: kernels.render(*args, light, camera, preset=preset)), tuple(maps)
    assert torch.autograd.gradcheck(fn, inputs, eps=1e-6, atol=1e-7, rtol=1e-5)


def test_backward_paths_agree_on_map_gradients(make_maps, make_positions, assert_close_to_max):
    """The hand-written map gradients equal Warp's generated adjoint (float64)."""
    maps = make_maps(2, 9, 11, dtype=torch.float64, seed=21, requires_grad=True)
    light = make_positions((2, 4), dtype=torch.float64, seed=22)
    camera = make_positions((4,), dtype=torch.float64, seed=23)
    cot = torch.randn(2, 4, 3, 9, 11, generator=torch.Generator().manual_seed(24), dtype=torch.float64)
    fast = torch.autograd.grad(kernels.render(*maps, light, camera), maps, cot)
    generated = torch.autograd.grad(kernels.render(*maps, light.requires_grad_(), camera.requires_grad_()), maps, cot)
    for name, a, b in zip(NAMES, fast, generated):
        assert_close_to_max(a, b, PATHS_RTOL_F64, name)


# --------------------------------------------------------------------------- l, v, h maps
def test_lvh_maps_match_reference_and_are_unit(dtype, device, make_positions, assert_close_to_max):
    light = make_positions((2, 3), dtype=dtype, device=device, seed=4)
    camera = make_positions((2, 3), dtype=dtype, device=device, seed=5)
    lvh = kernels.lvh_maps(light, camera, (5, 7))
    ref = reference.lvh_maps(light, camera, (5, 7))
    assert lvh.shape == (2, 3, 9, 5, 7) and not lvh.requires_grad
    u = UNIT_ROUNDOFF[dtype]
    assert_close_to_max(lvh, ref, LVH_ULPS * u, "lvh")
    norms = lvh.view(2, 3, 3, 3, 5, 7).norm(dim=3)
    torch.testing.assert_close(norms, torch.ones_like(norms), rtol=0, atol=UNIT_ULPS * u + UNIT_EPS_TERM)


def test_lvh_maps_broadcast_camera_and_plane_size(make_positions, assert_close_to_max):
    light = make_positions((4,), dtype=torch.float64, seed=4)
    camera = torch.tensor([0.0, 0.0, 4.0], dtype=torch.float64)
    lvh = kernels.lvh_maps(light, camera, (3, 8), plane_size=2.0)
    assert lvh.shape == (1, 4, 9, 3, 8)
    ref = reference.lvh_maps(light, camera, (3, 8), plane_size=2.0)
    assert_close_to_max(lvh, ref, LVH_ULPS * UNIT_ROUNDOFF[torch.float64])
    # The view vector above the plane centre's pixels points up and towards the camera.
    v = lvh[0, 0, 3:6]
    assert bool((v[2] > 0).all())
    assert bool((v[0, :, :4] > 0).all()) and bool((v[0, :, 4:] < 0).all())  # left half looks right


def test_render_return_lvh_matches_lvh_maps(scene, assert_close_to_max, assert_render_accurate):
    maps, light, camera = scene(2, 4, 6, 3)
    out, lvh = kernels.render(*maps, light, camera, return_lvh=True)
    torch.testing.assert_close(out, kernels.render(*maps, light, camera), rtol=0, atol=0)
    torch.testing.assert_close(lvh, kernels.lvh_maps(light, camera, (4, 6)), rtol=0, atol=0)
    _, ref_lvh = reference.render(*maps, light, camera, return_lvh=True)
    assert_render_accurate(out, maps, light, camera, "radiance")
    assert_close_to_max(lvh, ref_lvh, LVH_ULPS * UNIT_ROUNDOFF[torch.float32], "lvh")


# --------------------------------------------------------------------------- float32 at the floor
@pytest.mark.parametrize("impl", ["kernel", "reference"])
def test_float32_error_at_the_roughness_floor_under_the_highlight(impl, assert_close_to_max):
    """Roughness at the floor (alpha^2 ~ 1e-4) and pixels at the highlight peak (n.h ~ 1),
    where the textbook GGX denominator (n.h)^2 (alpha^2 - 1) + 1 cancels: with it, the
    float32 error here was 2.8e-3 of the peak (47,000 u, 9x the bound); with the
    cross-product form (kernels.brdf) 3.8e-6 (64 u). Both the kernel and the twin, against
    float64."""
    floor = kernels.get_preset("dgrsise").roughness_floor
    size = 48
    g = torch.Generator().manual_seed(3)
    # Normals tilted by up to ~3 degrees around +z: the peak falls on many pixels, at
    # n.h within 1e-3 of 1, with every sub-ulp detail of the tilt in the float32 inputs.
    tilt = (torch.rand(1, 2, size, size, generator=g, dtype=torch.float64) * 2 - 1) * 0.05
    normal = torch.cat([tilt, torch.ones(1, 1, size, size, dtype=torch.float64)], 1)
    maps = [
        torch.full((1, 3, size, size), 0.2, dtype=torch.float64),
        normal / normal.norm(dim=1, keepdim=True),
        torch.full((1, 1, size, size), floor, dtype=torch.float64),
        torch.full((1, 3, size, size), 0.9, dtype=torch.float64),
    ]
    maps32 = [t.float() for t in maps]
    # Co-located light and camera above a grid of points: h ~ l ~ v, the peak where n ~ l.
    light = torch.tensor([[[0.3, -0.2, 4.0], [-1.1, 0.7, 5.0]]], dtype=torch.float32)
    render = kernels.render if impl == "kernel" else reference.render
    out = render(*maps32, light, light)
    exact = reference.render(*(t.double() for t in maps32), light.double(), light.double())
    peak = exact.amax()
    assert float(peak) > 100 * float(exact.median()), "the test must see the highlight peak"
    assert_close_to_max(out.double(), exact, reference.render_rtol(torch.float32, floor), impl)


def test_pixel_layout_row0_is_plus_y():
    """A light above the top-left quadrant lights the top-left pixels most (SPEC: row 0 is +y)."""
    d = torch.full((1, 3, 8, 8), 0.5)
    n = torch.zeros(1, 3, 8, 8)
    n[:, 2] = 1
    r, s = torch.full((1, 1, 8, 8), 0.9), torch.zeros(1, 3, 8, 8)
    img = kernels.render(
        d, n, r, s, torch.tensor([[-1.3, 1.3, 1.0]]), torch.tensor([0.0, 0.0, 4.0]), inverse_square=True
    )[0, 0, 0]
    i, j = divmod(int(img.argmax()), 8)
    assert (i, j) == (1, 1)  # pixel centre (-1.25, 1.25) is nearest to (-1.3, 1.3)
