"""Windows of a photographed plane (``materials.windows``): they cover the photo with the
asked overlap, each window's centre and side put it where its pixels are (rendering the
window in its own frame gives the crop of the whole render), and the blend weights ramp
across the overlaps."""

import pytest
import torch

import kernels
from materials.capture_domain import crop_geometry
from materials.procedural import generate
from materials.types import Material
from materials.windows import TileBlend, blend_window, plane_windows, tile_starts

#: A window rendered in its own frame against the crop of the whole render, float64: the
#: same expressions on positions that differ by a few ulps after ``(p - c) * k`` (1e-16
#: relative), amplified by GGX peaks at most ~1e4 at roughness >= 0.2 (the crop test of
#: ``test_capture_domain.py`` has the same bound); a window one pixel off gives ~1e-2.
WINDOW_RTOL = 1e-9


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


def test_a_window_rendered_in_its_frame_is_the_crop_of_the_whole_render():
    size, tile, plane = 48, 16, 4.0
    m = generate(3, size=size).to(torch.float64)
    material = Material(m.diffuse, m.normal, m.roughness.clamp_min(0.2), m.specular)
    light = torch.tensor([[0.3, -0.2, 4.5], [3.0, 1.0, 6.0]], dtype=torch.float64)
    camera = torch.tensor([[0.3, -0.2, 4.5], [0.3, -0.2, 4.5]], dtype=torch.float64)
    whole = kernels.render(*(t[None] for t in material.map_tensors()), light, camera)[0]
    windows = plane_windows(size, tile, 4, plane)
    assert len(windows) == 16 and windows[0].side == pytest.approx(plane * tile / size)
    for w in windows:
        l2, c2, _ = crop_geometry(light, camera, w.center, w.side, plane_size=plane)
        crop = material.crop(w.top, w.left, tile, tile)
        seen = kernels.render(*(t[None] for t in crop.map_tensors()), l2, c2)[0]
        expected = whole[..., w.top : w.top + tile, w.left : w.left + tile]
        torch.testing.assert_close(seen, expected, rtol=WINDOW_RTOL, atol=0.0)


def test_blend_of_agreeing_windows_is_their_common_value():
    size, tile, overlap = 80, 32, 8
    truth = torch.rand(2, size, size, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    blend = TileBlend(size, tile, overlap, dtype=torch.float64)
    for w in plane_windows(size, tile, overlap, 4.0):
        blend.add(w, truth[:, w.top : w.top + tile, w.left : w.left + tile])
    torch.testing.assert_close(blend.result(), truth, rtol=1e-14, atol=0.0)
    with pytest.raises(ValueError, match="must be"):
        blend.add(plane_windows(size, tile, overlap, 4.0)[0], truth[:, :16, :16])
    with pytest.raises(ValueError, match="no window"):
        TileBlend(size, tile, overlap).result()
