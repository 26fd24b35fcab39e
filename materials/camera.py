"""Where the camera (and its flash) was: a height over the plane from a field of view.

A flash photo says nothing directly about the camera's position. The field's convention
for phone photos of flat materials (Deschaintre et al. 2018, used by MaterialGAN and
followers) is a camera straight above the plane's centre, looking down, with a field of
view of about 45 degrees across the photo, and the flash at the lens. In scene units the
camera is then at (0, 0, h) with the photo's long side ``L`` spanning the field of view:

    h = (L / 2) / tan(fov / 2)

(the ``dgrsise`` plane of side 4 and 45 degrees: h = 2 / tan(22.5 deg) = 4.83, inside
the training range h in [4, 8] of ``materials.lights.TRAIN_CAMERA_HEIGHT``, which is
fields of view from 28.1 to 53.1 degrees on that plane).

A field of view can come from the EXIF focal length in 35 mm equivalent
(``fov_from_exif``). That number is defined through the diagonal: a lens of focal length
f on a sensor of diagonal d is "equivalent" to f * 43.27 / d on 35 mm film, whose frame
is 36 x 24 mm with a 43.27 mm diagonal (CIPA DC-008, the standard EXIF 2.3 refers to).
Using the diagonal keeps it right for the 4:3 sensors of phones; the 36 mm width would
be right only for 3:2 frames and overestimates a 4:3 photo's long-side field of view by
3 to 4% (26 mm: 69.4 instead of 67.3 degrees). The long side's field of view then
follows from the photo's aspect ratio. Caveat: EXIF describes the full frame the camera
took; a photo cropped afterwards has a narrower field of view (``crop_fov``), while a
resized one keeps it, and the EXIF size alone cannot tell the two apart.
"""

from __future__ import annotations

import math

import torch

__all__ = [
    "DEFAULT_FOV_DEG",
    "FULL_FRAME_DIAGONAL_MM",
    "camera_height",
    "camera_from_fov",
    "fov_from_camera",
    "fov_from_exif",
    "crop_fov",
]

#: The field's convention for a phone flash photo of a material: about 45 degrees across
#: the photo's long side (Deschaintre et al. 2018; module docstring).
DEFAULT_FOV_DEG = 45.0
#: Diagonal of the 36 x 24 mm full frame, mm: sqrt(36^2 + 24^2).
FULL_FRAME_DIAGONAL_MM = math.hypot(36.0, 24.0)


def _check_fov(fov_deg: float) -> None:
    if not (isinstance(fov_deg, (int, float)) and 0.0 < fov_deg < 180.0):
        raise ValueError(f"field of view must lie strictly between 0 and 180 degrees, got {fov_deg!r}")


def camera_height(fov_deg: float, span: float) -> float:
    """Height over the plane at which a camera sees ``span`` (scene units) across a field
    of view of ``fov_deg`` degrees: ``(span / 2) / tan(fov / 2)``."""
    _check_fov(fov_deg)
    if not span > 0:
        raise ValueError(f"span must be positive, got {span}")
    return (span / 2.0) / math.tan(math.radians(fov_deg) / 2.0)


def camera_from_fov(fov_deg: float = DEFAULT_FOV_DEG, plane_size: float = 4.0) -> torch.Tensor:
    """Camera (and flash) position over the plane's centre for a field of view.

    Args:
        fov_deg: field of view across the photo's long side, degrees (default 45).
        plane_size: the photo's long side on the plane, scene units (4: a square photo on
            the ``dgrsise`` plane; use ``Frame.photo_long_side`` for a padded one).

    Returns:
        ``camera_pos``: ``[3]`` float32 ``(0, 0, h)``.

    Example:
        >>> [round(v, 3) for v in camera_from_fov(45.0).tolist()]
        [0.0, 0.0, 4.828]
    """
    return torch.tensor([0.0, 0.0, camera_height(fov_deg, plane_size)], dtype=torch.float32)


def fov_from_camera(camera_pos: torch.Tensor, plane_size: float = 4.0) -> float:
    """Inverse of :func:`camera_from_fov` for a camera above the centre: degrees."""
    h = float(camera_pos[..., 2])
    if not h > 0:
        raise ValueError(f"camera must lie above the plane (z > 0), got z = {h}")
    return math.degrees(2.0 * math.atan((plane_size / 2.0) / h))


def fov_from_exif(focal_35mm: float, aspect: float = 4.0 / 3.0) -> float:
    """Field of view across a photo's long side from its 35 mm equivalent focal length.

    Args:
        focal_35mm: EXIF ``FocalLengthIn35mmFilm``, mm (> 0).
        aspect: long side / short side of the full frame (>= 1; phones: 4/3; 35 mm
            film: 3/2). Any value below 1 is inverted.

    Returns:
        Degrees: ``2 atan(half_long / f)`` with ``half_long`` the long side's half of a
        frame with the 43.27 mm diagonal (module docstring).

    Example:
        >>> round(fov_from_exif(26.0), 1)  # a phone's main camera, 4:3
        67.3
        >>> round(fov_from_exif(50.0, aspect=1.5), 2)  # 35 mm film: 2 atan(18 / 50)
        39.6
    """
    if not (isinstance(focal_35mm, (int, float)) and focal_35mm > 0 and math.isfinite(focal_35mm)):
        raise ValueError(f"focal length must be a positive number of mm, got {focal_35mm!r}")
    if not aspect > 0:
        raise ValueError(f"aspect must be positive, got {aspect}")
    aspect = max(aspect, 1.0 / aspect)
    half_long = 0.5 * FULL_FRAME_DIAGONAL_MM * aspect / math.hypot(aspect, 1.0)
    return math.degrees(2.0 * math.atan(half_long / focal_35mm))


def crop_fov(fov_deg: float, fraction: float) -> float:
    """Field of view of a centred crop keeping ``fraction`` (0, 1] of the long side."""
    _check_fov(fov_deg)
    if not 0.0 < fraction <= 1.0:
        raise ValueError(f"fraction must lie in (0, 1], got {fraction}")
    return math.degrees(2.0 * math.atan(fraction * math.tan(math.radians(fov_deg) / 2.0)))
