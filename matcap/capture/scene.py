"""Where the camera, the flash and the lights sit over the plane (``CaptureScene``,
``capture_scene``), the flash's falloff over it (``falloff_factor``), the disc of its
highlight (``flash_disc``), and the exact area downsampling between the photo's and the
working resolution (``area_downsample``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from matcap.capture.config import DEFAULT_FALLOFF, RENDER_LIGHTS
from matcap.capture.flash import FlashPoint
from materials.camera import DEFAULT_FOV_DEG, camera_height, fov_from_exif
from materials.frame import Frame
from materials.highlight import plane_disc
from materials.io.photo import Photo
from materials.units import model_gain


@dataclass(frozen=True)
class CaptureScene:
    """Where the camera and the lights are, and how the refinement renders (scene units
    of the ``dgrsise`` plane, side ``plane_size``).

    Attributes:
        camera_pos: ``[3]`` camera and flash position.
        camera_source: ``"camera"`` (given), ``"fov"`` (given), ``"exif"`` or ``"default"``.
        fov_deg: field of view across the photo's long side (None when ``camera`` was given).
        relit_light_pos: ``[K, 3]`` lights of the relit views.
        falloff: ``FALLOFFS`` entry.
        plane_size: side of the plane the prepared square spans.
        flash_point: what ``locate_flash`` found (None when it was not asked or a
            ``camera`` was given).
    """

    camera_pos: torch.Tensor
    camera_source: str
    fov_deg: float | None
    relit_light_pos: torch.Tensor
    falloff: str
    plane_size: float
    flash_point: FlashPoint | None = None

    @property
    def render_kwargs(self) -> dict:
        """``kernels.render`` keywords of the refinement and the re-renders: ``dgrsise``,
        with 1/d^2 at intensity pi h^2 under ``"inverse-square"`` (package docstring)."""
        if self.falloff == "none":
            return {"preset": "dgrsise"}
        height = float(self.camera_pos[2])
        return {"preset": "dgrsise", "inverse_square": True, "intensity": math.pi * height * height}

    def to_dict(self) -> dict:
        return {
            "camera_pos": self.camera_pos.tolist(),
            "camera_source": self.camera_source,
            "fov_deg": self.fov_deg,
            "relit_light_pos": self.relit_light_pos.tolist(),
            "render_light_pos": [self.camera_pos.tolist(), *[list(p) for p in RENDER_LIGHTS]],
            "falloff": self.falloff,
            "plane_size": self.plane_size,
            "flash_point": None if self.flash_point is None else self.flash_point.to_dict(),
            "render": dict(self.render_kwargs),
        }


def area_downsample(x: torch.Tensor, size: int) -> torch.Tensor:
    """Mean over ``f x f`` blocks: ``[..., C, S, S]`` -> ``[..., C, size, size]``, S = f * size
    (the radiance a pixel ``f`` times larger collects; differentiable)."""
    s = x.shape[-1]
    if x.shape[-2] != s or s % size:
        raise ValueError(f"area_downsample needs a square side that is a multiple of {size}, got {tuple(x.shape)}")
    if s == size:
        return x
    f = s // size
    # A reshape and a mean: its backward is a broadcast (avg_pool2d's CPU backward cost
    # 20 ms per 256 px view here, more than the render's).
    return x.reshape(*x.shape[:-2], size, f, size, f).mean(dim=(-3, -1))


def falloff_factor(light_pos: torch.Tensor, reference_height: float, size: int, plane_size: float) -> torch.Tensor:
    """``h^2 / |p - x|^2`` per pixel of a square image spanning the plane.

    Args:
        light_pos: ``[K, 3]`` light positions (scene units).
        reference_height: ``h``, the flash's height (the factor is 1 under a flash at h).
        size: side of the image, pixels; plane_size: side of the plane, scene units.

    Returns:
        ``[K, 1, size, size]`` float32.
    """
    # The flash's power pi h^2 is what makes the factor 1 under it (materials.units: the
    # models' gain of a light of intensity I with falloff is pi d^2 / I).
    power = (math.pi * reference_height**2,) * 3
    return 1.0 / model_gain(light_pos, (size, size), plane_size, power, inverse_square=True)[:, :1]


def flash_disc(camera_pos: torch.Tensor, size: int, plane_size: float, half_angle_deg: float) -> torch.Tensor:
    """``[size, size]`` bool: the pixels of a square image spanning the plane whose point
    the collocated camera and flash at ``camera_pos`` see within ``half_angle_deg`` of the
    plane's normal, i.e. within ``h tan(angle)`` of the point under the flash.

    With light and view both at that angle, the half vector is too, so this is where a
    GGX lobe of that half-width puts the flash highlight on a flat sample, whatever the
    camera height (pixel centres as ``kernels.brdf``'s ``plane_point``, SPEC section 2).
    """
    if not (math.isfinite(half_angle_deg) and 0 <= half_angle_deg < 90):
        raise ValueError(f"half angle must lie in [0, 90) degrees, got {half_angle_deg}")
    x0, y0, h = (float(v) for v in camera_pos.reshape(3))
    return plane_disc((x0, y0), h * math.tan(math.radians(half_angle_deg)), (size, size), plane_size)


def capture_scene(
    photo: Photo,
    frame: Frame,
    light_pos: torch.Tensor,
    *,
    falloff: str = DEFAULT_FALLOFF,
    fov: float | None = None,
    camera: tuple[float, float, float] | None = None,
    flash_point: FlashPoint | None = None,
) -> CaptureScene:
    """The scene convention of a phone photo (package docstring): the camera and flash
    above the photo's centre, or above ``flash_point`` when it was found there, at the
    height where the photo's long side on the plane spans the field of view: ``fov``,
    else the EXIF focal length, else 45 degrees; ``camera`` overrides all of it.

    Args:
        photo: the ``Photo`` (its EXIF focal length and size); frame: its ``Frame``.
        light_pos: ``[K, 3]`` lights of the relit views (scene units).
        flash_point: ``matcap.capture.flash.locate_flash`` of the photo, on its pixel grid.
    """
    if camera is not None:
        camera_pos, source, fov_deg = torch.tensor(camera, dtype=torch.float32), "camera", None
    else:
        if fov is not None:
            fov_deg, source = float(fov), "fov"
        elif photo.focal_35mm is not None:
            h, w = photo.exif_size or photo.size
            fov_deg, source = fov_from_exif(photo.focal_35mm, aspect=max(h, w) / min(h, w)), "exif"
        else:
            fov_deg, source = DEFAULT_FOV_DEG, "default"
        if flash_point is not None and flash_point.found:
            x, y = flash_point.plane_point(frame)
        else:
            height, width = frame.photo_size
            x, y = (
                float(v) for v in frame.pixel_to_plane(torch.tensor((height - 1) / 2), torch.tensor((width - 1) / 2))
            )
        z = camera_height(fov_deg, frame.photo_long_side)
        camera_pos = torch.tensor([x, y, z], dtype=torch.float32)
    located = flash_point if camera is None else None
    lights = light_pos.float().reshape(-1, 3)
    return CaptureScene(camera_pos, source, fov_deg, lights, falloff, frame.plane_size, located)
