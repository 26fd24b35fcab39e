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
#: evaluation's highlight disc (radius 0.5, ``materials.highlight.HIGHLIGHT_RADIUS``) spans
#: four of them, fine enough to see the rim of a 0.5-wide highlight, coarse enough that
#: the innermost ring holds ~3 of every 1,000 pixels.
RADIAL_RINGS = 32
#: The flash-independence prior sums a map's rings on its block means over this grid (or
#: the nearest finer one that divides the side): a ring is 1/32 of the side wide, so at
#: 256 cells a ring is still 8 cells wide and the block means change the ring means by
#: little (``POOLED_ENERGY_TOL`` in the tests), while the ring sums of a 2048 px map cost
#: 1/64 of their full-resolution price (the index adds were ~1 s a step at 2048 px).
RADIAL_GRID = 256


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

    A map is first averaged over ``f x f`` blocks (``f = S // grid``, made to divide
    ``S``; 1 up to ``grid`` px); a block at distance ``r`` from the flash point (its
    centre's, in ring widths ``S / rings`` pixels) belongs to rings ``floor(r)`` and
    ``floor(r) + 1`` with linear weights, so the ring means, and the energy, change
    smoothly as a value moves outward; masked-out pixels belong to none.

    Args:
        side: ``S``, pixels.
        center: ``(row, col)`` of the point under the flash, pixel coordinates (pixel
            centres at integers; it may lie outside the grid).
        mask: ``[S, S]`` bool (True: a real pixel) or None (all real).
        rings: rings per side (``RADIAL_RINGS``).
        dtype: of the weights (the maps').
        grid: the block grid's side (``RADIAL_GRID``).
    """

    def __init__(
        self,
        side: int,
        center: tuple[float, float],
        mask: torch.Tensor | None = None,
        rings: int = RADIAL_RINGS,
        dtype: torch.dtype = torch.float32,
        grid: int = RADIAL_GRID,
    ):
        if side < 1 or rings < 1 or grid < 1:
            raise ValueError(f"side, rings and grid must be positive, got {side}, {rings}, {grid}")
        if mask is not None and tuple(mask.shape) != (side, side):
            raise ValueError(f"mask must be [{side}, {side}], got {tuple(mask.shape)}")
        factor = max(1, side // grid)
        while side % factor:
            factor -= 1
        self.side, self.factor = side, factor
        cells = side // factor
        # Block centres in pixel coordinates: block k spans pixels k f .. k f + f - 1.
        coord = torch.arange(cells, dtype=torch.float64) * factor + (factor - 1) / 2
        drow, dcol = coord[:, None] - float(center[0]), coord[None, :] - float(center[1])
        t = torch.hypot(drow, dcol) * (rings / side)
        inner = t.floor()
        frac = (t - inner).to(dtype)
        self.real = None if mask is None else mask.to(dtype)
        # Each block weighs its share of real pixels; its value is their mean.
        share = torch.ones(cells, cells, dtype=dtype) if mask is None else area_downsample(self.real, cells)
        self.index = inner.long().flatten()
        self.w_inner = (1 - frac).flatten()
        self.w_outer = frac.flatten()
        self.n_rings = int(self.index.max()) + 2
        self.counts = self._ring_sums(share.flatten()[None])[0]
        self.total = float(share.sum())
        if not self.total > 0:
            raise ValueError("the mask holds no real pixel")
        # The outward unit vector per pixel in the plane's axes (x right = +col, y up =
        # -row), for the normals' radial slope; 0 at the centre itself.
        pix = torch.arange(side, dtype=torch.float64)
        prow, pcol = pix[:, None] - float(center[0]), pix[None, :] - float(center[1])
        r = torch.hypot(prow, pcol)
        safe = r.clamp_min(1e-12)
        self.outward = torch.stack([pcol / safe, -prow / safe]).where(r > 0, 0.0).to(dtype)

    def _ring_sums(self, x: torch.Tensor) -> torch.Tensor:
        """Block values ``x`` ``[C, (S / f)^2]`` -> weighted sums per ring ``[C, n_rings]``."""
        out = x.new_zeros(x.shape[0], self.n_rings)
        out = out.index_add(1, self.index, x * self.w_inner)
        return out.index_add(1, self.index + 1, x * self.w_outer)

    def energy(self, x: torch.Tensor, centered: bool = True) -> torch.Tensor:
        """The radial profile's energy of ``x`` ``[1, C, S, S]``, mean over channels:
        ``sum_b n_b (m_b - g)^2 / sum_b n_b`` with ``m_b`` the mean of ring ``b``, ``n_b``
        its weight and ``g`` the mean of the real pixels (``centered``; else ``g = 0``: a
        signed quantity whose every ring should average 0). 0 for a map whose ring means
        are equal, at most the map's variance over the real pixels (Cauchy-Schwarz on each
        ring's weighted mean); its gradient is the same for all the pixels of a block
        (of a ring's share of it), so it moves ring means, never the texture within one.
        """
        if x.dim() != 4 or x.shape[0] != 1 or tuple(x.shape[-2:]) != (self.side, self.side):
            raise ValueError(f"x must be [1, C, {self.side}, {self.side}], got {tuple(x.shape)}")
        x = x[0] if self.real is None else x[0] * self.real.to(x.dtype)
        # Block sums over real pixels, in units of a block's pixel count (the share's).
        sums = self._ring_sums(area_downsample(x, self.side // self.factor).flatten(1))
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
