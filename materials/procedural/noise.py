"""Tileable noise primitives in pure torch, all periodic on the unit torus.

Every field here is a function of the *tile coordinates* ``(x, y)`` in [0, 1)^2 (one
tile = the whole map) and is exactly periodic with period 1 in both, so maps built from
them tile seamlessly. Pixel (row i, col j) of an N x N map sits at
``x = (j + 0.5) / N``, ``y = (i + 0.5) / N`` (``y`` grows down the image; the pattern
code does not care about handedness, only ``materials.procedural.height`` does).

Randomness comes only from the ``torch.Generator`` passed in (never the global RNG),
and every primitive draws a number of values that does not depend on the map size:
the same generator state gives the same field at 64, 100 or 256 pixels, sampled more or
less finely. Random draws happen on the CPU (so CPU and CUDA give the same material);
the arithmetic runs on ``device``.

Primitives:
- ``lattice_noise`` / ``fbm``: value noise on an integer lattice, smoothed by the
  periodic cubic B-spline; separable, so it is two small matrix products.
- ``spectral_noise``: white noise filtered in the Fourier domain (power law, band,
  anisotropy at any angle); periodic by construction of the DFT.
- ``worley``: cellular noise (F1, F2, cell index) with wrap-around distances.
- ``sample_periodic`` / ``warp``: bilinear resampling with wrap-around, for domain warps.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import NamedTuple, TypeVar

import torch

__all__ = [
    "uniform",
    "randint",
    "coin",
    "choice",
    "coords",
    "smoothstep",
    "lattice_noise",
    "fbm",
    "spectral_noise",
    "Cells",
    "worley",
    "sample_periodic",
    "warp",
    "wrap",
    "SPECTRAL_BAND",
]

T = TypeVar("T")

#: Highest frequency (cycles per tile, per axis) that ``spectral_noise`` draws. The
#: coefficients are drawn on this fixed band so the field does not depend on the map
#: size; 128 cycles is the Nyquist limit of a 256-px map, the size the project trains
#: at. Larger maps show the same material without extra sub-2-px spectral detail.
SPECTRAL_BAND = 128

#: Standard deviation, per axis, of unit-variance white noise smoothed by the cubic
#: B-spline: its variance is the spline's autocorrelation at 0, the central value of
#: the degree-7 B-spline, 2416 / 5040 = 151 / 315 (averaged over sub-cell positions).
_BSPLINE_STD_1D = math.sqrt(151.0 / 315.0)


# ---------------------------------------------------------------- scalar draws
def uniform(gen: torch.Generator, lo: float, hi: float) -> float:
    """A float uniform in [lo, hi)."""
    return lo + (hi - lo) * float(torch.rand((), generator=gen))


def randint(gen: torch.Generator, lo: int, hi: int) -> int:
    """An int uniform in [lo, hi] (both ends included)."""
    return int(torch.randint(lo, hi + 1, (), generator=gen))


def coin(gen: torch.Generator, p: float) -> bool:
    """True with probability ``p``."""
    return float(torch.rand((), generator=gen)) < p


def choice(gen: torch.Generator, options: Sequence[T]) -> T:
    """One element of ``options``, uniformly."""
    return options[int(torch.randint(len(options), (), generator=gen))]


# ---------------------------------------------------------------- coordinates
def coords(size: int, device: torch.device | str = "cpu") -> tuple[torch.Tensor, torch.Tensor]:
    """Tile coordinates of the pixel centres: ``(x, y)``, each ``[N, N]`` in (0, 1).

    ``x`` grows along columns, ``y`` down the rows.
    """
    t = (torch.arange(size, device=device, dtype=torch.float32) + 0.5) / size
    y, x = torch.meshgrid(t, t, indexing="ij")
    return x, y


def smoothstep(edge0: float | torch.Tensor, edge1: float | torch.Tensor, x: torch.Tensor) -> torch.Tensor:
    """Hermite step from 0 (x <= edge0) to 1 (x >= edge1), C1-smooth in between."""
    t = ((x - edge0) / (edge1 - edge0)).clamp(0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


# ---------------------------------------------------------------- lattice noise
def _bspline_matrix(size: int, cells: list[int], phases: torch.Tensor, gains: list[float], device) -> torch.Tensor:
    """Periodic cubic-B-spline weights from the nodes of several lattices to pixels:
    ``[size, sum(cells)]``, lattice o's block scaled by ``gains[o]``.

    Node k of lattice o sits at tile coordinate (k + phases[o]) / cells[o]; indices wrap
    modulo cells[o], so every smoothed field is periodic. All lattices are built in one
    vectorised pass (fBm needs several); scatter_add handles cells < 4, where several of
    the four taps land on the same node.
    """
    c = torch.tensor(cells, dtype=torch.float32, device=device)[:, None]  # [L, 1]
    p = (torch.arange(size, device=device, dtype=torch.float32) + 0.5) / size * c - phases.to(device)[:, None]
    i0 = torch.floor(p)
    t = (p - i0)[..., None]  # [L, N, 1]
    t2, t3 = t * t, t * t * t
    w = torch.cat([(1 - t) ** 3, 3 * t3 - 6 * t2 + 4, -3 * t3 + 3 * t2 + 3 * t + 1, t3], dim=-1)
    w = w * (torch.tensor(gains, device=device)[:, None, None] / 6.0)
    taps = i0[..., None] + torch.arange(-1, 3, device=device, dtype=torch.float32)  # [L, N, 4]
    first = torch.tensor([0] + list(cells[:-1]), device=device).cumsum(0).float()[:, None, None]
    idx = (taps - c[..., None] * torch.floor(taps / c[..., None]) + first).long()
    out = torch.zeros(size, sum(cells), device=device)
    return out.scatter_add_(1, idx.permute(1, 0, 2).reshape(size, -1), w.permute(1, 0, 2).reshape(size, -1))


def _lattice_sum(
    gen: torch.Generator,
    size: int,
    cells: list[tuple[int, int]],
    gains: list[float],
    channels: int,
    device,
) -> torch.Tensor:
    """sum_o gains[o] * (B-spline-smoothed Gaussian lattice o, ``cells[o]`` = (rows,
    cols)): ``[channels, N, N]``. One matrix product for all lattices:
    ``Wy @ blockdiag(values_o) @ Wx^T``."""
    cy = [c[0] for c in cells]
    cx = [c[1] for c in cells]
    values = [torch.randn(channels, a, b, generator=gen) for a, b in cells]
    # Random lattice phase: B-spline noise varies faster midway between nodes than at
    # them; a fixed lattice would always put the tile border at the same place relative
    # to the nodes, so the border's statistics would differ from the interior's.
    phases = torch.rand(2, len(cells), generator=gen)
    blocks = torch.zeros(channels, sum(cy), sum(cx))
    r0 = c0 = 0
    for v, (a, b) in zip(values, cells):
        blocks[:, r0 : r0 + a, c0 : c0 + b] = v
        r0, c0 = r0 + a, c0 + b
    wy = _bspline_matrix(size, cy, phases[0], gains, device)
    wx = _bspline_matrix(size, cx, phases[1], [1.0] * len(cells), device)
    return wy @ blocks.to(device) @ wx.T


def lattice_noise(
    gen: torch.Generator,
    size: int,
    cells: int | tuple[int, int],
    channels: int = 1,
    device: torch.device | str = "cpu",
) -> torch.Tensor:
    """Periodic value noise: ``[channels, N, N]``, zero mean, unit variance (Gaussian).

    Args:
        cells: lattice nodes per tile, one int or ``(rows, cols)``; unequal counts
            stretch the features (e.g. ``(16, 2)``: long along x).
    """
    cy, cx = (cells, cells) if isinstance(cells, int) else cells
    return _lattice_sum(gen, size, [(cy, cx)], [1.0 / _BSPLINE_STD_1D**2], channels, device)


def fbm(
    gen: torch.Generator,
    size: int,
    cells: int,
    octaves: int = 4,
    gain: float = 0.5,
    channels: int = 1,
    device: torch.device | str = "cpu",
) -> torch.Tensor:
    """Fractal sum of ``octaves`` lattice noises, cells doubling each octave and amplitude
    multiplied by ``gain``: ``[channels, N, N]``, zero mean, unit variance."""
    amps = [gain**o for o in range(octaves)]
    norm = math.sqrt(sum(a * a for a in amps)) * _BSPLINE_STD_1D**2
    grids = [(cells * 2**o, cells * 2**o) for o in range(octaves)]
    return _lattice_sum(gen, size, grids, [a / norm for a in amps], channels, device)


# ---------------------------------------------------------------- spectral noise
def _gaussian_window(r: torch.Tensor, f: float) -> torch.Tensor:
    """exp(-(r / f)^2) with the exponent clamped at 80: exp(-80) ~ 2e-35 is still a
    normal float32, while letting it underflow into denormals makes CPU exp ~20x slower."""
    return torch.exp(-((r / f) ** 2).clamp(max=80.0))


def spectral_noise(
    gen: torch.Generator,
    size: int,
    *,
    f_lo: float = 1.0,
    f_hi: float = 64.0,
    exponent: float = 1.0,
    anisotropy: float = 1.0,
    angle: float = 0.0,
    channels: int = 1,
    device: torch.device | str = "cpu",
) -> torch.Tensor:
    """FFT-filtered Gaussian noise: ``[channels, N, N]``, zero mean, unit std per channel.

    The amplitude spectrum is ``r^-exponent * (1 - exp(-(r/f_lo)^2)) * exp(-(r/f_hi)^2)``
    with r in cycles per tile (exponent 1 is the 1/f falloff of natural textures).
    ``anisotropy`` > 1 compresses frequencies along the direction ``angle`` (radians,
    from +x towards +row), so features are elongated along it: brushed metal, wood
    pores, fibres. Coefficients are drawn for integer frequencies |f| < B per axis,
    B = min(``SPECTRAL_BAND``, ceil(3 f_hi)) (the window is below exp(-9) ~ 1e-4
    beyond 3 f_hi): the draw count, and so the field, does not depend on N.
    """
    band = min(SPECTRAL_BAND, math.ceil(3.0 * f_hi))
    # Stored layout: rows 0..B-1 hold frequencies 0..B-1, rows B..2B-1 hold -B..-1;
    # columns 0..B-1 hold frequencies 0..B-1 (the half-plane an rfft keeps).
    coef = torch.randn(channels, 2 * band, band, dtype=torch.complex64, generator=gen).to(device)

    pos = min(band, (size - 1) // 2 + 1)  # non-negative row frequencies kept
    neg = min(band - 1, size // 2)  # negative row frequencies kept
    cols = min(band, size // 2 + 1)
    fy = torch.cat([torch.arange(pos), torch.arange(-neg, 0)]).float().to(device)[:, None]
    fx = torch.arange(cols, dtype=torch.float32, device=device)[None, :]
    ca, sa = math.cos(angle), math.sin(angle)
    along = (fx * ca + fy * sa) * anisotropy
    across = fy * ca - fx * sa
    r = torch.sqrt(along * along + across * across)
    amp = r.clamp(min=1e-6) ** (-exponent) * (1.0 - _gaussian_window(r, f_lo)) * _gaussian_window(r, f_hi)
    amp[0, 0] = 0.0  # no DC: the field has zero mean by construction
    # The inverse DFT samples pixel corners (i / N); a half-pixel phase shift evaluates
    # the field at pixel centres like every other primitive here. Separable, so only
    # two 1-D complex exponentials (a full-size complex exp is slow on CPU).
    shift_y = torch.polar(torch.ones_like(fy), math.pi * fy / size)
    shift_x = torch.polar(torch.ones_like(fx), math.pi * fx / size)
    shift = shift_y * shift_x
    filt = amp * shift
    spec = torch.zeros(channels, size, size // 2 + 1, dtype=torch.complex64, device=device)
    spec[:, :pos, :cols] = coef[:, :pos, :cols] * filt[:pos]
    if neg:
        spec[:, size - neg :, :cols] = coef[:, 2 * band - neg :, :cols] * filt[pos:]
    field = torch.fft.irfft2(spec, s=(size, size), norm="forward")
    return field / field.std(dim=(-2, -1), keepdim=True).clamp(min=1e-8)


# ---------------------------------------------------------------- cellular noise
class Cells(NamedTuple):
    """Worley noise of one jittered grid, each ``[N, N]``.

    f1, f2: distances to the nearest and second-nearest feature point, in cell widths.
    cell: int64 index (row * cells + col, in [0, cells^2)) of the nearest point's
        cell, for per-cell random lookups.
    """

    f1: torch.Tensor
    f2: torch.Tensor
    cell: torch.Tensor


def wrap(a: torch.Tensor, n: float) -> torch.Tensor:
    """``a mod n`` in [0, n) for float tensors (floor form: faster than torch.remainder
    on CPU)."""
    return a - n * torch.floor(a / n)


def worley(
    gen: torch.Generator,
    x: torch.Tensor,
    y: torch.Tensor,
    cells: int,
    jitter: float = 0.9,
) -> Cells:
    """Cellular noise on a ``cells x cells`` jittered grid, periodic on the unit torus.

    Args:
        x, y: ``[N, N]`` tile coordinates (any reals; warped coordinates welcome).
        cells: grid cells per tile, >= 3 so the 3 x 3 neighbourhood holds distinct cells.
        jitter: how far (fraction of a cell) a point may move from its cell centre;
            below 1 so the 3 x 3 search finds the true F1 and nearly always F2.
    """
    if cells < 3:
        raise ValueError(f"worley needs cells >= 3, got {cells}")
    offsets = (torch.rand(cells * cells, 2, generator=gen) - 0.5) * jitter
    # Feature points of a padded (cells + 2)^2 grid: cell a in -1..cells sits next to
    # the tile, its point is that of the wrapped cell a mod cells. The padding is what
    # makes distances wrap around, and turns the 3 x 3 search into constant offsets.
    pad = cells + 2
    a = torch.arange(-1, cells + 1)
    wrapped = torch.remainder(a, cells)
    ids = (wrapped[:, None] * cells + wrapped[None, :]).reshape(-1)
    grid = a.float() + 0.5
    px_grid = grid[None, :].expand(pad, pad).reshape(-1)
    py_grid = grid[:, None].expand(pad, pad).reshape(-1)
    points = torch.stack([px_grid + offsets[ids, 0], py_grid + offsets[ids, 1]], dim=1)
    # (x, y) float32 pairs viewed as one int64: one index_select fetches both.
    packed = points.contiguous().view(torch.int64).reshape(-1).to(x.device)

    px = wrap(x * cells, cells).reshape(-1)
    py = wrap(y * cells, cells).reshape(-1)
    # clamp: float rounding can put px at exactly `cells`.
    base = ((torch.floor(py).clamp(max=cells - 1) + 1) * pad + torch.floor(px).clamp(max=cells - 1) + 1).int()
    f1 = torch.full_like(px, float("inf"))
    f2 = torch.full_like(px, float("inf"))
    spare = torch.empty_like(px)
    neighbours = [oy * pad + ox for oy in (-1, 0, 1) for ox in (-1, 0, 1)]
    # This loop dominates the cellular families, so it runs in place, and tracks the
    # arg-min without torch.where (slow on CPU): the neighbour number k is written into
    # the 4 lowest mantissa bits of the squared distance, so min() carries it along
    # (relative distance error <= 2^-19, irrelevant for patterns).
    for k, step in enumerate(neighbours):
        p = packed.index_select(0, base + step).view(torch.float32).view(-1, 2)
        d = (p[:, 0] - px).square_().add_((p[:, 1] - py).square_())
        d.view(torch.int32).bitwise_and_(~15).bitwise_or_(k)
        torch.maximum(f1, d, out=spare)
        torch.minimum(f2, spare, out=f2)
        torch.minimum(f1, d, out=f1)
    k_best = f1.view(torch.int32).bitwise_and(15)
    best = base + torch.tensor(neighbours, dtype=torch.int32, device=x.device).index_select(0, k_best)
    index = ids.to(x.device).index_select(0, best).view(x.shape)
    return Cells(f1.sqrt_().view(x.shape), f2.sqrt_().view(x.shape), index)


# ---------------------------------------------------------------- warping
def sample_periodic(field: torch.Tensor, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """Bilinear lookup with wrap-around: ``field [C, H, W]`` at tile coords ``x, y``
    (``[N, N]``, any reals) -> ``[C, N, N]``."""
    c, h, w = field.shape
    px, py = x * w - 0.5, y * h - 0.5
    x0, y0 = torch.floor(px), torch.floor(py)
    tx, ty = px - x0, py - y0
    x0 = torch.remainder(x0.long(), w)
    y0 = torch.remainder(y0.long(), h)
    x1, y1 = torch.remainder(x0 + 1, w), torch.remainder(y0 + 1, h)
    flat = field.reshape(c, h * w)

    def tap(yy: torch.Tensor, xx: torch.Tensor) -> torch.Tensor:
        return flat[:, (yy * w + xx).reshape(-1)].reshape(c, *x.shape)

    top = tap(y0, x0) * (1 - tx) + tap(y0, x1) * tx
    bottom = tap(y1, x0) * (1 - tx) + tap(y1, x1) * tx
    return top * (1 - ty) + bottom * ty


def warp(field: torch.Tensor, dx: torch.Tensor, dy: torch.Tensor) -> torch.Tensor:
    """Domain warp: ``out(p) = field(p + (dx, dy))`` for ``field [C, N, N]`` and periodic
    displacements ``dx, dy [N, N]`` in tile units; the result stays periodic."""
    x, y = coords(field.shape[-1], field.device)
    return sample_periodic(field, x + dx, y + dy)
