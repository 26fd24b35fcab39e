"""Relighting a larger photo from the whole plane at a model's native size
(``relight.detail``): exact for a flat diffuse material, the model's change arrives at
full size at the model's scale, and the shapes are checked."""

import pytest
import torch
import torch.nn.functional as F

import kernels
from kernels.presets import get_preset
from relight.detail import detail_relight
from relight.interface import get_relighter
from relight.shading import lambertian_relight

PRESET = get_preset("dgrsise")
#: float32 round trip through the tone map (x ** (1/2.2) then ** 2.2) of radiance in
#: [0.02, 1]: a few ulps relative; 1e-5 is 100x that and far below any real change.
TONEMAP_ROUND_TRIP_RTOL = 1e-5
#: The renderer's Fresnel (Schlick) is (1 - cos)^5 at F0 = 0, not zero, so a
#: "diffuse-only" render is not exactly Lambertian away from the flash: at these lights
#: 0.69 % at most (measured); 1 %.
SCHLICK_AT_ZERO_F0_RTOL = 0.01
#: Peak of the test's added spot in display units: small enough that the re-shading
#: plus the spot stays below the tone map's saturation (1) everywhere.
SPOT_PEAK = 0.1
#: Bilinear upsampling by 4 then area averaging back is the filter [1/8, 3/4, 1/8] on
#: each axis of the native grid, so it returns a smooth field up to (1/8) f'' per axis:
#: at the peak of a Gaussian of sigma 4 native pixels, 2 * (1/8) * peak / 16 = 1.6 % of
#: the peak (measured 1.5 %); 2 % of it.
SMOOTH_CHANGE_ATOL = 0.02 * SPOT_PEAK


def _diffuse_scene(size: int, seed: int = 0):
    """A diffuse-only material (specular 0) with a textured albedo under the flash and
    two target lights: ``photo [1, 3, S, S]``, ``target [1, 2, 3, S, S]`` (linear)."""
    gen = torch.Generator().manual_seed(seed)
    albedo = F.interpolate(torch.rand(1, 3, 8, 8, generator=gen), size=(size, size), mode="nearest") * 0.6 + 0.1
    normal = torch.zeros(1, 3, size, size)
    normal[:, 2] = 1
    rough = torch.full((1, 1, size, size), 0.5)
    spec = torch.zeros(1, 3, size, size)
    camera = torch.tensor([[0.0, 0.0, 4.5]])
    lights = torch.tensor([[[0.0, 0.0, 4.5], [2.0, -1.0, 4.0], [-1.5, 1.5, 5.0]]])
    images = kernels.render(albedo, normal, rough, spec, lights[0], camera[0])  # [1, 3, 3, S, S]
    return images[:, 0], images[:, 1:], lights[:, 1:], camera


def test_a_flat_diffuse_material_is_relit_exactly_at_full_size():
    # The Lambertian re-shading is exact for a flat diffuse material, so with it as the
    # "model" the residual is zero and the full-size output is the full-size re-shading,
    # texture and all; and that is the truth up to the Fresnel term the renderer keeps
    # at F0 = 0.
    photo, target, light, camera = _diffuse_scene(128)
    lamb = get_relighter("lambertian")
    out = detail_relight(lamb.relight, photo, light, camera, size=32, preset=PRESET)
    assert out.shape == target.shape
    full = lambertian_relight(photo, light, camera, PRESET)
    err = float(((out - full).abs() / full).max())
    truth = float(((out - target).abs() / target).max())
    print(f"flat diffuse, 32 -> 128 px: max relative error {err:.1e} to the re-shading, {truth:.1e} to the truth")
    assert err < TONEMAP_ROUND_TRIP_RTOL
    assert truth < SCHLICK_AT_ZERO_F0_RTOL
    # Upsampling the native output instead would lose the texture's edges.
    coarse = F.interpolate(
        lamb.relight(F.adaptive_avg_pool2d(photo, 32), light, camera).flatten(0, 1), size=(128, 128), mode="bilinear"
    )
    assert float(((coarse - target.flatten(0, 1)).abs() / target.flatten(0, 1)).max()) > 10 * SCHLICK_AT_ZERO_F0_RTOL


def test_the_model_s_change_reaches_the_full_size_output_at_its_scale():
    # A "model" that adds a smooth bright spot (a new highlight) to the re-shading in
    # display space: at full size the output differs from the full-size re-shading by
    # that spot, upsampled (area-averaged back to the native grid it is the spot again).
    photo, _, light, camera = _diffuse_scene(128)
    yy, xx = torch.meshgrid(torch.arange(32.0), torch.arange(32.0), indexing="ij")
    spot = SPOT_PEAK * torch.exp(-((yy - 10) ** 2 + (xx - 20) ** 2) / (2 * 4.0**2))

    def spotted(p, lp, cp):
        return kernels.inverse_tonemap(kernels.tonemap(lambertian_relight(p, lp, cp, PRESET)) + spot)

    out = detail_relight(spotted, photo, light, camera, size=32, preset=PRESET)
    change = kernels.tonemap(out) - kernels.tonemap(lambertian_relight(photo, light, camera, PRESET))
    back = F.avg_pool2d(change.flatten(0, 1), 4)
    err = float((back - spot).abs().max())
    print(f"spot of peak {SPOT_PEAK} carried to 128 px: max error on the native grid {err:.4f}")
    assert err < SMOOTH_CHANGE_ATOL
    assert float(change[..., 40, 80].min()) > 0.9 * SPOT_PEAK  # the spot's centre (10, 20) * 4 is bright at full size


def test_the_native_size_is_one_call_and_bad_shapes_are_refused():
    photo, _, light, camera = _diffuse_scene(32)
    calls = []

    def native(p, lp, cp):
        calls.append(p.shape[-1])
        return p[:, None].expand(-1, lp.shape[1], -1, -1, -1)

    out = detail_relight(native, photo, light, camera, size=32, preset=PRESET)
    assert calls == [32] and torch.equal(out[:, 0], photo)
    for bad in (torch.rand(1, 3, 16, 16), torch.rand(1, 3, 32, 48)):
        with pytest.raises(ValueError, match="square with a side of at least 32"):
            detail_relight(native, bad, light, camera, size=32, preset=PRESET)


def test_bieron_relighter_takes_the_global_mode(tiny_checkpoint):
    # The network relighter's "global" mode runs the network once at its native size.
    relighter = get_relighter("bieron", tiny_checkpoint)
    assert relighter.large == "whole"
    sizes = []
    network = relighter._network
    relighter._network = lambda p, lp, cp: sizes.append(p.shape[-1]) or network(p, lp, cp)
    photo, _, light, camera = _diffuse_scene(64)
    whole = relighter.relight(photo, light, camera)
    relighter.large, relighter.native_size = "global", 16
    glob = relighter.relight(photo, light, camera)
    assert sizes == [64, 16] and glob.shape == whole.shape and torch.isfinite(glob).all()
    with pytest.raises(ValueError, match="large must be one of"):
        type(relighter)(relighter.model, large="tiles")
