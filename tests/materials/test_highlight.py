"""The flash highlight region (``materials.highlight``): the disc on the plane and the
saturated pixels."""

import math

import pytest
import torch

from kernels.reference import plane_points
from materials.highlight import HIGHLIGHT_RADIUS, SATURATION, highlight_mask, plane_disc, saturated
from materials.lights import EVAL_CAMERA


def test_highlight_mask_covers_the_disc_under_the_camera():
    dark = torch.zeros(1, 3, 32, 32)
    mask = highlight_mask(dark, EVAL_CAMERA)
    assert mask.shape == (1, 1, 32, 32) and mask[0, 0, 16, 16] and not mask[0, 0, 0, 0]
    # The disc's area is pi r^2 in plane units: (4 / 32)^2 per pixel.
    pixels = math.pi * HIGHLIGHT_RADIUS**2 / (4 / 32) ** 2
    assert abs(int(mask.sum()) - pixels) < 0.1 * pixels
    bright = dark.clone()
    bright[..., 0, 0] = 5.0
    assert highlight_mask(bright, EVAL_CAMERA)[0, 0, 0, 0]


def test_plane_disc_follows_the_centre_and_the_pixel_grid():
    # An off-centre flash: the disc holds exactly the pixel centres within the radius,
    # on a non-square grid (SPEC section 2: row 0 is +y).
    disc = plane_disc((0.75, -0.5), 0.6, (24, 40), 4.0)
    p = plane_points(24, 40, 4.0, dtype=torch.float64)
    expected = (p[0] - 0.75) ** 2 + (p[1] + 0.5) ** 2 <= 0.36
    assert disc.shape == (24, 40) and torch.equal(disc, expected)
    rows, cols = disc.nonzero(as_tuple=True)
    assert p[1][rows, cols].mean() < 0 and p[0][rows, cols].mean() > 0  # below and right of centre
    assert not plane_disc((0.0, 0.0), 0.0, (16, 16), 4.0).any()  # no pixel centre at the origin


@pytest.mark.parametrize("value, hit", [(SATURATION**2.2 * 0.999, False), (SATURATION**2.2 * 1.001, True)])
def test_saturated_is_the_tone_mapped_threshold(value, hit):
    # The tone map is x^(1/2.2) on [0, 1], so the linear threshold is SATURATION^2.2;
    # one channel is enough.
    image = torch.zeros(1, 3, 2, 2)
    image[0, 2, 1, 1] = value
    assert bool(saturated(image)[0, 0, 1, 1]) is hit
    assert not saturated(image)[0, 0, 0, 0]
