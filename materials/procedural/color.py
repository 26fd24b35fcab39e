"""Colour helpers for the procedural generator: HSV palettes drawn per seed, decoded to
linear RGB.

Palettes are specified in HSV over *sRGB-encoded* values because that is the space
in which designers pick and judge colours; every colour leaves this module as linear
RGB (SPEC section 2: maps are linear in memory), so nothing downstream decodes again.
"""

from __future__ import annotations

import torch

from materials.procedural.noise import uniform

__all__ = ["srgb_to_linear", "hsv_to_rgb", "random_color", "jitter_colors"]


def srgb_to_linear(x: torch.Tensor) -> torch.Tensor:
    """Decode sRGB-encoded values in [0, 1] to linear values in [0, 1] (IEC 61966-2-1)."""
    x = x.clamp(0.0, 1.0)
    return torch.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)


def hsv_to_rgb(hsv: torch.Tensor) -> torch.Tensor:
    """HSV ``[..., 3]`` (hue in turns, any real value; saturation, value in [0, 1]) to
    RGB ``[..., 3]`` in the same encoding as ``value`` (here: sRGB-encoded)."""
    h, s, v = hsv.unbind(-1)
    h = torch.remainder(h, 1.0)
    # f(n) = V - V S clamp(min(k, 4 - k), 0, 1), k = (n + 6 H) mod 6, n = 5, 3, 1 for
    # R, G, B: the closed form of the piecewise-linear HSV hexcone.
    n = torch.tensor([5.0, 3.0, 1.0], dtype=hsv.dtype, device=hsv.device)
    k = torch.remainder(n + 6.0 * h[..., None], 6.0)
    ramp = torch.minimum(k, 4.0 - k).clamp(0.0, 1.0)
    return v[..., None] - v[..., None] * s[..., None].clamp(0.0, 1.0) * ramp


def random_color(
    gen: torch.Generator,
    hue: tuple[float, float] = (0.0, 1.0),
    sat: tuple[float, float] = (0.0, 1.0),
    val: tuple[float, float] = (0.0, 1.0),
) -> torch.Tensor:
    """One colour drawn uniformly in an HSV box; returns ``[3]`` linear RGB in [0, 1].

    ``hue`` may run past 1 (e.g. ``(0.95, 1.05)`` for reds): hue is periodic.
    """
    hsv = torch.tensor([uniform(gen, *hue), uniform(gen, *sat), uniform(gen, *val)])
    return srgb_to_linear(hsv_to_rgb(hsv))


def jitter_colors(
    gen: torch.Generator,
    base: tuple[tuple[float, float], tuple[float, float], tuple[float, float]],
    n: int,
    spread: tuple[float, float, float],
) -> torch.Tensor:
    """``n`` variations of one palette colour: ``[n, 3]`` linear RGB.

    The base HSV colour is drawn from the box ``base`` (three (lo, hi) ranges); each of
    the ``n`` colours then moves by up to ``spread`` = (dh, ds, dv) from it, as
    individual tiles, bricks or threads of one batch do.
    """
    centre = torch.tensor([uniform(gen, *base[0]), uniform(gen, *base[1]), uniform(gen, *base[2])])
    offsets = (torch.rand(n, 3, generator=gen) * 2.0 - 1.0) * torch.tensor(spread)
    hsv = centre + offsets
    hsv[:, 1:] = hsv[:, 1:].clamp(0.0, 1.0)
    return srgb_to_linear(hsv_to_rgb(hsv))
