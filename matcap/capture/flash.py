"""Where the flash was: the point of a flash photo under the camera and flash
(``locate_flash``), for photos whose highlight is not at the centre.

A phone's flash sits next to its lens, so on a flat sample both the specular highlight
(half vector = normal where light and view meet the plane head-on) and the brightest
diffuse point (cos / d^2 largest) lie at the foot of the camera. A photo taken a little
off-centre, or with the phone tilted, has that point away from the image centre; a
pipeline that assumes the centre renders its highlight in the wrong place and the
refinement puts what it cannot render into the maps (on held-out photos 0.72 plane
units off-centre: 1.3-3.8 dB of re-render PSNR lost, ``results/capture_flash_point/``).

The locator: the photo's log luminance on a copy of ``LOCATE_SIDE`` pixels, blurred by a
Gaussian wide enough to average texture (``BLUR_FRACTION``), and its maximum inside a
window around the centre (``MAX_OFFSET``). The peak is taken only when it is a clear one
(``MIN_CONTRAST`` above the photo's median) and inside the window, not on its edge (an
edge maximum means the brightness keeps rising outwards: a bright part of the texture,
not a highlight); otherwise the centre is kept. The thresholds were chosen on synthetic
flash photos of held-out materials with known camera positions and checked by eye on the
real photos of ``../shared/data/real-dev/photos`` (``results/capture_flash_point/``).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import torch
import torch.nn.functional as F
from kornia.filters import gaussian_blur2d

from materials.frame import Frame

__all__ = ["FlashPoint", "locate_flash", "LOCATE_SIDE", "BLUR_FRACTION", "MAX_OFFSET", "MIN_CONTRAST"]

#: Long side of the copy the locator works on, pixels: the peak is a low-frequency
#: feature, and 128 px keeps it well under a pixel's error at 4 plane units (0.03) and the
#: cost at a few milliseconds for any photo size.
LOCATE_SIDE = 128
#: Gaussian sigma as a fraction of the long side (17 px of 128): wide enough that the
#: texture's bright parts (bricks, pebbles, grain) average out and the flash's
#: low-frequency bump stays a single peak. On the synthetic photos of
#: ``results/capture_flash_point/`` 0.06 put the real-texture materials' "highlight" on
#: a bright brick (mean error 0.94 plane units against 0.46 for the centre), 0.13 left
#: them at the centre and halved the others' error; 0.16-0.2 missed real highlights.
#: A second, narrower search near the peak sharpened real photos' points and cost the
#: INRIA-format set accuracy (median error 0.06 -> 0.12-0.17), so there is none.
BLUR_FRACTION = 0.13
#: The highlight is looked for within this fraction of each side from the centre (the
#: middle 60 %): photos of a flat sample are framed around it; a peak beyond is more often
#: a bright part of the texture (a gold letter at the border of a sign) than the flash.
MAX_OFFSET = 0.3
#: Smallest peak height above the median of the blurred log luminance, natural log (0.3:
#: 35 % brighter). A matte sample under a phone flash at 45 degrees peaks at ~0.1 from the
#: falloff alone, too little to tell from its texture. At this blur the real photos' peaks
#: are 0.30-1.10 and the held-out metals' up to 2.9; the real-texture materials' bright
#: bricks and pebbles reach 0.10-0.34 (0.77 at the window's edge), one of them just above
#: the threshold (``results/capture_flash_point/``). Below it the centre is kept; the
#: matte materials of an off-centre photo then still lose up to 2 dB to a centred one.
MIN_CONTRAST = 0.3
_LUMA = (0.2126, 0.7152, 0.0722)
_LOG_EPS = 1e-3


@dataclass(frozen=True)
class FlashPoint:
    """The located point under the flash, on the photo's pixel grid.

    Attributes:
        row, col: fractional photo pixel of the peak (the centre when not found).
        contrast: the blurred log luminance's peak above its median (natural log).
        found: True when a clear peak inside the window was taken; False: the photo's
            centre (no clear highlight, or one at the window's edge).
    """

    row: float
    col: float
    contrast: float
    found: bool

    def to_dict(self) -> dict:
        return {k: (round(v, 3) if isinstance(v, float) else v) for k, v in asdict(self).items()}

    def plane_point(self, frame: Frame) -> tuple[float, float]:
        """``(x, y)`` scene units: the plane point of this pixel, for the photo's ``frame``."""
        x, y = frame.pixel_to_plane(torch.tensor(self.row), torch.tensor(self.col))
        return float(x), float(y)


def _gaussian_blur(x: torch.Tensor, sigma: float) -> torch.Tensor:
    """Gaussian blur of ``[H, W]`` with reflected borders (a border is not dark), taps to
    3 sigma (fewer when the image is smaller), as ``matcap.capture.priors`` blurs."""
    radius = min(max(1, math.ceil(3 * sigma)), x.shape[0] - 1, x.shape[1] - 1)
    return gaussian_blur2d(x[None, None], 2 * radius + 1, (sigma, sigma), border_type="reflect")[0, 0]


def _subpixel(values: torch.Tensor, i: int) -> float:
    """Offset in (-0.5, 0.5) of a parabola's vertex through ``values[i - 1 : i + 2]``."""
    a, b, c = (float(v) for v in values[i - 1 : i + 2])
    curvature = a - 2 * b + c
    return 0.0 if curvature >= 0 else max(-0.5, min(0.5, 0.5 * (a - c) / curvature))


def locate_flash(image: torch.Tensor) -> FlashPoint:
    """The point of a flash photo under the camera and flash (module docstring).

    Args:
        image: ``[3, H, W]`` linear radiance (any size of at least 16 px a side).

    Returns:
        A ``FlashPoint`` on ``image``'s pixel grid.
    """
    if image.dim() != 3 or image.shape[0] != 3:
        raise ValueError(f"image must be [3, H, W], got {list(image.shape)}")
    h, w = image.shape[-2:]
    if min(h, w) < 16:
        raise ValueError(f"image must be at least 16 px a side, got {h} x {w}")
    scale = min(1.0, LOCATE_SIDE / max(h, w))
    size = (max(8, round(h * scale)), max(8, round(w * scale)))
    small = F.interpolate(image[None].float().clamp_min(0), size=size, mode="area")[0]
    luma = sum(c * small[i] for i, c in enumerate(_LUMA))
    blurred = _gaussian_blur(torch.log(luma + _LOG_EPS), BLUR_FRACTION * max(size))
    sh, sw = size
    r0, r1 = round(sh * (0.5 - MAX_OFFSET)), round(sh * (0.5 + MAX_OFFSET))
    c0, c1 = round(sw * (0.5 - MAX_OFFSET)), round(sw * (0.5 + MAX_OFFSET))
    window = blurred[r0:r1, c0:c1]
    r, c = divmod(int(window.argmax()), window.shape[1])
    contrast = float(window[r, c] - blurred.median())
    interior = 0 < r < window.shape[0] - 1 and 0 < c < window.shape[1] - 1
    centre = ((h - 1) / 2, (w - 1) / 2)
    if not interior or contrast < MIN_CONTRAST:
        return FlashPoint(*centre, contrast=contrast, found=False)
    r, c = r + r0, c + c0
    # Fractional small-grid position -> the photo's grid (pixel centres at i + 0.5).
    row = r + _subpixel(blurred[:, c], r)
    col = c + _subpixel(blurred[r], c)
    return FlashPoint((row + 0.5) * h / sh - 0.5, (col + 0.5) * w / sw - 0.5, contrast=contrast, found=True)
