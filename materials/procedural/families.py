"""Material families of the procedural generator: one function per family.

Each family is ``fn(gen, size, glossy, device) -> Layers`` where ``Layers`` holds

- ``height``    ``[1, N, N]`` in tile units (1 = side of the map), turned into normals by
  ``materials.procedural.height.height_to_normal``;
- ``diffuse``   ``[3, N, N]`` linear RGB albedo, dielectrics in [0.02, 0.9], metals ~0;
- ``roughness`` ``[1, N, N]`` in [0.05, 1] (alpha = roughness^2, SPEC section 2);
- ``specular``  ``[3, N, N]`` linear RGB F0: grey 0.02-0.08 for dielectrics, grey
  0.25-0.5 for glossy coated dielectrics, coloured 0.5-1.0 for metals.

Every random choice (scale, count, orientation, palette, finish) is drawn from ``gen``
and the number of draws does not depend on ``size``, so a seed gives the same material
at every resolution. ``glossy`` selects the strongly specular finish (low roughness, high
F0) that the method exists for (SPEC section 1: a saturated flash highlight).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from types import MappingProxyType
from typing import NamedTuple

import torch

from materials.procedural.color import jitter_colors, random_color
from materials.procedural.noise import (
    choice,
    coin,
    coords,
    fbm,
    lattice_noise,
    randint,
    smoothstep,
    spectral_noise,
    uniform,
    worley,
    wrap,
)

__all__ = [
    "Layers",
    "FAMILY_FUNCTIONS",
    "DIELECTRIC_F0",
    "GLOSSY_F0",
    "GLOSSY_ROUGHNESS",
    "ROUGHNESS_RANGE",
    "DIFFUSE_RANGE",
    "METAL_DIFFUSE_MAX",
    "METAL_F0",
]

# ---------------------------------------------------------------- physical ranges
#: F0 of common dielectrics: ((n - 1) / (n + 1))^2 for refractive index n = 1.33 (water,
#: 0.020) to n = 1.8 (dense glass, glazes, 0.082).
DIELECTRIC_F0 = (0.02, 0.08)
#: F0 of the "strongly specular" coated finishes (varnish, glaze, lacquer, polish).
#: Deliberately above the physical dielectric range: a single GGX lobe standing in for a
#: clear coat, and the saturated-highlight regime the method targets (SPEC section 1).
GLOSSY_F0 = (0.25, 0.5)
#: Base roughness of glossy finishes; below the 0.3 that counts as "low roughness".
GLOSSY_ROUGHNESS = (0.05, 0.25)
#: Final roughness clamp: 0.05 keeps alpha = r^2 >= 0.0025, a near-mirror that stays
#: finite in GGX; the renderer presets apply their own, higher floor (SPEC section 2).
ROUGHNESS_RANGE = (0.05, 1.0)
#: Dielectric albedo range: fresh snow ~0.9, charcoal / black paint ~0.02-0.04.
DIFFUSE_RANGE = (0.02, 0.9)
#: Metals have no diffuse body reflection; a little dust or oxide keeps it just above 0.
METAL_DIFFUSE_MAX = 0.03
#: Linear RGB F0 of metals (values widely tabulated from measured complex IORs, e.g.
#: Naty Hoffman, "Physics and Math of Shading", SIGGRAPH 2015 course).
METAL_F0 = {
    "iron": (0.56, 0.57, 0.58),
    "silver": (0.95, 0.93, 0.88),
    "aluminium": (0.91, 0.92, 0.92),
    "gold": (1.00, 0.71, 0.29),
    "copper": (0.95, 0.64, 0.54),
    "brass": (0.91, 0.78, 0.42),
    "chromium": (0.55, 0.56, 0.55),
    "nickel": (0.66, 0.61, 0.53),
    "titanium": (0.54, 0.50, 0.45),
}


class Layers(NamedTuple):
    """One family's output before normals (shapes and ranges in the module docstring)."""

    height: torch.Tensor
    diffuse: torch.Tensor
    roughness: torch.Tensor
    specular: torch.Tensor


Family = Callable[[torch.Generator, int, bool, "torch.device | str"], Layers]


# ---------------------------------------------------------------- helpers
def _finish(gen: torch.Generator, glossy: bool, matte: tuple[float, float]) -> tuple[float, float]:
    """(base roughness, grey F0) of a dielectric surface: glossy coat or ``matte`` range."""
    if glossy:
        return uniform(gen, *GLOSSY_ROUGHNESS), uniform(gen, *GLOSSY_F0)
    return uniform(gen, *matte), uniform(gen, *DIELECTRIC_F0)


def _fill(color: torch.Tensor, size: int, device) -> torch.Tensor:
    """``[C]`` -> constant map ``[C, N, N]``."""
    return color.to(device)[:, None, None].expand(-1, size, size)


def _lerp(a: torch.Tensor, b: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
    """a + (b - a) t, broadcasting maps ``[C, N, N]`` with masks ``[1, N, N]``."""
    return a + (b - a) * t


def _lookup(table: torch.Tensor, index: torch.Tensor) -> torch.Tensor:
    """Per-cell values: ``table [K, C]`` at ``index [N, N]`` (int) -> ``[C, N, N]``.

    index_select on the flat index: several times faster on CPU than advanced indexing,
    and the result is contiguous in the channels-first layout.
    """
    flat = table.to(index.device).T.contiguous().index_select(1, index.reshape(-1).int())
    return flat.view(table.shape[1], *index.shape)


def _above(a: torch.Tensor, b: torch.Tensor | float) -> torch.Tensor:
    """1.0 where a > b, else 0.0 (float mask; arithmetic blends are faster than
    torch.where on CPU)."""
    return (a - b).sign().clamp(min=0.0)


def _grey(value: torch.Tensor | float, size: int, device) -> torch.Tensor:
    """A grey F0 ``[3, N, N]`` from a scalar or a ``[1, N, N]`` map."""
    if isinstance(value, torch.Tensor):
        return value.expand(3, -1, -1)
    return torch.full((3, size, size), float(value), device=device)


def _coords(gen: torch.Generator, size: int, device) -> tuple[torch.Tensor, torch.Tensor]:
    """Tile coordinates ``(x, y)`` shifted by a random phase in [0, 1)^2.

    Every pattern repeats a whole number of times per tile, so the shift keeps it
    periodic; it puts the tile border (the seam) at a random place in the pattern
    instead of always on a grout line or thread gap.
    """
    ox, oy = uniform(gen, 0.0, 1.0), uniform(gen, 0.0, 1.0)
    x, y = coords(size, device)
    return x + ox, y + oy


def _edge(threshold: float, distance: torch.Tensor, size: int) -> torch.Tensor:
    """Anti-aliased step ``distance > threshold`` -> ``[1, N, N]`` in [0, 1].

    ``distance`` in tile units; the ramp is 1.5 px wide and *centred* on the threshold,
    so the covered area (e.g. the share of grout) does not grow at small map sizes.
    """
    half = 0.75 / size
    return smoothstep(threshold - half, threshold + half, distance)[None]


def _edge_distance(f: torch.Tensor) -> torch.Tensor:
    """Distance of a fractional coordinate in [0, 1) to the nearest cell edge."""
    return torch.minimum(f, 1.0 - f)


def _done(height, diffuse, roughness, specular, *, metal: bool = False) -> Layers:
    """Clamp to the documented ranges (noise tails would otherwise leak out)."""
    lo, hi = (0.0, METAL_DIFFUSE_MAX) if metal else DIFFUSE_RANGE
    return Layers(
        height.reshape(1, *height.shape[-2:]),
        diffuse.clamp(lo, hi),
        roughness.clamp(*ROUGHNESS_RANGE),
        specular.clamp(0.0, 1.0),
    )


# ---------------------------------------------------------------- tiles
def tiles(gen: torch.Generator, size: int, glossy: bool, device="cpu") -> Layers:
    """Ceramic tiles in a grid (2-8 per side, square or rectangular), grout lines,
    bevelled edges, slightly tilted faces; optional two-colour checker."""
    nx = randint(gen, 2, 8)
    ny = nx if coin(gen, 0.6) else randint(gen, 2, 8)
    cell = min(1.0 / nx, 1.0 / ny)
    grout_half = uniform(gen, 0.025, 0.07) * cell
    bevel = uniform(gen, 0.02, 0.08) * cell
    thickness = uniform(gen, 0.002, 0.005)
    tilt = uniform(gen, 0.0, 0.02)  # face slope variation between tiles (laying error)
    colors = jitter_colors(gen, ((0.0, 1.0), (0.03, 0.75), (0.3, 0.95)), nx * ny, (0.01, 0.04, 0.06))
    # Checker of a second colour; only with even counts, or it would break at the wrap.
    if coin(gen, 0.5) and nx % 2 == 0 and ny % 2 == 0:
        second = jitter_colors(gen, ((0.0, 1.0), (0.0, 0.8), (0.1, 0.95)), nx * ny, (0.01, 0.04, 0.06))
        parity = (torch.arange(ny)[:, None] + torch.arange(nx)[None, :]).remainder(2).reshape(-1, 1)
        colors = torch.where(parity.bool(), second, colors)
    grout_color = random_color(gen, (0.05, 0.15), (0.0, 0.25), (0.25, 0.85))
    face_r, face_f0 = _finish(gen, glossy, (0.3, 0.7))
    grout_r = uniform(gen, 0.75, 1.0)
    tilts = (torch.rand(nx * ny, 2, generator=gen) * 2 - 1) * tilt
    mottle = spectral_noise(gen, size, f_lo=2, f_hi=24, exponent=1.0, device=device)
    sand = spectral_noise(gen, size, f_lo=16, f_hi=128, exponent=0.0, device=device)

    x, y = _coords(gen, size, device)
    u, v = x * nx, y * ny
    iu, iv = torch.floor(u), torch.floor(v)
    fu, fv = u - iu, v - iv
    d = torch.minimum(_edge_distance(fu) / nx, _edge_distance(fv) / ny)
    # Keep edges at least ~1.5 px wide: sharper steps alias and give one-pixel normals.
    face = smoothstep(grout_half, grout_half + max(bevel, 1.5 / size), d)[None]
    # The glaze covers the bevel too: colour and finish switch at the grout line.
    solid = _edge(grout_half, d, size)
    idx = (wrap(iv, ny) * nx + wrap(iu, nx)).int()
    t = _lookup(tilts, idx)
    face_h = thickness + t[0:1] * (fu - 0.5) / nx + t[1:2] * (fv - 0.5) / ny + 3e-5 * mottle
    height = face * face_h + (1 - face) * 1.5e-4 * sand

    face_col = _lookup(colors, idx) * (1 + 0.06 * mottle)
    grout_col = _fill(grout_color, size, device) * (1 + 0.15 * sand)
    diffuse = _lerp(grout_col, face_col, solid)
    roughness = _lerp(grout_r + 0.05 * sand, face_r * (1 + 0.1 * mottle), solid)
    specular = _grey(_lerp(torch.full_like(solid, 0.035), torch.full_like(solid, face_f0), solid), size, device)
    return _done(height, diffuse, roughness, specular)


# ---------------------------------------------------------------- bricks
def bricks(gen: torch.Generator, size: int, glossy: bool, device="cpu") -> Layers:
    """Brick wall: running / random / stack bond, rough mortar, chipped edges, per-brick
    colour variation (red, brown, yellow or grey clay)."""
    rows = 2 * randint(gen, 2, 6)  # even, so the half-brick offset of odd rows wraps
    per_row = max(1, round(rows / uniform(gen, 1.8, 3.5)))  # brick length : height ~2-3.5
    bond = choice(gen, ("running", "running", "random", "stack"))
    row_offsets = torch.rand(rows, generator=gen)
    if bond == "running":
        row_offsets = (torch.arange(rows) % 2) * 0.5
    elif bond == "stack":
        row_offsets = torch.zeros(rows)
    brick_h = 1.0 / rows
    mortar_half = uniform(gen, 0.03, 0.07) * brick_h
    rounding = uniform(gen, 0.05, 0.25) * brick_h
    depth = uniform(gen, 0.003, 0.008)
    clay = choice(
        gen,
        (
            ((-0.02, 0.05), (0.45, 0.8), (0.35, 0.7)),  # red
            ((0.04, 0.09), (0.35, 0.7), (0.25, 0.55)),  # brown
            ((0.09, 0.14), (0.3, 0.6), (0.55, 0.85)),  # yellow
            ((0.0, 1.0), (0.0, 0.1), (0.3, 0.7)),  # grey
        ),
    )
    colors = jitter_colors(gen, clay, rows * per_row, (0.02, 0.1, 0.15))
    mortar_color = random_color(gen, (0.05, 0.15), (0.0, 0.2), (0.35, 0.8))
    face_r, face_f0 = _finish(gen, glossy, (0.7, 0.95))
    edge_noise = spectral_noise(gen, size, f_lo=8, f_hi=40, exponent=1.0, device=device)
    surface = spectral_noise(gen, size, f_lo=4, f_hi=100, exponent=1.0, device=device)
    grain = spectral_noise(gen, size, f_lo=32, f_hi=128, exponent=0.0, device=device)

    x, y = _coords(gen, size, device)
    v = y * rows
    iv = torch.floor(v)
    row = wrap(iv, rows)
    u = x * per_row + _lookup(row_offsets[:, None], row.int())[0]
    iu = torch.floor(u)
    d = torch.minimum(_edge_distance(u - iu) / per_row, _edge_distance(v - iv) / rows)
    d = d + 0.25 * mortar_half * edge_noise[0]  # chipped, irregular brick edges
    face = smoothstep(mortar_half, mortar_half + max(rounding, 1.5 / size), d)[None]
    solid = _edge(mortar_half, d, size)  # brick vs mortar
    idx = (row * per_row + wrap(iu, per_row)).int()
    pits = (grain - 1.8).clamp(min=0.0)
    height = face * (depth + 4e-4 * surface - 3e-4 * pits) + (1 - face) * 2e-4 * grain

    brick_col = _lookup(colors, idx) * (1 + 0.12 * surface) * (1 - 0.3 * pits)
    mortar_col = _fill(mortar_color, size, device) * (1 + 0.12 * grain)
    diffuse = _lerp(mortar_col, brick_col, solid)
    roughness = _lerp(0.95 + 0.05 * grain, face_r * (1 + 0.08 * surface) + 0.2 * pits, solid)
    specular = _grey(_lerp(torch.full_like(solid, 0.03), torch.full_like(solid, face_f0), solid), size, device)
    return _done(height, diffuse, roughness, specular)


# ---------------------------------------------------------------- wood
def wood(gen: torch.Generator, size: int, glossy: bool, device="cpu") -> Layers:
    """Flat-sawn wood: growth rings bent by anisotropic noise, pores along the grain,
    optional planks with end joints; raw / oiled or varnished."""
    rings = randint(gen, 4, 14)
    slant = randint(gen, -2, 2)  # integer, so the slanted ring pattern stays periodic
    bend = uniform(gen, 0.5, 2.5)  # ring wander, in rings
    planks = choice(gen, (1, 2, 3, 4, 5, 6, 8))
    joints = randint(gen, 1, 2)
    joint_pos = torch.rand(planks, joints, generator=gen)
    plank_shift = torch.rand(planks * joints, 1, generator=gen) * 10.0
    plank_tint = 1.0 + (torch.rand(planks * joints, 1, generator=gen) * 2 - 1) * 0.15
    gap_half = uniform(gen, 0.0015, 0.004)
    sharp = uniform(gen, 1.5, 5.0)  # late-wood sharpness
    early = random_color(gen, (0.04, 0.1), (0.3, 0.7), (0.35, 0.85))
    late = early * uniform(gen, 0.35, 0.7) * torch.tensor([1.0, 0.9, 0.8])  # darker, warmer
    base_r, f0 = _finish(gen, glossy, (0.4, 0.8))
    bend_field = lattice_noise(gen, size, (randint(gen, 6, 12), randint(gen, 1, 3)), device=device)
    fine_bend = fbm(gen, size, 4, octaves=3, device=device)
    # Pores follow the fibres, i.e. the board's long axis (x), even where slanted
    # rings cross the board.
    pores = spectral_noise(
        gen, size, f_lo=8, f_hi=110, exponent=0.3, anisotropy=uniform(gen, 15, 40), angle=0.0, device=device
    )
    figure = spectral_noise(gen, size, f_lo=1, f_hi=12, exponent=1.0, device=device)

    x, y = _coords(gen, size, device)
    pv = y * planks
    plank = wrap(torch.floor(pv), planks)
    jp = _lookup(joint_pos, plank.int()).permute(1, 2, 0)  # [N, N, joints]
    xw = wrap(x, 1.0)[..., None]  # x carries a random phase: compare joints within [0, 1)
    rel = wrap(xw - jp, 1.0)
    segment = wrap(_above(xw, jp).sum(-1), joints)  # wraps: last segment = first
    seg_idx = (plank * joints + segment).int()
    if planks == 1:  # one board spans the tile: no joints, no seams
        seg_idx = torch.zeros_like(seg_idx)
    dist_joint = torch.minimum(rel, 1.0 - rel).min(-1).values
    phase = rings * y + slant * x + bend * bend_field[0] + 0.15 * fine_bend[0] + _lookup(plank_shift, seg_idx)[0]
    t = wrap(phase, 1.0)
    latewood = (t**sharp)[None]
    gap = torch.minimum(_edge_distance(pv - torch.floor(pv)) / planks, dist_joint)
    gaps = 1 - _edge(gap_half, gap, size) if planks > 1 else torch.zeros(1, size, size, device=device)
    pore = (pores - 1.0).clamp(min=0.0)

    tint = _lookup(plank_tint, seg_idx) * (1 + 0.1 * figure)
    diffuse = _lerp(_fill(early, size, device), _fill(late, size, device), latewood) * tint
    diffuse = diffuse * (1 - 0.25 * pore) * (1 - 0.7 * gaps)
    height = 2e-4 * latewood - 1.5e-4 * pore - 3e-3 * gaps
    # Varnish fills the pores: only raw / oiled wood shows them in the roughness.
    roughness = base_r * (1 + 0.1 * figure) + (0.0 if glossy else 0.15) * pore + 0.5 * gaps
    specular = _grey(f0, size, device)
    return _done(height, diffuse, roughness, specular)


# ---------------------------------------------------------------- stone
def stone(gen: torch.Generator, size: int, glossy: bool, device="cpu") -> Layers:
    """Stone in four kinds: veined marble, speckled granite, rough cracked rock, and
    flagstones set in mortar; polished (glossy) or honed / natural."""
    kind = choice(gen, ("marble", "granite", "rock", "flagstone"))
    x, y = _coords(gen, size, device)
    base_r, f0 = _finish(gen, glossy, (0.35, 0.9) if kind in ("marble", "granite") else (0.6, 0.95))
    fine = spectral_noise(gen, size, f_lo=16, f_hi=128, exponent=0.5, device=device)

    if kind == "marble":
        base = choice(
            gen,
            (
                ((0.0, 1.0), (0.0, 0.06), (0.75, 0.95)),  # white
                ((0.0, 1.0), (0.0, 0.1), (0.05, 0.2)),  # black
                ((0.3, 0.45), (0.2, 0.6), (0.15, 0.45)),  # green
                ((0.0, 0.1), (0.1, 0.35), (0.55, 0.85)),  # pink / cream
                ((0.0, 1.0), (0.0, 0.08), (0.35, 0.65)),  # grey
            ),
        )
        c1 = jitter_colors(gen, base, 2, (0.02, 0.05, 0.08))
        vein_color = random_color(gen, (0.0, 1.0), (0.0, 0.4), (0.05, 0.3) if base[2][0] > 0.3 else (0.7, 0.95))
        m, n = randint(gen, -2, 2), randint(gen, 1, 3)
        turbulence = uniform(gen, 0.4, 1.2)  # above ~1.5 veins close into contour loops
        sharp = uniform(gen, 6.0, 30.0)
        cells = randint(gen, 2, 4)
        clouds = fbm(gen, size, cells, octaves=5, device=device)[0]
        # Perlin's marble: sin(phase + k * turbulence), turbulence = sum of |noise| over
        # octaves; the |.| creases give veins their sharp bends and branching.
        turb = sum(lattice_noise(gen, size, cells * 2**o, device=device)[0].abs() * 0.5**o for o in range(5))
        fade = smoothstep(-0.8, 0.8, lattice_noise(gen, size, cells, device=device)[0])
        phase = m * x + n * y + turbulence * turb
        vein = (1 - torch.sin(math.pi * phase).abs()) ** sharp
        vein2 = (1 - torch.sin(math.pi * (2 * phase + 0.5 * clouds)).abs()) ** (2 * sharp)
        halo = (1 - torch.sin(math.pi * phase).abs()) ** (sharp / 6)  # soft stain around veins
        v = (vein * (0.4 + 0.6 * fade) + 0.3 * halo * fade + 0.6 * vein2 * (1 - fade)).clamp(max=1.0)[None]
        cloud_t = smoothstep(-1.5, 1.5, clouds)[None]
        ground = _lerp(_fill(c1[0], size, device), _fill(c1[1], size, device), cloud_t)
        diffuse = _lerp(ground, _fill(vein_color, size, device), v)
        # Polished marble is optically flat; honed marble keeps a faint grain.
        height = (0.0 if glossy else 3e-5) * fine + (0.0 if glossy else 1e-4) * v
        roughness = base_r * (1 + 0.1 * fine[0:1]) + 0.1 * v
    elif kind == "granite":
        hue = uniform(gen, 0.0, 1.0)
        # Feldspar in the stone's hue, quartz (light), mica / hornblende (dark), accent.
        minerals = torch.stack(
            [
                random_color(gen, (hue - 0.03, hue + 0.03), (0.05, 0.4), (0.35, 0.8)),
                random_color(gen, (0.0, 1.0), (0.0, 0.12), (0.7, 0.95)),
                random_color(gen, (0.0, 1.0), (0.0, 0.2), (0.12, 0.25)),
                random_color(gen, (hue - 0.06, hue + 0.06), (0.2, 0.6), (0.25, 0.6)),
            ]
        )
        share = torch.rand(4, generator=gen) ** 2 + 0.05
        cum = torch.cumsum(share / share.sum(), 0)
        cells = randint(gen, 40, 90)
        which = torch.searchsorted(cum, torch.rand(cells * cells, generator=gen)).clamp(max=3)
        shade = 1 + (torch.rand(cells * cells, 1, generator=gen) * 2 - 1) * 0.15
        dx, dy = fbm(gen, size, 8, octaves=3, channels=2, device=device) * (0.4 / cells)
        c = worley(gen, x + dx, y + dy, cells, jitter=0.9)
        per_cell = _lookup(torch.cat([minerals[which] * shade, shade], dim=1), c.cell)
        diffuse = per_cell[:3] * (1 + 0.08 * fine)
        border = (1 - smoothstep(0.0, 0.08, c.f2 - c.f1))[None]
        # Polished granite is flat; flamed / honed granite keeps grain relief.
        height = (0.0 if glossy else 2e-4) * (0.5 * fine + per_cell[3:] * 2 - border)
        roughness = base_r * (1 + 0.1 * fine) + 0.1 * border
    elif kind == "rock":
        color = random_color(gen, (0.03, 0.15), (0.0, 0.35), (0.25, 0.75))
        amp = uniform(gen, 0.003, 0.008)
        relief = spectral_noise(gen, size, f_lo=1, f_hi=96, exponent=uniform(gen, 1.0, 1.5), device=device)
        cells = randint(gen, 3, 8)
        dx, dy = fbm(gen, size, 4, octaves=4, channels=2, device=device) * (0.4 / cells)
        c = worley(gen, x + dx, y + dy, cells, jitter=0.9)
        crack_w = uniform(gen, 0.02, 0.06)
        cracked = 1.0 if coin(gen, 0.6) else 0.0
        crack = (1 - smoothstep(0.0, crack_w, c.f2 - c.f1))[None] * cracked
        tone = spectral_noise(gen, size, f_lo=1, f_hi=16, exponent=1.0, device=device)
        diffuse = _fill(color, size, device) * (1 + 0.25 * tone + 0.1 * fine + 0.1 * relief) * (1 - 0.5 * crack)
        height = amp * (0.3 * relief + 0.05 * fine) - amp * 0.5 * crack
        roughness = base_r * (1 + 0.1 * fine) + 0.05 * crack
    else:  # flagstone
        cells = randint(gen, 3, 7)
        dx, dy = fbm(gen, size, 3, octaves=4, channels=2, device=device) * (0.25 / cells)
        c = worley(gen, x + dx, y + dy, cells, jitter=0.85)
        colors = jitter_colors(gen, ((0.02, 0.15), (0.05, 0.4), (0.25, 0.7)), cells * cells, (0.03, 0.1, 0.15))
        mortar_color = random_color(gen, (0.05, 0.15), (0.0, 0.15), (0.3, 0.7))
        lift = torch.rand(cells * cells, 1, generator=gen)
        joint = uniform(gen, 0.06, 0.15)
        relief = spectral_noise(gen, size, f_lo=2, f_hi=96, exponent=1.2, device=device)
        gap = c.f2 - c.f1  # cell widths
        face = smoothstep(joint, joint + max(0.1, 1.5 * cells / size), gap)[None]  # rounded edge
        solid = _edge(joint / cells, gap / cells, size)  # stone vs mortar
        stone_col = _lookup(colors, c.cell) * (1 + 0.15 * relief + 0.1 * fine)
        mortar_col = _fill(mortar_color, size, device) * (1 + 0.15 * fine)
        diffuse = _lerp(mortar_col, stone_col, solid)
        height = face * (4e-3 + 1.5e-3 * _lookup(lift, c.cell) + 8e-4 * relief) + 2e-4 * fine
        roughness = _lerp(torch.full_like(solid, 0.95), base_r * (1 + 0.1 * fine), solid)
        f0_map = _lerp(torch.full_like(solid, 0.03), torch.full_like(solid, f0), solid)
        return _done(height, diffuse, roughness, _grey(f0_map, size, device))
    return _done(height, diffuse, roughness, _grey(f0, size, device))


# ---------------------------------------------------------------- fabric
def _weave(kind: str) -> torch.Tensor:
    """``[R, R]`` bool weave repeat: True where the warp (vertical) thread is on top."""
    i = torch.arange({"plain": 2, "basket": 4, "twill3": 3, "twill4": 4, "satin": 5}[kind])
    r, c = i[:, None], i[None, :]
    if kind == "plain":
        return (r + c) % 2 == 0
    if kind == "basket":
        return (r // 2 + c // 2) % 2 == 0
    if kind == "twill3":
        return (r + c) % 3 < 2
    if kind == "twill4":
        return (r + c) % 4 < 2
    return (2 * c - r) % 5 == 0  # 5-end satin, move 2: long weft floats


def fabric(gen: torch.Generator, size: int, glossy: bool, device="cpu") -> Layers:
    """Woven cloth: plain, basket, twill or satin weave of round threads with fibre
    noise, optional striped / plaid yarn colours; matte, or silk-like when glossy."""
    kind = choice(gen, ("plain", "basket", "twill3", "twill4", "satin"))
    pattern = _weave(kind)
    rep = pattern.shape[0]
    count = rep * randint(gen, math.ceil(12 / rep), 48 // rep)  # threads per tile
    width = uniform(gen, 0.7, 0.95)  # thread width / spacing
    thick = uniform(gen, 0.12, 0.25) / count
    warp_base = ((0.0, 1.0), (0.05, 0.85), (0.2, 0.9))
    warp_cols = jitter_colors(gen, warp_base, count, (0.01, 0.05, 0.06))
    if coin(gen, 0.5):
        weft_cols = warp_cols[torch.randperm(count, generator=gen)] * uniform(gen, 0.7, 1.1)
    else:
        weft_cols = jitter_colors(gen, warp_base, count, (0.01, 0.05, 0.06))
    if coin(gen, 0.35):  # stripes / plaid: threads grouped in coloured bands
        bands = randint(gen, 2, 4)
        band_cols = torch.stack([random_color(gen, (0, 1), (0.2, 0.9), (0.05, 0.8)) for _ in range(bands)])
        # The colour repeat divides the thread count, so the plaid wraps seamlessly.
        repeats = [d for d in range(2 * bands, count + 1) if count % d == 0]
        repeat = choice(gen, repeats)
        band_of = (torch.arange(count) % repeat) * bands // repeat
        warp_cols = band_cols[band_of]
        if coin(gen, 0.6):
            weft_cols = band_cols[band_of]
    base_r, f0 = _finish(gen, glossy, (0.65, 0.95))
    wobble_x, wobble_y = fbm(gen, size, 4, octaves=3, channels=2, device=device) * (0.15 / count)
    fibres = dict(f_lo=16, f_hi=128, exponent=0.3, anisotropy=8.0, device=device)
    fib_warp = spectral_noise(gen, size, angle=math.pi / 2, **fibres)  # along the warp (y)
    fib_weft = spectral_noise(gen, size, angle=0.0, **fibres)
    mottle = lattice_noise(gen, size, 4, device=device)

    x, y = _coords(gen, size, device)
    u, v = (x + wobble_x) * count, (y + wobble_y) * count
    iu, iv = torch.floor(u), torch.floor(v)
    fu, fv = u - iu, v - iv
    iu, iv = wrap(iu, count), wrap(iv, count)
    warp_top = _lookup(pattern.float().reshape(-1, 1), (wrap(iv, rep) * rep + wrap(iu, rep)).int())[0]
    # Cosine cross-section of a round thread, zero in the gap between threads.
    s_warp = ((fu - 0.5) / (width / 2)).abs().clamp(max=1.0)
    s_weft = ((fv - 0.5) / (width / 2)).abs().clamp(max=1.0)
    p_warp = torch.cos(0.5 * math.pi * s_warp)
    p_weft = torch.cos(0.5 * math.pi * s_weft)
    # A thread is high where it crosses over, low where it passes under.
    h_warp = p_warp * (0.4 + warp_top * (0.35 + 0.25 * torch.sin(math.pi * fv)))
    h_weft = p_weft * (0.4 + (1 - warp_top) * (0.35 + 0.25 * torch.sin(math.pi * fu)))
    on_warp = _above(h_warp, h_weft)[None]
    h = torch.maximum(h_warp, h_weft)[None]
    fib = _lerp(fib_weft, fib_warp, on_warp)
    height = thick * (h + 0.08 * fib)

    yarn = _lerp(_lookup(weft_cols, iv.int()), _lookup(warp_cols, iu.int()), on_warp)
    # Gaps between threads read darker (the backing shows through / shadows).
    diffuse = yarn * (1 + 0.12 * fib + 0.05 * mottle) * (0.55 + 0.45 * smoothstep(0.0, 0.4, h))
    roughness = base_r * (1 + 0.08 * fib + 0.3 * (1 - h))  # fuzzier between threads
    specular = _grey(f0 * (0.8 + 0.2 * h), size, device)  # weaker in the gaps
    return _done(height, diffuse, roughness, specular)


# ---------------------------------------------------------------- metal
def metal(gen: torch.Generator, size: int, glossy: bool, device="cpu") -> Layers:
    """Bare metal (iron, silver, gold, copper, brass, ...): brushed, scratched, hammered
    or polished with smudges. Diffuse ~0, coloured F0 in [0.5, 1]."""
    name = choice(gen, tuple(METAL_F0))
    f0 = (torch.tensor(METAL_F0[name]) + (torch.rand(3, generator=gen) * 2 - 1) * 0.03).clamp(0.5, 1.0)
    kind = choice(gen, ("brushed", "scratched", "hammered", "polished"))
    base_r = uniform(gen, *GLOSSY_ROUGHNESS) if glossy else uniform(gen, 0.3, 0.6)
    dust = uniform(gen, 0.0, 0.02)
    smudge = spectral_noise(gen, size, f_lo=2, f_hi=24, exponent=1.0, device=device)
    x, y = _coords(gen, size, device)

    if kind == "brushed":
        angle = uniform(gen, 0.0, math.pi)
        streaks = spectral_noise(
            gen, size, f_lo=16, f_hi=128, exponent=0.2, anisotropy=uniform(gen, 30, 80), angle=angle, device=device
        )
        height = 1e-4 * streaks
        roughness = base_r * (1 + 0.1 * streaks + 0.1 * smudge)
    elif kind == "scratched":
        scratches = torch.zeros(1, size, size, device=device)
        for _ in range(randint(gen, 2, 5)):
            n = spectral_noise(
                gen,
                size,
                f_lo=8,
                f_hi=128,
                exponent=0.0,
                anisotropy=uniform(gen, 60, 150),
                angle=uniform(gen, 0.0, math.pi),
                device=device,
            )
            scratches = scratches + (n - uniform(gen, 2.0, 2.8)).clamp(min=0.0)
        scratches = scratches.clamp(max=1.0)
        height = -4e-4 * scratches + 1e-5 * smudge
        roughness = base_r * (1 + 0.15 * smudge) + 0.3 * scratches
    elif kind == "hammered":
        cells = randint(gen, 6, 16)
        dx, dy = fbm(gen, size, 4, octaves=3, channels=2, device=device) * (0.2 / cells)
        c = worley(gen, x + dx, y + dy, cells, jitter=0.8)
        depth = uniform(gen, 0.05, 0.15) / cells
        height = (depth * c.f1**2)[None]  # spherical-cap dimple around each hammer blow
        roughness = base_r * (1 + 0.1 * smudge)
    else:  # polished: smudges and faint hairline scratches only
        hair = spectral_noise(
            gen,
            size,
            f_lo=16,
            f_hi=128,
            exponent=0.0,
            anisotropy=100.0,
            angle=uniform(gen, 0.0, math.pi),
            device=device,
        )
        lines = (hair - 2.6).clamp(min=0.0)
        height = -1e-4 * lines
        roughness = base_r * (1 + 0.1 * smudge) + 0.15 * lines
    diffuse = torch.full((3, size, size), dust, device=device)
    specular = (_fill(f0, size, device) * (1 - 0.03 * smudge.clamp(min=0.0))).clamp(0.5, 1.0)
    return _done(height, diffuse, roughness, specular, metal=True)


# ---------------------------------------------------------------- leather
def leather(gen: torch.Generator, size: int, glossy: bool, device="cpu") -> Layers:
    """Grained leather: domed Voronoi cells split by creases, large wrinkles and pores;
    brown / black / tan / coloured dye; natural, or patent / polished when glossy."""
    cells = randint(gen, 16, 48)
    dye = choice(
        gen,
        (
            ((0.03, 0.09), (0.4, 0.8), (0.15, 0.55)),  # brown
            ((0.0, 1.0), (0.0, 0.2), (0.15, 0.25)),  # black (dyed leather, albedo ~0.03)
            ((0.07, 0.11), (0.35, 0.6), (0.5, 0.8)),  # tan
            ((-0.03, 0.02), (0.5, 0.85), (0.2, 0.5)),  # red / burgundy
            ((0.0, 1.0), (0.3, 0.8), (0.15, 0.6)),  # any dye
        ),
    )
    color = random_color(gen, *dye)
    base_r, f0 = _finish(gen, glossy, (0.45, 0.75))
    soft = uniform(gen, 0.15, 0.4)  # crease valley width, in cell widths
    amp = uniform(gen, 0.04, 0.1) / cells  # pebble height: slopes ~0.1-0.3 at any cell count
    wrinkle_amp = uniform(gen, 0.0005, 0.002)
    dx, dy = fbm(gen, size, 4, octaves=3, channels=2, device=device) * (0.35 / cells)
    x, y = _coords(gen, size, device)
    c = worley(gen, x + dx, y + dy, cells, jitter=0.9)
    wrinkles = spectral_noise(
        gen,
        size,
        f_lo=2,
        f_hi=16,
        exponent=1.0,
        anisotropy=uniform(gen, 1.5, 4.0),
        angle=uniform(gen, 0, math.pi),
        device=device,
    )
    pores_n = spectral_noise(gen, size, f_lo=64, f_hi=128, exponent=0.0, device=device)
    mottle = spectral_noise(gen, size, f_lo=1, f_hi=12, exponent=1.0, device=device)

    # Pebbled grain: each cell a rounded plateau, valleys (creases) between cells.
    pebble = smoothstep(0.0, soft, c.f2 - c.f1)[None]
    crease = 1 - pebble
    dome = (1 - c.f1.clamp(max=1.0) ** 2)[None]
    pores = (pores_n - 2.2).clamp(min=0.0)
    height = amp * pebble * (0.8 + 0.2 * dome) + wrinkle_amp * wrinkles - 1e-4 * pores
    diffuse = _fill(color, size, device) * (1 + 0.12 * mottle + 0.08 * dome) * (1 - 0.35 * crease) * (1 - 0.3 * pores)
    roughness = base_r * (1 + 0.08 * mottle) + 0.1 * crease + 0.1 * pores
    specular = _grey(f0 * (1 - 0.3 * crease), size, device)
    return _done(height, diffuse, roughness, specular)


# ---------------------------------------------------------------- paint / plastic
def paint(gen: torch.Generator, size: int, glossy: bool, device="cpu") -> Layers:
    """Painted or plastic surface with a pattern (plain, stripes at any rational angle,
    dots, checker, camouflage blobs), orange-peel texture and optional wear chips."""
    pattern = choice(gen, ("plain", "stripes", "dots", "checker", "blobs"))
    base = random_color(gen, (0.0, 1.0), (0.1, 0.9), (0.15, 0.95))
    ink = random_color(gen, (0.0, 1.0), (0.0, 0.9), (0.05, 0.95))
    third = random_color(gen, (0.0, 1.0), (0.1, 0.9), (0.1, 0.9))
    base_r, f0 = _finish(gen, glossy, (0.35, 0.9))
    # Matte ink on a satin / matte base; under a gloss coat the print is glossy too.
    ink_r = uniform(gen, 0.4, 0.9) if coin(gen, 0.3) and not glossy else base_r
    layer = uniform(gen, 2e-4, 6e-4)  # paint thickness of the pattern layer
    peel = lattice_noise(gen, size, randint(gen, 24, 64), device=device)
    x, y = _coords(gen, size, device)
    px = 1.0 / size  # one pixel in tile units: anti-aliasing width of pattern edges

    if pattern == "plain":
        mask = torch.zeros(size, size, device=device)
    elif pattern == "stripes":
        m, n, k = randint(gen, -4, 4), randint(gen, 1, 6), randint(gen, 1, 4)
        duty = uniform(gen, 0.2, 0.6)
        period = 1.0 / (k * math.hypot(m, n))  # stripe period in tile units
        d = _edge_distance(wrap(k * (m * x + n * y), 1.0)) * period
        mask = 1 - smoothstep(duty * period / 2 - px, duty * period / 2 + px, d)
    elif pattern == "dots":
        n = 2 * randint(gen, 2, 6)  # even: the half-offset of alternate rows wraps
        radius = uniform(gen, 0.15, 0.4) / n
        stagger = coin(gen, 0.5)
        v = y * n
        shift = (wrap(torch.floor(v), 2) * 0.5) if stagger else 0.0
        u = x * n + shift
        d = torch.hypot((u - torch.floor(u) - 0.5) / n, (v - torch.floor(v) - 0.5) / n)
        mask = 1 - smoothstep(radius - px, radius + px, d)
    elif pattern == "checker":
        n = randint(gen, 1, 6)
        c = torch.sin(2 * math.pi * n * x) * torch.sin(2 * math.pi * n * y)
        mask = smoothstep(-2 * math.pi * n * px, 2 * math.pi * n * px, c)
    else:  # blobs: camouflage in three colours
        f = fbm(gen, size, randint(gen, 2, 4), octaves=4, device=device)[0]
        g = fbm(gen, size, randint(gen, 2, 4), octaves=4, device=device)[0]
        mask = smoothstep(0.15, 0.25, f)
        # The second blob field splits the ink layer into two colours.
        split = smoothstep(-0.05, 0.05, g)[None]
        ink = _lerp(_fill(third, size, device), _fill(ink, size, device), split)
    mask = mask[None]
    wear = torch.zeros_like(mask)
    substrate_metal = False
    if coin(gen, 0.25):
        chips = fbm(gen, size, randint(gen, 3, 8), octaves=5, device=device)[0]
        wear = smoothstep(1.6, 1.75, chips)[None]
        substrate_metal = coin(gen, 0.5)

    ink_map = ink if ink.dim() == 3 else _fill(ink, size, device)
    diffuse = _lerp(_fill(base, size, device), ink_map, mask)
    roughness = _lerp(torch.full_like(mask, base_r), torch.full_like(mask, ink_r), mask) * (1 + 0.05 * peel)
    specular = _grey(torch.full_like(mask, f0), size, device)
    if substrate_metal:  # chipped to bare steel
        sub_d = torch.full((3, size, size), 0.02, device=device)
        sub_r, sub_s = 0.4, _fill(torch.tensor(METAL_F0["iron"]), size, device)
    else:  # chipped to grey primer
        sub_d = torch.full((3, size, size), 0.35, device=device)
        sub_r, sub_s = 0.85, _grey(0.04, size, device)
    diffuse = _lerp(diffuse, sub_d, wear)
    roughness = _lerp(roughness, torch.full_like(roughness, sub_r), wear)
    specular = _lerp(specular, sub_s, wear)
    height = 2e-5 * peel + layer * mask - 2 * layer * wear
    return _done(height, diffuse, roughness, specular)


# ---------------------------------------------------------------- terrazzo
def terrazzo(gen: torch.Generator, size: int, glossy: bool, device="cpu") -> Layers:
    """Terrazzo: angular stone chips of 2-5 colours at two scales in a cement matrix;
    polished (glossy) or honed."""
    dark = coin(gen, 0.2)
    matrix = random_color(gen, (0.0, 1.0), (0.0, 0.3), (0.1, 0.3) if dark else (0.5, 0.95))
    k = randint(gen, 2, 5)
    palette = torch.stack([random_color(gen, (0.0, 1.0), (0.0, 0.8), (0.08, 0.95)) for _ in range(k)])
    base_r, f0 = _finish(gen, glossy, (0.35, 0.65))
    x, y = _coords(gen, size, device)
    speckle = spectral_noise(gen, size, f_lo=32, f_hi=128, exponent=0.0, device=device)
    diffuse = _fill(matrix, size, device) * (1 + 0.08 * speckle)
    chip_h = torch.zeros(1, size, size, device=device)
    for cells in (randint(gen, 4, 10), randint(gen, 14, 32)):
        gap = uniform(gen, 0.15, 0.5)  # matrix between shards, in cell widths
        density = uniform(gen, 0.5, 0.95)
        present = (torch.rand(cells * cells, 1, generator=gen) < density).float()
        color_idx = torch.randint(k, (cells * cells,), generator=gen)
        shade = 1 + (torch.rand(cells * cells, 1, generator=gen) * 2 - 1) * 0.15
        table = torch.cat([palette[color_idx] * shade, present], dim=1)  # [cells^2, 4]
        dx, dy = fbm(gen, size, 6, octaves=3, channels=2, device=device) * (0.15 / cells)
        c = worley(gen, x + dx, y + dy, cells, jitter=0.9)
        # Shrunken Voronoi cells give the angular shard outline of crushed stone.
        per_cell = _lookup(table, c.cell)
        chip = _edge(gap / cells, (c.f2 - c.f1) / cells, size) * per_cell[3:]  # in tile units
        chip_col = per_cell[:3]
        diffuse = _lerp(diffuse, chip_col * (1 + 0.05 * speckle), chip)
        chip_h = torch.maximum(chip_h, chip)
    relief = 3e-5 if glossy else 2e-4
    height = relief * (chip_h + 0.3 * speckle)
    roughness = base_r * (1 + 0.1 * speckle) + (0.0 if glossy else 0.1) * (1 - chip_h)
    specular = _grey(f0, size, device)
    return _done(height, diffuse, roughness, specular)


#: Family name -> function, in the canonical order (``materials.procedural.FAMILIES``);
#: read-only so no caller can re-register a family behind another's back.
FAMILY_FUNCTIONS: Mapping[str, Family] = MappingProxyType(
    {
        "tiles": tiles,
        "bricks": bricks,
        "wood": wood,
        "stone": stone,
        "fabric": fabric,
        "metal": metal,
        "leather": leather,
        "paint": paint,
        "terrazzo": terrazzo,
    }
)
