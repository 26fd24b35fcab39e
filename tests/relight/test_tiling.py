"""Tiled relighting (``relight.tiling``): the tiles cover the photo, each is relit in its
own exact frame (a pixel-local relighter gives the whole-image result), and tiles that
disagree are blended without a step at their borders."""

import torch

from materials.capture_domain import crop_geometry
from materials.windows import plane_windows
from relight.interface import get_relighter
from relight.tiling import tiled_relight

#: A pixel-local relighter tiled must equal it on the whole image up to float32 rounding
#: of the window's positions ((p - c) * k, |p| <= ~40 units here): a few ulps of the light
#: direction, carried into the radiance relative to its largest value. Measured 3.1e-7;
#: 1e-5 keeps a 30x margin and is still 1,000x below what a misplaced window (one pixel
#: off: ~1e-2) gives.
LOCAL_TILING_RTOL = 1e-5


def _scene(size, k=3, seed=0):
    gen = torch.Generator().manual_seed(seed)
    photo = torch.rand(3, size, size, generator=gen) * 0.8 + 0.05
    light = torch.cat([torch.rand(k, 2, generator=gen) * 8 - 4, 4 + 4 * torch.rand(k, 1, generator=gen)], dim=1)
    camera = torch.tensor([0.3, -0.2, 4.5])
    return photo, light, camera


def test_a_pixel_local_relighter_tiled_equals_the_whole_image():
    # The Lambertian re-shading depends on each pixel's own l / v only, so if every window
    # is put in its exact frame, the tiles agree where they overlap and the blend returns
    # the whole-image result everywhere (borders included).
    lamb = get_relighter("lambertian")
    photo, light, camera = _scene(96)
    whole = lamb.relight(photo[None], light[None], camera[None])[0]

    def one(crop, light_t, camera_t):
        return lamb.relight(crop[None], light_t[None], camera_t[None])[0]

    tiled = tiled_relight(one, photo, light, camera, tile=32, overlap=8)
    err = float((tiled - whole).abs().max() / whole.abs().max())
    print(f"tiled vs whole (Lambertian): max relative error {err:.1e}")
    assert err < LOCAL_TILING_RTOL


def test_disagreeing_tiles_blend_without_a_step():
    # A relighter whose output has a different offset in every window (an extreme of what
    # a non-local model does): a hard paste would jump by the offset difference at a tile
    # border; the blend spreads it over the overlap in equal steps of 1 / (overlap + 1) of
    # it (the two ramps sum to 1 there). Tiles of 48 with an overlap of 16 have a flat
    # middle, as the default 64 / 16 do, so two transitions never stack.
    def offset(crop, light_t, camera_t):
        c = float(camera_t[0] * 0.1 + camera_t[1] * 0.07)  # differs per window
        return torch.full((light_t.shape[0], *crop.shape), c)

    size, tile, overlap = 112, 48, 16
    photo, light, camera = _scene(size)
    out = tiled_relight(offset, photo, light, camera, tile=tile, overlap=overlap)
    first_row = [w for w in plane_windows(size, tile, overlap, 4.0) if w.top == 0]
    values = [float(offset(photo, *crop_geometry(light, camera, w.center, w.side)[:2])[0, 0, 0, 0]) for w in first_row]
    jumps = [abs(a - b) for a, b in zip(values, values[1:])]
    assert min(jumps) > 0.05  # the windows do disagree: the bound is not vacuous
    steps = (out[..., :, 1:] - out[..., :, :-1]).abs()
    assert float(steps.max()) <= max(jumps) / (overlap + 1) * (1 + 1e-4)  # float32 rounding of the blend
    hard = max(jumps)  # what pasting the tiles side by side would leave at a border
    print(f"largest step across tile borders: {float(steps.max()):.4f} (hard paste: {hard:.4f})")
