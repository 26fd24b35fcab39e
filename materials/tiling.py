"""Tileable maps: blend a material with its half-period shift so opposite edges meet.

A captured material is a window of a surface; its maps do not wrap, so a repeated
texture shows a seam at every tile border. ``make_tileable`` uses the classic
offset-and-blend construction: ``J = roll(I, (H/2, W/2))`` has continuous wrap-around
edges (its border pixels are neighbours in the interior of ``I``) and a seam along its
centre lines; the output is ``w I + (1 - w) J`` with ``w`` = 0 on the border and 1 in
the interior (a linear ramp over ``border`` of each side, product of the two axes), so
the edges come from ``J`` and the centre, where ``J`` has its seam, from ``I``. Normals
are renormalised after blending. The cost is honest and visible: inside the ramp the
two copies are mixed (ghosting, lower contrast), so the result is a tileable variant
beside the maps, not a replacement.

``seam_error`` measures what it fixes: the mean absolute difference across the wrap
border (last column vs first, last row vs first) relative to the mean difference
between interior neighbours (1: a seam as visible as any pixel step; >> 1: a visible
seam).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from materials.types import Material

__all__ = ["DEFAULT_BORDER", "make_tileable", "seam_error"]

#: Width of the blend ramp as a fraction of each side: wide enough to hide the change
#: from ``I`` to ``J`` (a narrow ramp is a seam of its own), narrow enough to keep the
#: centre half of the photo untouched.
DEFAULT_BORDER = 0.25


def _ramp(n: int, border: float, dtype: torch.dtype, device: torch.device) -> torch.Tensor:
    """``[n]``: 0 at both ends rising linearly to 1 over ``border * n`` pixels."""
    width = max(1.0, border * n)
    i = torch.arange(n, dtype=dtype, device=device)
    distance = torch.minimum(i + 0.5, n - 0.5 - i)  # to the nearest edge, pixel centres
    return (distance / width).clamp(0, 1)


def make_tileable(material: Material, border: float = DEFAULT_BORDER) -> Material:
    """A tileable variant of ``material`` (unbatched ``[C, H, W]`` or batched).

    Args:
        material: the maps (diffuse and specular linear RGB, roughness, unit normals).
        border: ramp width as a fraction of each side, in (0, 0.5].

    Returns:
        A ``Material`` of the same shape whose maps wrap around without a seam.
    """
    if not 0 < border <= 0.5:
        raise ValueError(f"border must be in (0, 0.5], got {border}")
    h, w = material.shape
    ref = material.diffuse
    weight = _ramp(h, border, ref.dtype, ref.device)[:, None] * _ramp(w, border, ref.dtype, ref.device)[None, :]
    out = {}
    for name, x in material.maps().items():
        shifted = torch.roll(x, shifts=(h // 2, w // 2), dims=(-2, -1))
        out[name] = weight * x + (1 - weight) * shifted
    out["normal"] = F.normalize(out["normal"], dim=-3)
    return Material(**out)


def seam_error(x: torch.Tensor) -> float:
    """Wrap-border difference over interior-neighbour difference of ``[..., H, W]`` maps
    (module docstring): about 1 for a tileable map, larger for a visible seam."""
    across = torch.cat(
        [(x[..., :, -1] - x[..., :, 0]).abs().flatten(), (x[..., -1, :] - x[..., 0, :]).abs().flatten()]
    ).mean()
    inside = torch.cat(
        [(x[..., :, 1:] - x[..., :, :-1]).abs().flatten(), (x[..., 1:, :] - x[..., :-1, :]).abs().flatten()]
    ).mean()
    return float(across / inside.clamp_min(1e-12))
