"""Tiled relighting (``relight.tiling``): the tiles cover the photo, each is relit in its
own exact frame (a pixel-local relighter gives the whole-image result), and tiles that
disagree are blended without a step at their borders."""

import pytest
import torch

from relight.interface import get_relighter
from relight.tiling import blend_window, tile_starts, tiled_relight

#: A pixel-local relighter tiled must equal it on the whole image up to float32 rounding
#: of the window's positions ((p - c) * k, |p| <= ~40 units here): a few ulps of the light
#: direction, carried into the radiance relative to its largest value. Measured 3.1e-7;
#: 1e-5 keeps a 30x margin and is still 1,000x below what a misplaced window (one pixel
#: off: ~1e-2) gives.
LOCAL_TILING_RTOL = 1e-5


@pytest.mark.parametrize("size, tile, overlap", [(256, 64, 16), (100, 64, 16), (64, 64, 16), (200, 32, 0), (97, 32, 8)])
def test_tiles_cover_the_photo_with_at_least_the_overlap(size, tile, overlap):
    starts = tile_starts(size, tile, overlap)
    assert starts[0] == 0 and starts[-1] + tile == size
    assert all(b - a <= tile - overlap for a, b in zip(starts, starts[1:]))  # overlap >= asked
    assert all(b > a for a, b in zip(starts, starts[1:]))
    covered = torch.zeros(size, dtype=torch.bool)
    for s in starts:
        covered[s : s + tile] = True
    assert covered.all()


@pytest.mark.parametrize("args", [(32, 64, 8), (64, 64, 64), (64, 32, -1)])
def test_bad_tilings_are_refused(args):
    with pytest.raises(ValueError, match="need 0 <= overlap < tile <= size"):
        tile_starts(*args)


def test_blend_window_ramps_across_the_overlap_and_never_vanishes():
    w = blend_window(64, 16)
    assert torch.equal(w, w.flip(0)) and (w > 0).all()
    assert torch.equal(w[16:48], torch.ones(32))
    assert (w[1:17] > w[:16]).all()  # strictly rising over the overlap
    assert float(w[0]) == pytest.approx(1 / 17)


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
    starts = tile_starts(size, tile, overlap)
    values = [float(offset(photo, *_window(light, camera, 0, s, size, tile)[:2])[0, 0, 0, 0]) for s in starts]
    jumps = [abs(a - b) for a, b in zip(values, values[1:])]
    assert min(jumps) > 0.05  # the windows do disagree: the bound is not vacuous
    steps = (out[..., :, 1:] - out[..., :, :-1]).abs()
    assert float(steps.max()) <= max(jumps) / (overlap + 1) * (1 + 1e-4)  # float32 rounding of the blend
    hard = max(jumps)  # what pasting the tiles side by side would leave at a border
    print(f"largest step across tile borders: {float(steps.max()):.4f} (hard paste: {hard:.4f})")


def _window(light, camera, top, left, size, tile, plane=4.0):
    from materials.capture_domain import crop_geometry

    cx = ((left + tile / 2) / size - 0.5) * plane
    cy = -((top + tile / 2) / size - 0.5) * plane
    return crop_geometry(light, camera, (cx, cy), plane * tile / size, plane_size=plane)
