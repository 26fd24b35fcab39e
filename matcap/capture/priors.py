"""Priors of the capture refinement (``refine_full_resolution``): what a photographed
flat sample looks like whatever the photo says, for the places the photo cannot tell.

- ``tilt_energy``: the flat-sample prior. A flat sample's normal map does not tilt at low
  frequency, however bumpy its surface.
- ``FlashRings`` / ``radial_energy``: the flash-independence prior. The material does not
  know where the flash was: the mean of a map over a ring around the point under the
  flash should not depend on the ring's radius. A single flash photo samples each pixel's
  specular lobe at one half-angle, which grows with the distance from that point, so the
  per-pixel fit resolves the roughness / specular / diffuse ambiguity differently at each
  distance and leaves discs and rings centred on the flash (the dark specular disc with a
  bright ring on real leather, a rough blob under the flash, a dark diffuse disc where the
  highlight was). The prior costs exactly that radial profile, and nothing that is not a
  function of the distance (texture, an edge, a gradient across the sample).
"""

from __future__ import annotations

import math

import torch
from kornia.filters import gaussian_blur2d

from matcap.capture.scene import area_downsample

#: The flatness prior (``tilt_energy``) looks at the slopes area-averaged to this grid
#: (the photo's padded side is a multiple of the 64 px working size) and then blurred by
#: a Gaussian of ``FLATNESS_SIGMA`` grid cells: the low frequencies only, with a smooth
#: gradient (averages over disjoint cells gave the maps a visible cell pattern).
FLATNESS_GRID = 64
#: 1/16 of the photo's side: a tilt that varies over a sixteenth of the sample or more.
FLATNESS_SIGMA = 4.0


def tilt_energy(
    slope: torch.Tensor,
    mask: torch.Tensor | None = None,
    grid: int = FLATNESS_GRID,
    sigma: float = FLATNESS_SIGMA,
) -> torch.Tensor:
    """Mean squared low-pass normal slope: ``slope`` ``[1, 2, S, S]`` (``n_xy / n_z``),
    zero where ``mask`` (``[S, S]`` bool, None: all True) is False, area-averaged to
    ``grid x grid`` (S a multiple of it, or S itself if smaller) and blurred by a Gaussian
    of ``sigma`` grid cells (reflected at the borders). Masked-out pixels (a photo's
    padding) neither pay nor can cancel a tilt of the real pixels.

    The mean slope over a region is the height difference across it divided by its
    width, so this is ~0 for a flat sample however bumpy its surface; what it costs is a
    tilt of the normal map at low frequency, the refinement's way of moving a flash
    highlight it cannot otherwise explain (a four-quadrant tilt on real photos).
    """
    g = min(grid, slope.shape[-1])
    x = area_downsample(slope if mask is None else slope * mask.to(slope.dtype), g)
    r = math.ceil(3 * sigma)  # taps to 3 sigma
    if r >= g:  # the blur would span the whole grid (reflect padding needs r < g)
        return x.mean(dim=(-2, -1)).square().mean()
    return gaussian_blur2d(x, 2 * r + 1, (sigma, sigma), border_type="reflect").square().mean()


#: Rings of the flash-independence prior per side of the (padded, square) photo: rings
#: 1/32 of the side wide, 0.125 scene units on the ``dgrsise`` plane of side 4, so the
#: evaluation's highlight disc (radius 0.5, ``estimator.evaluate.HIGHLIGHT_RADIUS``) spans
#: four of them, fine enough to see the rim of a 0.5-wide highlight, coarse enough that
#: the innermost ring holds ~3 of every 1,000 pixels.
RADIAL_RINGS = 32


def plane_to_grid(x: float, y: float, side: int, plane_size: float) -> tuple[float, float]:
    """The fractional ``(row, col)`` of the plane point ``(x, y)`` (scene units) on the
    ``side x side`` grid of a square plane of side ``plane_size``: ``kernels.brdf``'s
    ``plane_point`` inverted (pixel ``(i, j)`` centred at ``x = ((j + 0.5) / S - 0.5) *
    plane_size``, ``y = -((i + 0.5) / S - 0.5) * plane_size``, SPEC section 2).

    >>> plane_to_grid(0.0, 0.0, 64, 4.0)
    (31.5, 31.5)
    """
    return (0.5 - y / plane_size) * side - 0.5, (x / plane_size + 0.5) * side - 0.5


class FlashRings:
    """Rings around the point under the flash on an ``S x S`` grid, built once and used
    at every refinement step (``energy``).

    A pixel at distance ``r`` (in ring widths ``S / rings`` pixels) belongs to rings
    ``floor(r)`` and ``floor(r) + 1`` with linear weights, so the ring means, and the
    energy, change smoothly as a value moves outward; masked-out pixels belong to none.

    Args:
        side: ``S``, pixels.
        center: ``(row, col)`` of the point under the flash, pixel coordinates (pixel
            centres at integers; it may lie outside the grid).
        mask: ``[S, S]`` bool (True: a real pixel) or None (all real).
        rings: rings per side (``RADIAL_RINGS``).
        dtype: of the weights (the maps').
    """

    def __init__(
        self,
        side: int,
        center: tuple[float, float],
        mask: torch.Tensor | None = None,
        rings: int = RADIAL_RINGS,
        dtype: torch.dtype = torch.float32,
    ):
        if side < 1 or rings < 1:
            raise ValueError(f"side and rings must be positive, got {side}, {rings}")
        if mask is not None and tuple(mask.shape) != (side, side):
            raise ValueError(f"mask must be [{side}, {side}], got {tuple(mask.shape)}")
        coord = torch.arange(side, dtype=torch.float64)
        drow, dcol = coord[:, None] - float(center[0]), coord[None, :] - float(center[1])
        r = torch.hypot(drow, dcol)
        t = r * (rings / side)
        inner = t.floor()
        frac = (t - inner).to(dtype)
        real = torch.ones(side, side, dtype=dtype) if mask is None else mask.to(dtype)
        self.side = side
        self.index = inner.long().flatten()
        self.w_inner = ((1 - frac) * real).flatten()
        self.w_outer = (frac * real).flatten()
        self.n_rings = int(self.index.max()) + 2
        self.counts = self._ring_sums(real.flatten()[None] * 0 + 1)[0]
        self.total = float(real.sum())
        if not self.total > 0:
            raise ValueError("the mask holds no real pixel")
        # The outward unit vector in the plane's axes (x right = +col, y up = -row), for
        # the normals' radial slope; 0 at the centre itself.
        safe = r.clamp_min(1e-12)
        self.outward = torch.stack([dcol / safe, -drow / safe]).where(r > 0, 0.0).to(dtype)

    def _ring_sums(self, x: torch.Tensor) -> torch.Tensor:
        """``x`` ``[C, S * S]`` -> weighted sums per ring ``[C, n_rings]``."""
        out = x.new_zeros(x.shape[0], self.n_rings)
        out = out.index_add(1, self.index, x * self.w_inner)
        return out.index_add(1, self.index + 1, x * self.w_outer)

    def energy(self, x: torch.Tensor, centered: bool = True) -> torch.Tensor:
        """The radial profile's energy of ``x`` ``[1, C, S, S]``, mean over channels:
        ``sum_b n_b (m_b - g)^2 / sum_b n_b`` with ``m_b`` the mean of ring ``b``, ``n_b``
        its weight and ``g`` the mean of the real pixels (``centered``; else ``g = 0``: a
        signed quantity whose every ring should average 0). 0 for a map whose ring means
        are equal, at most the map's variance over the real pixels (Cauchy-Schwarz on each
        ring's weighted mean); its gradient is the same for all the pixels of a ring, so
        it moves ring means, never the texture within a ring.
        """
        if x.dim() != 4 or x.shape[0] != 1 or tuple(x.shape[-2:]) != (self.side, self.side):
            raise ValueError(f"x must be [1, C, {self.side}, {self.side}], got {tuple(x.shape)}")
        sums = self._ring_sums(x[0].flatten(1))
        counts = self.counts.to(x.dtype)
        means = sums / counts.clamp_min(1e-12)
        if centered:
            means = means - sums.sum(1, keepdim=True) / self.total
        return ((counts * means.square()).sum(1) / self.total).mean()

    def radial_slope(self, slope: torch.Tensor) -> torch.Tensor:
        """The normals' slope toward or away from the flash point: ``slope`` ``[1, 2, S,
        S]`` (``n_xy / n_z``) -> ``[1, 1, S, S]``, positive where the normal leans away
        from it (a dome) and negative toward it (a bowl)."""
        return (slope * self.outward.to(slope.dtype)).sum(1, keepdim=True)


def radial_energy(
    x: torch.Tensor,
    center: tuple[float, float],
    mask: torch.Tensor | None = None,
    rings: int = RADIAL_RINGS,
    centered: bool = True,
) -> torch.Tensor:
    """``FlashRings(S, center, mask, rings).energy(x, centered)`` for one ``[1, C, S, S]``
    map (the refinement builds the rings once instead).

    >>> x = torch.zeros(1, 1, 64, 64)
    >>> x[..., 24:40, 24:40] = 1.0  # a bright square under a flash at the centre
    >>> float(radial_energy(x, (31.5, 31.5))) > 0.8 * x.var(unbiased=False).item()
    True
    >>> float(radial_energy(torch.linspace(-1, 1, 64).expand(1, 1, 64, 64), (31.5, 31.5))) < 1e-12
    True
    """
    return FlashRings(x.shape[-1], center, mask, rings, x.dtype).energy(x, centered)


#: The refinement's maps as the flash-independence prior sees them: diffuse, specular and
#: roughness by their logarithm (the log-L1 loss's scale, ``kernels.loss.LOG_EPS``: a dark
#: disc is a factor, whatever the material's brightness), the normals by their radial
#: slope, whose ring means a flat sample keeps at 0.
RADIAL_LOG_EPS = 0.01


def flash_independence(rings: FlashRings, maps: dict[str, torch.Tensor]) -> torch.Tensor:
    """Sum over ``maps`` (names of ``diffuse [1, 3, S, S]``, ``roughness [1, 1, S, S]``,
    ``specular [1, 3, S, S]``, linear; ``normal``: the slopes ``[1, 2, S, S]``) of their
    radial profile's energy (``FlashRings.energy``)."""
    total = next(iter(maps.values())).new_zeros(())
    for name, x in maps.items():
        if name == "normal":
            total = total + rings.energy(rings.radial_slope(x), centered=False)
        else:
            total = total + rings.energy(torch.log(x + RADIAL_LOG_EPS))
    return total
