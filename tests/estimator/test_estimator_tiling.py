"""Tiled estimation (``estimator.tiling.tiled_estimate``): every window is put in its exact
frame, so a pixel-local model tiled equals it run whole; the real network runs tiled at
any multiple of its window with the blend's seams bounded; bad calls are refused."""

from __future__ import annotations

import pytest
import torch
import torch.nn as nn
import torch.nn.functional as F

import kernels
from estimator.tiling import tiled_estimate
from materials.types import Material

#: A pixel-local model tiled vs whole: the windows' positions ``(p - c) * k`` differ from
#: the whole frame's by float32 rounding (a few ulps of |p| <= ~30 units), carried into
#: the unit directions the stand-in model outputs; measured ~3e-7. 1e-5 keeps a 30x
#: margin and is far below a window one pixel off (~1e-2 in the directions).
LOCAL_TILING_ATOL = 1e-5


class PixelLocal(nn.Module):
    """An estimator stand-in whose maps depend on each pixel's own inputs only: diffuse
    is view 0's light direction mapped to [0, 1], normal its view direction, roughness
    and specular the view-mean radiance. Tiling it is exact iff the windows' geometry is."""

    def __init__(self, plane_size: float = 4.0):
        super().__init__()
        self.config = type("Config", (), {"plane_size": plane_size})()
        self.downsample_factor = 16

    def forward(self, images, light_pos, camera_pos) -> Material:
        b, v, _, h, w = images.shape
        lvh = kernels.lvh_maps(light_pos, camera_pos, (h, w), plane_size=self.config.plane_size)
        light, view = lvh[:, 0, 0:3], lvh[:, 0, 3:6]
        mean = images.mean(dim=(1, 2))[:, None]
        return Material((light + 1) / 2, view, mean.clamp(0, 1), mean.expand(b, 3, h, w).clamp(0, 1))


def _views(size: int, views: int = 3, seed: int = 0):
    g = torch.Generator().manual_seed(seed)
    images = torch.rand(1, views, 3, size, size, generator=g)
    light = torch.cat([torch.rand(1, views, 2, generator=g) * 6 - 3, 4 + 2 * torch.rand(1, views, 1, generator=g)], -1)
    camera = torch.tensor([0.2, -0.1, 4.5]).expand(1, views, 3).clone()
    return images, light, camera


def test_a_pixel_local_model_tiled_equals_it_whole():
    model = PixelLocal()
    images, light, camera = _views(96)
    whole = model(images, light, camera)
    tiled = tiled_estimate(model, images, light, camera, tile=32, overlap=8, batch=5)
    for name, a, b in zip(("diffuse", "normal", "roughness", "specular"), tiled.map_tensors(), whole.map_tensors()):
        err = float((a - b).abs().max())
        print(f"{name}: max |tiled - whole| {err:.1e}")
        assert err < LOCAL_TILING_ATOL, name


def test_a_plane_in_other_units_is_mapped_to_the_models():
    # The same scene in centimetres (plane 17 cm) gives the same windows in model units.
    model = PixelLocal()
    images, light, camera = _views(64)
    k = 17.0 / 4.0
    model_units = tiled_estimate(model, images, light, camera, tile=32, overlap=8)
    cm = tiled_estimate(model, images, light * k, camera * k, tile=32, overlap=8, plane_size=17.0)
    torch.testing.assert_close(cm.stacked(), model_units.stacked(), atol=LOCAL_TILING_ATOL, rtol=0)


def test_the_network_tiled_gives_valid_maps_without_a_seam(tiny_model, random_views):
    images, light, camera = random_views(1, 2, size=64)
    out = tiled_estimate(tiny_model, images, light, camera, tile=32, overlap=8)
    assert out.diffuse.shape == (1, 3, 64, 64)
    torch.testing.assert_close(out.normal.norm(dim=1), torch.ones(1, 64, 64), atol=1e-5, rtol=0)
    assert float(out.normal[:, 2].min()) > 0
    # Seamless: no step across a window border is larger than the largest step inside a
    # window (the blend spreads the windows' disagreement over the overlap).
    with torch.no_grad():
        single = tiny_model(images[..., :32, :32], *_window_positions(light, camera))
    inside = (single.diffuse[..., 1:] - single.diffuse[..., :-1]).abs().max()
    steps = (out.diffuse[..., 1:] - out.diffuse[..., :-1]).abs()
    assert float(steps.max()) <= 2 * float(inside)


def _window_positions(light, camera):
    from materials.capture_domain import crop_geometry

    l2, c2, _ = crop_geometry(light, camera, (-1.0, 1.0), 2.0)
    return l2, c2


def test_one_window_is_the_whole_forward(tiny_model, random_views):
    images, light, camera = random_views(2, 3, size=32)
    with torch.no_grad():
        whole = tiny_model(images, light, camera)
    tiled = tiled_estimate(tiny_model, images, light, camera, tile=32)
    torch.testing.assert_close(tiled.diffuse, whole.diffuse)
    torch.testing.assert_close(tiled.normal, F.normalize(whole.normal, dim=1))


@pytest.mark.parametrize(
    "kwargs, message",
    [({"tile": 30}, "not a multiple"), ({"batch": 0}, "batch must be"), ({"tile": 32, "overlap": 40}, "overlap")],
)
def test_bad_tiling_is_refused(tiny_model, random_views, kwargs, message):
    images, light, camera = random_views(1, 1, size=64)
    with pytest.raises(ValueError, match=message):
        tiled_estimate(tiny_model, images, light, camera, **kwargs)
    with pytest.raises(ValueError, match="square"):
        tiled_estimate(tiny_model, images[..., :48], light, camera)
