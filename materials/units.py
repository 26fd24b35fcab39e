"""A capture's own units mapped to the models' (issue 16, item 3): one place for the
scale of the positions, the light's intensity and its falloff.

The networks were trained in the ``dgrsise`` frame (SPEC section 2): a plane of side 4,
positions in its units, a light of intensity pi without falloff, so a pixel's radiance is
``f * (n.l) * pi``. A capture lives in its own preset: MaterialGAN / Luo folders in cm
with a light power per channel (1500) and 1/d^2 falloff, a phone photo on a plane whose
size the pipeline chooses, with a flash whose power nobody knows. Two conversions make a
capture look like the training data:

- **Positions**: multiplied by ``MODEL_PLANE_SIZE / plane_size``. Directions (hence l, v,
  h and the images) do not change under a uniform scale.
- **Radiance**: a view lit by intensity ``I`` with falloff holds ``f (n.l) I / d^2`` at a
  pixel at distance ``d`` from its light; multiplied by ``pi d^2 / I`` (``model_gain``)
  it holds ``f (n.l) pi``, exactly the training convention, whatever the units (``d``
  and ``I`` in the capture's own; the gain is unitless). Without falloff the gain is
  ``pi / I``.

Rendering the estimated maps in the capture's own lighting (refinement) needs the
intensity in model units instead: with falloff, distances grew by the scale, so the
intensity grows by its square (``model_intensity``).

Shapes: positions ``[V, 3]``, images ``[V, 3, H, W]``; the plane of side ``plane_size``
spans the image's width and its height (SPEC section 2, as ``kernels.render`` places
pixels).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import torch

from kernels.presets import get_preset
from materials.types import Capture

__all__ = [
    "MODEL_PLANE_SIZE",
    "MODEL_INTENSITY",
    "CaptureUnits",
    "capture_units",
    "model_gain",
    "to_model_units",
]

#: Side of the plane in the models' frame (``dgrsise``, SPEC section 2).
MODEL_PLANE_SIZE = 4.0
#: The models' light intensity (``dgrsise``: pi, no falloff).
MODEL_INTENSITY = math.pi


@dataclass(frozen=True)
class CaptureUnits:
    """How a capture's scene relates to the models' frame.

    Attributes:
        plane_size: side of the photographed plane in the capture's units.
        intensity: the light's intensity per channel, capture units.
        inverse_square: whether the capture's light falls off with 1/d^2.
    """

    plane_size: float
    intensity: tuple[float, float, float]
    inverse_square: bool

    @property
    def scale(self) -> float:
        """Capture units -> model units for positions."""
        return MODEL_PLANE_SIZE / self.plane_size

    def model_intensity(self) -> tuple[float, float, float]:
        """The capture's intensity for a render in model units with the capture's falloff:
        1/d^2 scales with the square of the units, so the intensity does too."""
        k = self.scale**2 if self.inverse_square else 1.0
        return (self.intensity[0] * k, self.intensity[1] * k, self.intensity[2] * k)


def capture_units(capture: Capture) -> CaptureUnits:
    """The units of ``capture`` (its preset, with its own plane size and intensity when set)."""
    preset = get_preset(capture.preset)
    intensity = capture.intensity or preset.intensity
    return CaptureUnits(
        plane_size=float(capture.plane_size or preset.plane_size),
        intensity=(float(intensity[0]), float(intensity[1]), float(intensity[2])),
        inverse_square=bool(preset.inverse_square),
    )


def model_gain(
    light_pos: torch.Tensor,
    size: tuple[int, int],
    plane_size: float,
    intensity: Sequence[float],
    inverse_square: bool,
) -> torch.Tensor:
    """``[V, 3, H, W]`` per-pixel factor from a capture's radiance to the models' convention
    (``pi d^2 / I`` with falloff, ``pi / I`` without; module docstring).

    Args:
        light_pos: ``[V, 3]`` light positions, capture units.
        size: ``(H, W)`` of the images; the plane of side ``plane_size`` spans both (SPEC
            section 2).
        intensity: the light's intensity per channel (3 values), capture units.
        inverse_square: whether the capture's light falls off with 1/d^2.

    Computed in float64 (d^2 of cm-sized scenes), returned as float32.

    >>> g = model_gain(torch.tensor([[0.0, 0.0, 2.0]]), (1, 1), 4.0, (math.pi,) * 3, True)
    >>> [round(v, 6) for v in g.flatten().tolist()]  # d = 2 under the light: pi 4 / pi
    [4.0, 4.0, 4.0]
    """
    h, w = size
    i = torch.tensor([float(v) for v in intensity], dtype=torch.float64)[None, :, None, None]
    if not inverse_square:
        return (MODEL_INTENSITY / i).expand(light_pos.shape[0], 3, h, w).float()
    xs = ((torch.arange(w, dtype=torch.float64) + 0.5) / w - 0.5) * plane_size
    ys = -((torch.arange(h, dtype=torch.float64) + 0.5) / h - 0.5) * plane_size
    p = light_pos.to(torch.float64)[:, :, None, None]
    d2 = (p[:, 0] - xs[None, None, :]) ** 2 + (p[:, 1] - ys[None, :, None]) ** 2 + p[:, 2] ** 2
    return (MODEL_INTENSITY * d2[:, None] / i).float()


def to_model_units(capture: Capture) -> Capture:
    """``capture`` as the models' training data look: positions scaled to the plane of side
    4, every view's radiance multiplied by ``model_gain`` (no falloff, intensity pi), in the
    ``dgrsise`` preset. Rendering the maps with the result's preset reproduces its images
    wherever the original ones were not clipped (``tests/materials/test_units.py``)."""
    units = capture_units(capture)
    gain = model_gain(capture.light_pos, capture.shape, units.plane_size, units.intensity, units.inverse_square)
    meta = dict(capture.meta, model_units={"from_preset": capture.preset, "scale": units.scale})
    return replace(
        capture,
        images=capture.images * gain.to(capture.images),
        light_pos=capture.light_pos * units.scale,
        camera_pos=capture.camera_pos * units.scale,
        preset="dgrsise",
        plane_size=None,
        intensity=None,
        meta=meta,
    )
