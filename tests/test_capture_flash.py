"""``matcap.capture.flash.locate_flash`` and ``CaptureConfig.flash_point``: the located
point on synthetic flash photos, the cases where the centre must be kept, the mapping to
a non-square photo's pixels, and the pipeline's camera over the located point."""

from __future__ import annotations

import math

import pytest
import torch

import kernels
from estimator.config import TINY_TEST_CONFIG
from estimator.model import SVBRDFEstimator
from matcap.capture import CaptureConfig, CapturePipeline, FlashPoint, locate_flash
from matcap.capture.flash import MIN_CONTRAST
from matcap.capture_eval import CaptureEvalConfig, as_8bit, photo_render_kwargs
from materials.frame import prepare_photo
from materials.types import Material

#: Plane units (side 4). On a uniform glossy sample the blurred peak is symmetric about
#: the point under the flash but for the reflected borders of the blur, which pull it
#: towards the centre by up to 0.03 for a point 1.1 units off-centre (roughness 0.5;
#: 0.006 at roughness 0.15), about one pixel of the locator's 128 px grid (0.031).
LOCATE_TOL = 0.05
#: Photo pixels: cutting a photo's sides changes the copy the locator blurs (its grid and
#: its borders), so the same highlight may move by a pixel of that grid (128 px here).
CROP_TOL = 1.5
SIDE = 128
HEIGHT = 2 / math.tan(math.radians(22.5))  # the default camera: 45 degrees over the side-4 plane


def glossy_photo(offset: tuple[float, float], side: int = SIDE, roughness: float = 0.3) -> torch.Tensor:
    """``[3, side, side]``: an 8-bit flash photo (1/d^2) of a uniform glossy sample, the
    camera and flash above ``offset``, with a faint albedo texture."""
    g = torch.Generator().manual_seed(1)
    texture = 1 + 0.1 * torch.nn.functional.interpolate(torch.rand(1, 1, 8, 8, generator=g) - 0.5, size=(side, side))
    material = Material(
        0.3 * texture[0].expand(3, side, side).contiguous(),
        torch.tensor([0.0, 0.0, 1.0]).view(3, 1, 1).expand(3, side, side).contiguous(),
        torch.full((1, side, side), roughness),
        torch.full((3, side, side), 0.04),
    )
    camera = torch.tensor([*offset, HEIGHT])
    # photo_render_kwargs: the evaluation's (and relight capture's) flash convention.
    render = kernels.render(
        *(t[None] for t in material.map_tensors()), camera[None, None], camera, **photo_render_kwargs(camera)
    )
    return as_8bit(render[0, 0])


def plane_point(point: FlashPoint, image: torch.Tensor) -> tuple[float, float]:
    return point.plane_point(prepare_photo(image)[1])


@pytest.mark.parametrize("offset", [(0.0, 0.0), (0.6, -0.4), (-0.9, 0.7)])
@pytest.mark.parametrize("roughness", [0.15, 0.5])
def test_the_point_under_the_flash_is_found(offset, roughness):
    image = glossy_photo(offset, roughness=roughness)
    point = locate_flash(image)
    assert point.found and point.contrast >= MIN_CONTRAST
    x, y = plane_point(point, image)
    assert math.hypot(x - offset[0], y - offset[1]) < LOCATE_TOL


def test_a_photo_without_a_clear_highlight_keeps_the_centre():
    flat = torch.full((3, 96, 80), 0.2)
    point = locate_flash(flat)
    assert not point.found and (point.row, point.col) == (47.5, 39.5) and point.contrast == pytest.approx(0.0)


def test_a_bright_patch_outside_the_window_is_not_a_highlight():
    # Brightest at a corner: the window's maximum sits on its edge (brightness rising
    # outwards), which is texture, not the flash.
    image = torch.full((3, SIDE, SIDE), 0.1)
    image[:, :36, :36] = 2.0
    point = locate_flash(image)
    assert not point.found and point.contrast > MIN_CONTRAST


def test_the_point_is_on_the_photos_own_pixel_grid():
    square = glossy_photo((0.5, 0.3))
    full = locate_flash(square)
    cut = locate_flash(square[:, :, 16:112])  # 128 x 96: columns 16 and up kept
    assert full.found and cut.found
    assert abs(cut.row - full.row) < CROP_TOL and abs(cut.col - (full.col - 16)) < CROP_TOL
    # A photo of 4x the pixels: the same point, on its grid.
    big = torch.nn.functional.interpolate(square[None], scale_factor=4, mode="nearest")[0]
    large = locate_flash(big)
    assert abs((large.row + 0.5) / 4 - (full.row + 0.5)) < CROP_TOL
    assert abs((large.col + 0.5) / 4 - (full.col + 0.5)) < CROP_TOL


def test_bad_images_are_refused():
    with pytest.raises(ValueError, match=r"\[3, H, W\]"):
        locate_flash(torch.rand(1, 32, 32))
    with pytest.raises(ValueError, match="at least 16"):
        locate_flash(torch.rand(3, 8, 64))


# ---------------------------------------------------------------------- the pipeline
@pytest.fixture(scope="module")
def tiny_estimator():
    torch.manual_seed(0)
    return SVBRDFEstimator(**TINY_TEST_CONFIG.to_dict()).eval()


def test_auto_puts_the_camera_over_the_located_point(tiny_estimator):
    image = glossy_photo((0.6, -0.4))
    auto = CapturePipeline(None, tiny_estimator, config=CaptureConfig(relit=0, refine_steps=0, flash_point="auto"))
    out = auto(image)
    x, y, z = out.scene.camera_pos.tolist()
    assert math.hypot(x - 0.6, y + 0.4) < LOCATE_TOL and z == pytest.approx(HEIGHT, abs=1e-3)
    record = out.provenance["scene"]["flash_point"]
    assert record["found"] and record == out.scene.flash_point.to_dict()
    # The relit views' scene, the refinement and the re-renders use that camera.
    assert torch.equal(out.capture.camera_pos[0], out.scene.camera_pos)

    centred = CaptureConfig(relit=0, refine_steps=0, flash_point="centre")
    centre = CapturePipeline(None, tiny_estimator, config=centred)(image)
    assert centre.scene.camera_pos[:2].abs().max() < 1e-6 and centre.scene.flash_point is None
    # A camera given outright wins; nothing is located.
    given = CaptureConfig(relit=0, refine_steps=0, flash_point="auto", camera=(0.1, 0.2, 5.0))
    out = CapturePipeline(None, tiny_estimator, config=given)(image)
    assert out.scene.camera_pos.tolist() == pytest.approx([0.1, 0.2, 5.0]) and out.scene.flash_point is None


def test_settings_are_checked():
    with pytest.raises(ValueError, match="flash_point must be one of centre, auto"):
        CaptureConfig(flash_point="middle")
    with pytest.raises(ValueError, match="photo_offset must be two finite numbers"):
        CaptureEvalConfig(photo_offset=(float("nan"), 0.0))
    with pytest.raises(ValueError, match="photo_offset must be two finite numbers"):
        CaptureEvalConfig(photo_offset=(0.1,))  # type: ignore[arg-type]
