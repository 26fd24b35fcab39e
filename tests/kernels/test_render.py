"""kernels.render and kernels.lvh_maps against their pure-torch twins in kernels.reference:
forward values for every preset, override, broadcast shape, size, batch, light count and
dtype; random-cotangent VJPs for the four maps and both positions; float64 gradcheck;
gradients that are alive and point where the reference's do.
"""

from __future__ import annotations

import pytest
import torch

import kernels
from kernels import reference
from kernels._autograd import _shading_chunks

#: Forward, float32: both sides evaluate the same expressions in float32, differing only
#: in operation order and fused ops (measured ~1e-7 of the largest value); 1e-5 leaves
#: headroom for a few ulps of accumulated rounding.
FWD_RTOL_F32 = 1e-5
#: Forward, float64: the same argument with float64 rounding (measured ~1e-16).
FWD_RTOL_F64 = 1e-12
#: VJP, float32, relative to the largest gradient entry: per the kernels issue, float32
#: cancellation near specular peaks (measured ~1e-6 on this data).
VJP_RTOL_F32 = 1e-3
#: VJP, float64: float64 rounding of the same adjoint expressions (measured ~1e-15).
VJP_RTOL_F64 = 1e-10
#: The two backward paths (hand-written map gradients, Warp's generated adjoint) agree to
#: float64 rounding of differently ordered sums over the lights.
PATHS_RTOL_F64 = 1e-10
#: l/v/h vectors are unit length up to the 1e-12 epsilon under the normalising square
#: root and float32 rounding of three squares.
UNIT_ATOL_F32 = 1e-6

FWD_RTOL = {torch.float32: FWD_RTOL_F32, torch.float64: FWD_RTOL_F64}
VJP_RTOL = {torch.float32: VJP_RTOL_F32, torch.float64: VJP_RTOL_F64}
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
def test_forward_matches_reference_for_every_preset(preset, dtype, device, scene, assert_close_to_max):
    plane = kernels.get_preset(preset).plane_size
    maps, light, camera = scene(2, 7, 13, 3, dtype=dtype, device=device, plane_size=plane)
    out = kernels.render(*maps, light, camera, preset=preset)
    ref = reference.render(*maps, light, camera, preset=preset)
    assert out.shape == (2, 3, 3, 7, 13) and out.device.type == device
    assert_close_to_max(out, ref, FWD_RTOL[dtype], preset)
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
def test_forward_matches_reference_with_overrides(overrides, dtype, scene, assert_close_to_max):
    maps, light, camera = scene(2, 5, 6, 2, dtype=dtype)
    out = kernels.render(*maps, light, camera, **overrides)
    ref = reference.render(*maps, light, camera, **overrides)
    assert_close_to_max(out, ref, FWD_RTOL[dtype], str(overrides))
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
def test_forward_sizes_batches_and_light_counts(b, h, w, k, dtype, scene, assert_close_to_max):
    maps, light, camera = scene(b, h, w, k, dtype=dtype)
    out = kernels.render(*maps, light, camera)
    assert out.shape == (b, k, 3, h, w) and out.dtype == dtype
    assert_close_to_max(out, reference.render(*maps, light, camera), FWD_RTOL[dtype], f"{b}x{h}x{w} K={k}")


def test_thread_split_paths_are_exercised():
    """With two threads (conftest), B=1 splits image rows and B>=2 splits the batch."""
    cpu = torch.device("cpu")
    assert _shading_chunks(1, 7, cpu) == ("rows", [(0, 4), (4, 3)])
    assert _shading_chunks(3, 7, cpu)[0] == "batch"


@pytest.mark.parametrize("light_shape", ["K3", "BK3"])
@pytest.mark.parametrize("camera_shape", ["3", "13", "K3", "BK3"])
def test_forward_broadcast_positions(
    light_shape, camera_shape, dtype, device, scene, make_positions, assert_close_to_max
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
    assert_close_to_max(out, reference.render(*maps, light, camera), FWD_RTOL[dtype], "broadcast")
    # Broadcasting is exactly the explicit [B, K, 3] expansion.
    explicit = kernels.render(*maps, light.expand(b, k, 3), camera.expand(b, k, 3))
    torch.testing.assert_close(out, explicit, rtol=0, atol=0)


# --------------------------------------------------------------------------- VJP
@pytest.mark.parametrize("positions_grad", [True, False], ids=["adjoint", "maps-only"])
@pytest.mark.parametrize("b", [1, 3])
def test_vjp_matches_reference(b, positions_grad, dtype, device, scene, assert_close_to_max, assert_grad_alive):
    """Both backward paths: Warp's generated adjoint (positions need gradients) and the
    hand-written map gradients (they do not)."""
    maps, light, camera = scene(b, 7, 13, 5, dtype=dtype, device=device, requires_grad=True)
    if not positions_grad:
        light, camera = light.detach(), camera.detach()
    inputs = [*maps, light, camera] if positions_grad else list(maps)
    out = kernels.render(*maps, light, camera)
    ref = reference.render(*maps, light, camera)
    cot = torch.randn(out.shape, generator=torch.Generator().manual_seed(7), dtype=torch.float64)
    cot = cot.to(dtype=dtype, device=device)
    grads = torch.autograd.grad(out, inputs, cot)
    ref_grads = torch.autograd.grad(ref, inputs, cot)
    for name, g, r in zip(NAMES, grads, ref_grads):
        assert_close_to_max(g, r, VJP_RTOL[dtype], name)
        assert_grad_alive(g, r, name)


def test_vjp_with_broadcast_positions(dtype, make_maps, make_positions, assert_close_to_max, assert_grad_alive):
    """Gradients of broadcast positions ([K, 3] light, [3] camera) sum over the batch."""
    maps = make_maps(3, 6, 5, dtype=dtype, requires_grad=True)
    light = make_positions((4,), dtype=dtype, seed=2, requires_grad=True)
    camera = torch.tensor([0.1, 0.2, 5.0], dtype=dtype, requires_grad=True)
    inputs = [*maps, light, camera]
    out, ref = kernels.render(*inputs), reference.render(*inputs)
    cot = torch.randn(out.shape, generator=torch.Generator().manual_seed(8), dtype=torch.float64).to(dtype)
    for name, g, r in zip(NAMES, torch.autograd.grad(out, inputs, cot), torch.autograd.grad(ref, inputs, cot)):
        assert g.shape == r.shape
        assert_close_to_max(g, r, VJP_RTOL[dtype], name)
        assert_grad_alive(g, r, name)


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


def test_backward_paths_agree_on_map_gradients(make_maps, make_positions):
    """The hand-written map gradients equal Warp's generated adjoint (float64)."""
    maps = make_maps(2, 9, 11, dtype=torch.float64, seed=21, requires_grad=True)
    light = make_positions((2, 4), dtype=torch.float64, seed=22)
    camera = make_positions((4,), dtype=torch.float64, seed=23)
    cot = torch.randn(2, 4, 3, 9, 11, generator=torch.Generator().manual_seed(24), dtype=torch.float64)
    fast = torch.autograd.grad(kernels.render(*maps, light, camera), maps, cot)
    generated = torch.autograd.grad(kernels.render(*maps, light.requires_grad_(), camera.requires_grad_()), maps, cot)
    for name, a, b in zip(NAMES, fast, generated):
        torch.testing.assert_close(a, b, rtol=PATHS_RTOL_F64, atol=0, msg=name)


# --------------------------------------------------------------------------- l, v, h maps
def test_lvh_maps_match_reference_and_are_unit(dtype, device, make_positions, assert_close_to_max):
    light = make_positions((2, 3), dtype=dtype, device=device, seed=4)
    camera = make_positions((2, 3), dtype=dtype, device=device, seed=5)
    lvh = kernels.lvh_maps(light, camera, (5, 7))
    ref = reference.lvh_maps(light, camera, (5, 7))
    assert lvh.shape == (2, 3, 9, 5, 7) and not lvh.requires_grad
    assert_close_to_max(lvh, ref, FWD_RTOL[dtype], "lvh")
    norms = lvh.view(2, 3, 3, 3, 5, 7).norm(dim=3)
    atol = UNIT_ATOL_F32 if dtype == torch.float32 else 1e-12
    torch.testing.assert_close(norms, torch.ones_like(norms), rtol=0, atol=atol)


def test_lvh_maps_broadcast_camera_and_plane_size(make_positions, assert_close_to_max):
    light = make_positions((4,), dtype=torch.float64, seed=4)
    camera = torch.tensor([0.0, 0.0, 4.0], dtype=torch.float64)
    lvh = kernels.lvh_maps(light, camera, (3, 8), plane_size=2.0)
    assert lvh.shape == (1, 4, 9, 3, 8)
    assert_close_to_max(lvh, reference.lvh_maps(light, camera, (3, 8), plane_size=2.0), FWD_RTOL_F64)
    # The view vector above the plane centre's pixels points up and towards the camera.
    v = lvh[0, 0, 3:6]
    assert bool((v[2] > 0).all())
    assert bool((v[0, :, :4] > 0).all()) and bool((v[0, :, 4:] < 0).all())  # left half looks right


def test_render_return_lvh_matches_lvh_maps(scene, assert_close_to_max):
    maps, light, camera = scene(2, 4, 6, 3)
    out, lvh = kernels.render(*maps, light, camera, return_lvh=True)
    torch.testing.assert_close(out, kernels.render(*maps, light, camera), rtol=0, atol=0)
    torch.testing.assert_close(lvh, kernels.lvh_maps(light, camera, (4, 6)), rtol=0, atol=0)
    ref_out, ref_lvh = reference.render(*maps, light, camera, return_lvh=True)
    assert_close_to_max(out, ref_out, FWD_RTOL_F32, "radiance")
    assert_close_to_max(lvh, ref_lvh, FWD_RTOL_F32, "lvh")


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
