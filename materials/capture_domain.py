"""Capture-domain randomisation of training renders: geometry, light falloff and the
photometric chain of a real flash photo (issue 16; SPEC sections 2-3).

The paper's training renders (SPEC section 3) are clean linear radiance of a plane seen
from (0, 0, h), h ~ U[4, 8], lit without falloff. A phone photo differs in ways a model
trained there never sees: the camera is closer or farther and not centred, the flash sits
about a centimetre from the lens, radiance falls off with 1/d^2, the exposure and white
balance are the phone's guess, the sensor adds noise, the flash highlight clips at the
sensor's full well, and the file is an 8-bit (often JPEG) image. This module samples
those effects, deterministically from a ``torch.Generator``:

- ``sample_geometry`` -> ``CaptureGeometry``: light / camera positions in the model's
  frame (plane of side 4, ``dgrsise`` units), a per-view intensity gain and the falloff
  switch, optionally for a random crop of the photographed plane (``crop_geometry``).
- ``render_geometry``: render a material under a ``CaptureGeometry`` (linear radiance).
- ``sample_degradation`` -> ``Degradation`` and ``apply_degradation`` (``degrade`` does
  both): exposure, white balance, sensor noise, clipping, 8-bit tone-mapped quantisation
  and JPEG on linear renders ``[V, 3, H, W]``; the output is decoded back to linear, as
  ``materials.io`` decodes a real photo.

Every effect has a probability in ``CaptureDomain`` (0 switches it off);
``CaptureDomain.paper()`` is the paper's clean setup, ``CaptureDomain()`` the capture
domain. The ranges and their sources are documented on the fields.

Frames and units: positions are in scene units of the ``dgrsise`` preset (plane side
``MODEL_PLANE_SIZE`` = 4 at z = 0). Geometry is first sampled for the whole photographed
plane (the "full frame", also side 4) and then, with a crop, mapped into the crop's own
normalised frame: a crop of side ``s`` centred at ``(cx, cy)`` is the same scene as a
centred plane of side ``s`` with every position moved by ``(-cx, -cy, 0)``; scaling it to
side 4 multiplies positions by ``4 / s`` and, with 1/d^2 falloff, the intensity by
``(4 / s)^2`` (as ``matcap.estimate.estimate_material`` does for captures in other units).
Directions, hence l / v / h and the image, are unchanged.
"""

from __future__ import annotations

import io
import math
from dataclasses import dataclass, fields, replace
from typing import Any

import numpy as np
import torch
from PIL import Image

import kernels
from kernels.tonemap import inverse_tonemap, tonemap
from materials.lights import TRAIN_LIGHT_HEIGHT, TRAIN_LIGHT_XY, sample_paper_lights
from materials.types import Material

__all__ = [
    "CaptureDomain",
    "CaptureGeometry",
    "Degradation",
    "MODEL_PLANE_SIZE",
    "PHONE_CAMERA_HEIGHT",
    "crop_geometry",
    "sample_geometry",
    "render_geometry",
    "sample_degradation",
    "apply_degradation",
    "degrade",
    "quantize_8bit",
]

#: Side of the plane in the models' frame (``dgrsise`` preset, SPEC section 2).
MODEL_PLANE_SIZE = 4.0
#: Camera height of the field's phone convention (Deschaintre et al. 2018: 45 degree field
#: of view over the whole plane): h = (side / 2) / tan(22.5 deg) = 2 / 0.4142 = 4.83.
PHONE_CAMERA_HEIGHT = (MODEL_PLANE_SIZE / 2) / math.tan(math.radians(22.5))
#: 8-bit code range of the tone-mapped image.
_CODES = 255.0


@dataclass(frozen=True)
class CaptureDomain:
    """Ranges and probabilities of the capture-domain randomisation.

    Geometry (full-frame plane units, plane side 4; SPEC sections 2-3):

    Attributes:
        geometry: ``"capture"`` (the fields below) or ``"paper"``: exactly
            ``materials.lights.sample_paper_lights`` (camera (0, 0, U[4, 8]), view 0 lit
            from the camera, others x, y ~ U[-4, 4], z ~ U[4, 8]); then only the falloff
            and photometric fields apply.
        camera_height: log-uniform range of the camera height. The paper trains on
            [4, 8]; the phone convention (45 degree FOV over the plane) is 4.83, a
            MaterialGAN capture maps to 9.76 (issue 16), a close-up fills the frame with
            a smaller plane region, i.e. a lower height: [2.5, 12] covers all three.
            Log-uniform because height acts as a scale.
        camera_offset: the camera's ground point is uniform in a square of half-side
            ``camera_offset * h`` around the plane centre: hand-held aiming error of up
            to atan(0.1) ~ 6 degrees.
        flash_offset: range of the lens-to-flash distance as a fraction of the height,
            uniform, in a random direction at the camera's height. Phones put the flash
            0.8-1.5 cm from the lens and shoot materials from 20-40 cm: 2-7 %; 0 keeps the
            paper's exactly collocated flash in the range.
        p_collocated: probability that views 1.. are a collocated moving camera (each view
            a phone position with its own flash, as in MaterialGAN / Luo et al. captures)
            instead of a fixed camera with the paper's light sampling.
        collocated_tilt: largest angle (degrees) between the vertical and the direction
            from a moving view's ground point to its camera; MaterialGAN-style captures
            walk the phone around the sample at up to ~30-40 degrees.
        collocated_height_jitter: moving views' heights are ``h * exp(U[-j, j])``.
        p_crop: probability of cropping the photographed plane (resolution-free training:
            a window of a larger photo has the crop's own l / v / h).
        crop_scale: log-uniform range of the crop side as a fraction of the plane side.
            1/8 is a 64 px window of a 512 px photo.

    Light falloff:
        p_falloff: probability of 1/d^2 falloff (a real flash; SPEC preset
            ``materialgan``) instead of none (preset ``dgrsise``). With falloff the
            light's intensity is set by auto-exposure: the radiance at view 0's metering
            point (the camera's ground point) equals the no-falloff convention's, i.e.
            intensity = pi * d0^2 with d0 the light-to-metering-point distance, the same
            for every view of the group (one flash, one exposure, as in MaterialGAN data).

    Photometric chain (on linear radiance, in this order; Deschaintre et al. 2018 / 2019
    augment exposure, light power and white balance; Brooks et al. 2019 model the noise):
        p_exposure, exposure_sigma, exposure_view_sigma: exposure error, log-normal with
            median 1: one factor per group (sigma 0.4, Deschaintre et al. 2018's
            auto-exposure spread) times one per view (sigma 0.05: per-shot flash power and
            metering variation).
        p_white_balance, white_balance_sigma: per-channel log-normal gains (sigma 0.05,
            a little above Deschaintre et al. 2018's 0.03: phone auto white balance under
            mixed flash and room light), normalised to geometric mean 1 so it does not
            move the exposure.
        p_noise, shot_noise, read_noise_fit: heteroscedastic Gaussian sensor noise,
            variance ``read + shot * x`` (Brooks et al. 2019, "Unprocessing images for
            learned raw denoising"): shot log-uniform in ``shot_noise``, log(read) =
            a log(shot) + b + N(0, c) with (a, b, c) = ``read_noise_fit``, their fit to
            real sensors. Negative values after the noise are clamped to 0 (black level).
        p_clip, clip_level: saturation of the sensor: values above ``clip_level`` (linear,
            1 = the tone map's white) are clamped, so a bright flash highlight clips (the
            problem the paper is about).
        p_quantize: 8-bit round trip through the project's tone map
            (``kernels.tonemap``: clamp to [0, 1], x^(1/2.2), codes 0..255) and back.
            The tone map clamps at 1, so quantising always clips at 1 as well.
        p_jpeg, jpeg_quality: JPEG compression (Pillow, 4:2:0, quality uniform in the
            integer range) of the 8-bit tone-mapped image; implies the 8-bit round trip.
    """

    geometry: str = "capture"
    camera_height: tuple[float, float] = (2.5, 12.0)
    camera_offset: float = 0.1
    flash_offset: tuple[float, float] = (0.0, 0.06)
    p_collocated: float = 0.5
    collocated_tilt: float = 35.0
    collocated_height_jitter: float = 0.2
    p_crop: float = 0.5
    crop_scale: tuple[float, float] = (0.125, 1.0)
    p_falloff: float = 0.5
    p_exposure: float = 1.0
    exposure_sigma: float = 0.4
    exposure_view_sigma: float = 0.05
    p_white_balance: float = 0.5
    white_balance_sigma: float = 0.05
    p_noise: float = 0.5
    shot_noise: tuple[float, float] = (1e-4, 1.2e-2)
    read_noise_fit: tuple[float, float, float] = (2.18, 1.20, 0.26)
    p_clip: float = 1.0
    clip_level: float = 1.0
    p_quantize: float = 1.0
    p_jpeg: float = 0.5
    jpeg_quality: tuple[int, int] = (60, 95)

    def __post_init__(self) -> None:
        if self.geometry not in ("capture", "paper"):
            raise ValueError(f"geometry must be 'capture' or 'paper', got {self.geometry!r}")
        for f in fields(self):
            if f.name.startswith("p_"):
                p = getattr(self, f.name)
                if not 0.0 <= p <= 1.0:
                    raise ValueError(f"{f.name} must be a probability in [0, 1], got {p}")
        lo, hi = self.camera_height
        if not 0 < lo <= hi:
            raise ValueError(f"camera_height must be 0 < lo <= hi, got {self.camera_height}")
        lo, hi = self.crop_scale
        if not 0 < lo <= hi <= 1:
            raise ValueError(f"crop_scale must be 0 < lo <= hi <= 1, got {self.crop_scale}")
        lo, hi = self.flash_offset
        if not 0 <= lo <= hi:
            raise ValueError(f"flash_offset must be 0 <= lo <= hi, got {self.flash_offset}")
        lo, hi = self.shot_noise
        if not 0 < lo <= hi:
            raise ValueError(f"shot_noise must be 0 < lo <= hi, got {self.shot_noise}")
        lo, hi = self.jpeg_quality
        if not 1 <= lo <= hi <= 100:
            raise ValueError(f"jpeg_quality must be 1 <= lo <= hi <= 100, got {self.jpeg_quality}")
        if self.camera_offset < 0 or not 0 <= self.collocated_tilt < 90 or self.collocated_height_jitter < 0:
            raise ValueError("camera_offset and collocated_height_jitter must be >= 0, collocated_tilt in [0, 90)")
        if min(self.exposure_sigma, self.exposure_view_sigma, self.white_balance_sigma) < 0:
            raise ValueError("exposure and white balance sigmas must be >= 0")
        if not self.clip_level > 0:
            raise ValueError(f"clip_level must be positive, got {self.clip_level}")

    @classmethod
    def paper(cls) -> CaptureDomain:
        """The paper's training setup (SPEC section 3): paper lights, no falloff, clean
        linear renders. ``DomainGroups`` with it reproduces ``RenderedGroups``."""
        return cls(geometry="paper", p_falloff=0.0).without_photometric()

    @classmethod
    def relighting(cls, p_crop: float | None = None) -> CaptureDomain:
        """The capture domain as the capture pipeline's relighter sees it
        (``matcap.capture``): a fixed camera with the paper's light sampling for views
        1.. (the pipeline relights to lights around a camera that does not move) and no
        falloff (the pipeline divides the photo by its flash's 1/d^2 factor before
        relighting and multiplies the relit views by theirs); every photometric effect
        of the photo (exposure, white balance, noise, clipped highlights, 8-bit, JPEG) and
        the geometry's height, offset and crops as in ``CaptureDomain()``; ``p_crop``, when
        given, the share of windows (0: whole planes, what the diffusion relighter's ``large="global"``
        mode sees)."""
        domain = cls(p_collocated=0.0, p_falloff=0.0)
        return domain if p_crop is None else replace(domain, p_crop=p_crop)

    def without_photometric(self) -> CaptureDomain:
        """The same geometry and falloff, every photometric effect switched off."""
        return self.switched(exposure=False, white_balance=False, noise=False, clip=False, quantize=False, jpeg=False)

    def switched(self, **effects: bool) -> CaptureDomain:
        """Switch effects by name (``noise=False``; True keeps the current probability,
        or sets 1 where it is 0). Names: the ``p_`` fields without the prefix."""
        changes: dict[str, Any] = {}
        for name, on in effects.items():
            key = f"p_{name}"
            if not hasattr(self, key):
                known = sorted(f.name[2:] for f in fields(self) if f.name.startswith("p_"))
                raise ValueError(f"unknown effect {name!r}; known: {known}")
            current = getattr(self, key)
            changes[key] = (current if current > 0 else 1.0) if on else 0.0
        return replace(self, **changes)


# ---------------------------------------------------------------------- random draws
def _rand(generator: torch.Generator, *shape: int) -> torch.Tensor:
    """U[0, 1) in float64 (positions are drawn in float64 and returned as float32)."""
    return torch.rand(shape if shape else (1,), generator=generator, dtype=torch.float64)


def _coin(generator: torch.Generator, p: float) -> bool:
    """One Bernoulli(p) draw. Always consumes one number, so switching one effect off
    does not shift the random stream of the others."""
    return bool(_rand(generator)[0] < p)


def _uniform(generator: torch.Generator, lo: float, hi: float, *shape: int) -> torch.Tensor:
    return lo + (hi - lo) * _rand(generator, *shape)


def _log_uniform(generator: torch.Generator, lo: float, hi: float, *shape: int) -> torch.Tensor:
    return torch.exp(_uniform(generator, math.log(lo), math.log(hi), *shape))


def _normal(generator: torch.Generator, *shape: int) -> torch.Tensor:
    return torch.randn(shape if shape else (1,), generator=generator, dtype=torch.float64)


# ---------------------------------------------------------------------- geometry
@dataclass(frozen=True)
class CaptureGeometry:
    """Where the lights and cameras of one group are, in the model's frame.

    Attributes:
        light: ``[V, 3]`` float32 light positions (model frame: plane side 4, z > 0).
        camera: ``[V, 3]`` float32 camera positions (model frame).
        gain: ``[V]`` float32 light intensity as a multiple of the ``dgrsise`` preset's
            (pi per channel): render with ``intensity = pi * gain[v]``. Includes the crop's
            ``(4 / s)^2`` under falloff. 1 without falloff.
        inverse_square: whether radiance falls off with 1/d^2.
        collocated: whether views 1.. are a moving collocated camera (else a fixed camera).
        crop: (cx, cy, side) of the rendered window in the full frame (no crop:
            (0, 0, 4)).
    """

    light: torch.Tensor
    camera: torch.Tensor
    gain: torch.Tensor
    inverse_square: bool
    collocated: bool
    crop: tuple[float, float, float]

    @property
    def intensity(self) -> torch.Tensor:
        """``[V, 3]`` light intensity per view and channel (``dgrsise`` scale times gain)."""
        return (math.pi * self.gain)[:, None].expand(-1, 3).contiguous()


def crop_geometry(
    light: torch.Tensor,
    camera: torch.Tensor,
    center: tuple[float, float],
    side: float,
    *,
    plane_size: float = MODEL_PLANE_SIZE,
    inverse_square: bool = False,
) -> tuple[torch.Tensor, torch.Tensor, float]:
    """Positions of a crop of the plane, in the crop's own frame scaled to ``plane_size``.

    Rendering a centred plane of side ``plane_size`` with the returned positions (and the
    intensity multiplied by the returned factor) gives exactly the window of side ``side``
    centred at ``center`` of the full render, at whatever resolution the window is drawn.

    Args:
        light, camera: ``[..., 3]`` positions in the full frame (any float dtype).
        center: (cx, cy) of the window on the plane (full-frame units).
        side: side of the window (full-frame units), > 0.
        plane_size: side of the frame the window is mapped to (the model's: 4).
        inverse_square: whether the render uses 1/d^2 falloff.

    Returns:
        (light, camera, intensity factor): positions ``(p - (cx, cy, 0)) * plane_size /
        side``; factor ``(plane_size / side)^2`` with falloff (distances grew by
        ``plane_size / side``), else 1.
    """
    if not side > 0 or not plane_size > 0:
        raise ValueError(f"side and plane_size must be positive, got side={side}, plane_size={plane_size}")
    k = plane_size / side
    shift = light.new_tensor([float(center[0]), float(center[1]), 0.0])
    factor = k * k if inverse_square else 1.0
    return (light - shift) * k, (camera.to(light.dtype) - shift) * k, factor


def _flash(camera: torch.Tensor, domain: CaptureDomain, generator: torch.Generator) -> torch.Tensor:
    """Flash positions ``[V, 3]`` next to each camera: a random direction in the camera's
    horizontal plane at a distance of ``flash_offset`` times the height."""
    v = camera.shape[0]
    r = _uniform(generator, *domain.flash_offset, v) * camera[:, 2]
    phi = _uniform(generator, 0.0, 2 * math.pi, v)
    light = camera.clone()
    light[:, 0] += r * torch.cos(phi)
    light[:, 1] += r * torch.sin(phi)
    return light


def _capture_positions(
    views: int, domain: CaptureDomain, generator: torch.Generator, collocated: bool
) -> tuple[torch.Tensor, torch.Tensor]:
    """Full-frame (light, camera) ``[V, 3]`` float64 of the ``capture`` geometry."""
    h = float(_log_uniform(generator, *domain.camera_height)[0])
    ground = _uniform(generator, -domain.camera_offset * h, domain.camera_offset * h, 2)
    camera = torch.empty(views, 3, dtype=torch.float64)
    camera[:, :2] = ground
    camera[:, 2] = h
    if collocated and views > 1:
        # Each moving view: its own height, a tilt from the vertical and an azimuth; the
        # phone points at the sample, so the ground point stays where view 0 aimed.
        heights = h * torch.exp(
            _uniform(generator, -domain.collocated_height_jitter, domain.collocated_height_jitter, views - 1)
        )
        tilt = torch.deg2rad(_uniform(generator, 0.0, domain.collocated_tilt, views - 1))
        phi = _uniform(generator, 0.0, 2 * math.pi, views - 1)
        radius = heights * torch.tan(tilt)
        camera[1:, 0] = ground[0] + radius * torch.cos(phi)
        camera[1:, 1] = ground[1] + radius * torch.sin(phi)
        camera[1:, 2] = heights
        light = _flash(camera, domain, generator)
    else:
        light = torch.empty(views, 3, dtype=torch.float64)
        light[:1] = _flash(camera[:1], domain, generator)
        light[1:, :2] = _uniform(generator, *TRAIN_LIGHT_XY, views - 1, 2)
        light[1:, 2] = _uniform(generator, *TRAIN_LIGHT_HEIGHT, views - 1)
    return light, camera


def sample_geometry(views: int, domain: CaptureDomain, generator: torch.Generator) -> CaptureGeometry:
    """One group's light / camera positions, gain and falloff (``CaptureGeometry``).

    View 0 is the flash photo (the light next to the camera). Deterministic given the
    generator's state; with ``domain.geometry == "paper"`` the positions are exactly
    ``sample_paper_lights(views, generator)`` (drawn first, so the stream matches
    ``materials.dataset.RenderedGroups``).
    """
    if views < 1:
        raise ValueError(f"views must be at least 1, got {views}")
    crop = (0.0, 0.0, MODEL_PLANE_SIZE)
    collocated = False
    if domain.geometry == "paper":
        light, camera = (t.double() for t in sample_paper_lights(views, generator))
    else:
        collocated = _coin(generator, domain.p_collocated)
        light, camera = _capture_positions(views, domain, generator, collocated)
    inverse_square = _coin(generator, domain.p_falloff)
    gain = torch.ones(views, dtype=torch.float64)
    if inverse_square:
        # Auto-exposure: radiance at view 0's ground point matches the no-falloff preset.
        metering = torch.cat([camera[0, :2], camera.new_zeros(1)])
        gain = gain * float(((light[0] - metering) ** 2).sum())
    if domain.geometry == "capture" and _coin(generator, domain.p_crop):
        side = float(_log_uniform(generator, *domain.crop_scale)[0]) * MODEL_PLANE_SIZE
        half = (MODEL_PLANE_SIZE - side) / 2
        cx, cy = (float(v) for v in _uniform(generator, -half, half, 2))
        light, camera, factor = crop_geometry(light, camera, (cx, cy), side, inverse_square=inverse_square)
        gain = gain * factor
        crop = (cx, cy, side)
    return CaptureGeometry(light.float(), camera.float(), gain.float(), inverse_square, collocated, crop)


def render_geometry(material: Material, geometry: CaptureGeometry) -> torch.Tensor:
    """Render one unbatched material ``[C, H, W]`` under a ``CaptureGeometry``.

    Returns ``[V, 3, H, W]`` float32 linear radiance (``dgrsise`` preset, the geometry's
    falloff, view v at intensity ``pi * gain[v]``; no clamp, no tone map).
    """
    gain = geometry.gain
    # One gain for the whole group (what sample_geometry draws) goes into the render's
    # intensity, so the paper setup renders bit-identically to kernels.render's default.
    uniform = bool((gain == gain[0]).all())
    d, n, r, s = (t[None] for t in material.map_tensors())
    images = kernels.render(
        d,
        n,
        r,
        s,
        geometry.light.to(material.device),
        geometry.camera.to(material.device),
        preset="dgrsise",
        intensity=math.pi * float(gain[0]) if uniform else 1.0,
        inverse_square=geometry.inverse_square,
    )[0]
    if uniform:
        return images
    return images * geometry.intensity.to(images)[:, :, None, None]


# ---------------------------------------------------------------------- photometric
@dataclass(frozen=True)
class Degradation:
    """The photometric effects drawn for one group (see ``CaptureDomain``).

    Attributes:
        exposure: ``[V]`` float32 multiplicative exposure per view (1: none).
        white_balance: ``[3]`` float32 per-channel gains, geometric mean 1 (1s: none).
        shot_noise: variance per unit of linear signal (0: no noise).
        read_noise: signal-independent variance (0: no noise).
        clip: sensor saturation level (linear), or None.
        quantize: 8-bit round trip through the tone map.
        jpeg_quality: JPEG quality of the 8-bit image, or None.
    """

    exposure: torch.Tensor
    white_balance: torch.Tensor
    shot_noise: float = 0.0
    read_noise: float = 0.0
    clip: float | None = None
    quantize: bool = False
    jpeg_quality: int | None = None

    @property
    def gain(self) -> torch.Tensor:
        """``[V, 3]`` the linear per-view, per-channel factor (exposure x white balance)."""
        return self.exposure[:, None] * self.white_balance[None, :]

    @property
    def is_identity(self) -> bool:
        return (
            bool((self.exposure == 1).all() and (self.white_balance == 1).all())
            and self.shot_noise == 0
            and self.read_noise == 0
            and self.clip is None
            and not self.quantize
            and self.jpeg_quality is None
        )


def sample_degradation(views: int, domain: CaptureDomain, generator: torch.Generator) -> Degradation:
    """Draw one group's photometric effects. Every effect consumes the same random
    numbers whether it is on or off, so switches do not change the others' draws."""
    exposure = torch.exp(
        domain.exposure_sigma * _normal(generator) + domain.exposure_view_sigma * _normal(generator, views)
    )
    if not _coin(generator, domain.p_exposure):
        exposure = torch.ones(views, dtype=torch.float64)
    wb = domain.white_balance_sigma * _normal(generator, 3)
    wb = torch.exp(wb - wb.mean())
    if not _coin(generator, domain.p_white_balance):
        wb = torch.ones(3, dtype=torch.float64)
    shot = float(_log_uniform(generator, *domain.shot_noise)[0])
    a, b, c = domain.read_noise_fit
    read = math.exp(a * math.log(shot) + b + c * float(_normal(generator)[0]))
    if not _coin(generator, domain.p_noise):
        shot = read = 0.0
    clip = domain.clip_level if _coin(generator, domain.p_clip) else None
    quantize = _coin(generator, domain.p_quantize)
    lo, hi = domain.jpeg_quality
    quality = lo + int(_rand(generator)[0] * (hi - lo + 1))
    jpeg = quality if _coin(generator, domain.p_jpeg) else None
    return Degradation(exposure.float(), wb.float(), shot, read, clip, quantize or jpeg is not None, jpeg)


def quantize_8bit(images: torch.Tensor) -> torch.Tensor:
    """Linear radiance -> 8-bit codes of the tone-mapped image (``kernels.tonemap``):
    ``round(255 * clamp(x, 0, 1)^(1/2.2))``, uint8, same shape."""
    return torch.round(tonemap(images) * _CODES).to(torch.uint8)


def _jpeg(codes: torch.Tensor, quality: int) -> torch.Tensor:
    """JPEG round trip of ``[V, 3, H, W]`` uint8 images (Pillow, default 4:2:0 chroma)."""
    out = []
    for view in codes:
        buffer = io.BytesIO()
        Image.fromarray(view.permute(1, 2, 0).contiguous().numpy(), mode="RGB").save(
            buffer, format="JPEG", quality=quality
        )
        buffer.seek(0)
        decoded = np.asarray(Image.open(buffer).convert("RGB"))
        out.append(torch.from_numpy(decoded.copy()).permute(2, 0, 1))
    return torch.stack(out)


def apply_degradation(images: torch.Tensor, degradation: Degradation, generator: torch.Generator) -> torch.Tensor:
    """Apply drawn effects to linear renders; return what a decoded photo would hold.

    Order (a camera's): exposure and white balance (linear gains), sensor noise (variance
    ``read + shot * x``, then clamp at 0), clipping at the saturation level, 8-bit codes of
    the tone-mapped image, JPEG, decode (``inverse_tonemap``) back to linear.

    Args:
        images: ``[V, 3, H, W]`` linear radiance, float32 or float64, on the CPU.
        degradation: from ``sample_degradation`` (V must match).
        generator: draws the noise (CPU generator).

    Returns:
        ``[V, 3, H, W]`` linear radiance, same dtype. Equal to ``images`` when the
        degradation is the identity.
    """
    if images.dim() != 4 or images.shape[1] != 3:
        raise ValueError(f"images must be [V, 3, H, W], got {tuple(images.shape)}")
    if degradation.exposure.shape != (images.shape[0],):
        raise ValueError(f"degradation has {degradation.exposure.shape[0]} views, images {images.shape[0]}")
    if degradation.is_identity:
        return images
    x = images * degradation.gain.to(images)[:, :, None, None]
    if degradation.shot_noise > 0 or degradation.read_noise > 0:
        std = torch.sqrt(degradation.read_noise + degradation.shot_noise * x.clamp_min(0))
        noise = torch.randn(x.shape, generator=generator, dtype=x.dtype, device=generator.device).to(x)
        x = (x + std * noise).clamp_min(0)
    if degradation.clip is not None:
        x = x.clamp(max=degradation.clip)
    if degradation.quantize:
        codes = quantize_8bit(x.cpu())
        if degradation.jpeg_quality is not None:
            codes = _jpeg(codes, degradation.jpeg_quality)
        x = inverse_tonemap(codes.to(images.dtype) / _CODES).to(images.device)
    return x


def degrade(images: torch.Tensor, domain: CaptureDomain, generator: torch.Generator) -> torch.Tensor:
    """``apply_degradation(images, sample_degradation(V, domain, generator), generator)``."""
    return apply_degradation(images, sample_degradation(images.shape[0], domain, generator), generator)
