"""Procedural SVBRDF generator: diverse, deterministic-by-seed, seamlessly tileable maps.

The product cannot download MatSynth or the INRIA data (SPEC section 6), so its tests,
demo and bundled models train on these materials. ``generate(seed)`` returns one
``Material`` (maps ``[C, H, W]``, float32, linear; SPEC section 2):

- diffuse   ``[3, H, W]`` linear RGB albedo, dielectrics in [0.02, 0.9], metals <= 0.03;
- normal    ``[3, H, W]`` unit tangent-space normals, OpenGL (+x right, +y up), z > 0;
- roughness ``[1, H, W]`` in [0.05, 1];
- specular  ``[3, H, W]`` linear RGB F0 (0.02-0.08 dielectric, 0.25-0.5 glossy coat,
  0.5-1 coloured metal).

About ``GLOSSY_PROBABILITY`` (40%) of seeds get a strongly specular finish (roughness
< 0.3 and F0 > 0.2 or metal), the case the method exists for.

Cost: about 20 ms of CPU time per 256 x 256 material in one thread (measured on the
project's 2-core CPU while it was shared with other jobs; ``benchmarks/bench_synth.py``).
The work is many small tensor ops, which gain little from intra-op threads: on a busy
machine ``torch.set_num_threads(1)`` is much faster than two threads waiting on each other.

Example::

    >>> from materials.procedural import generate, family_of
    >>> m = generate(7, size=64).validate()
    >>> m.diffuse.shape, family_of(7)
    (torch.Size([3, 64, 64]), 'paint')

Design (dependencies point one way, nothing here imports the rest of the project but
``materials.types``):

- ``noise``: tileable primitives on the unit torus (lattice / spectral / cellular noise,
  warps) drawing from an explicit ``torch.Generator``.
- ``color``: HSV palettes -> linear RGB. ``height``: height -> normals (wrap-around).
- ``families``: one function per family, returning height, diffuse, roughness, specular.
- this module: seeding, family choice, random orientation (dihedral flips), normals,
  argument checks.
"""

from __future__ import annotations

import operator
import zlib

import torch

from materials.procedural.families import FAMILY_FUNCTIONS, Layers
from materials.procedural.height import height_to_normal
from materials.procedural.noise import coin
from materials.types import Material

__all__ = ["generate", "generate_batch", "FAMILIES", "family_of", "glossy_of", "GLOSSY_PROBABILITY", "MIN_SIZE"]

#: Family names; ``family_of(seed)`` cycles through them in this order.
FAMILIES: tuple[str, ...] = tuple(FAMILY_FUNCTIONS)
#: Probability that a seed gets the strongly specular (glossy) finish. Above the 1/3
#: share the brief asks for, so that share holds with margin on small seed ranges.
GLOSSY_PROBABILITY = 0.4
#: Smallest map side: below 8 px the tile, brick and weave structures are meaningless.
MIN_SIZE = 8

_MASK64 = (1 << 64) - 1
#: Fractional part of the golden ratio: the most evenly spread additive recurrence.
_GOLDEN = 0.6180339887498949


def _mix(seed: int, stream: str) -> int:
    """A 63-bit seed for one named random stream of ``seed`` (splitmix64 finaliser).

    Streams keep the family choice, the glossy flag and each family's draws independent;
    ``zlib.crc32`` (unlike ``hash``) is the same in every process.
    """
    z = (seed * 0x9E3779B97F4A7C15 + zlib.crc32(stream.encode())) & _MASK64
    z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & _MASK64
    z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & _MASK64
    return (z ^ (z >> 31)) >> 1


def _check_seed(seed: int) -> int:
    if isinstance(seed, bool):
        raise TypeError("seed must be an int, got bool")
    try:
        seed = operator.index(seed)
    except TypeError:
        raise TypeError(f"seed must be an int, got {type(seed).__name__}") from None
    if seed < 0:
        raise ValueError(f"seed must be non-negative, got {seed}")
    return seed


def family_of(seed: int) -> str:
    """The family ``generate(seed)`` uses: ``FAMILIES[seed % len(FAMILIES)]``, so any run
    of consecutive seeds covers the families evenly."""
    return FAMILIES[_check_seed(seed) % len(FAMILIES)]


def glossy_of(seed: int) -> bool:
    """Whether ``generate(seed)`` gets the strongly specular finish.

    The k-th seed of a family (k = seed // len(FAMILIES)) is glossy when the golden-ratio
    sequence frac(k phi + offset) < ``GLOSSY_PROBABILITY``: a low-discrepancy draw, so every
    family gets its share of glossy seeds even in short seed ranges (independent coin
    flips gave one family 18 glossy seeds of 23 in 0..199). The per-family offset
    decorrelates the families.
    """
    k, fam = divmod(_check_seed(seed), len(FAMILIES))
    offset = _mix(fam, "glossy") / float(1 << 63)
    return (k * _GOLDEN + offset) % 1.0 < GLOSSY_PROBABILITY


def _place(gen: torch.Generator, layers: Layers) -> Layers:
    """Random dihedral orientation (transpose, flips), shared by all maps.

    The families lay out tiles, bricks and planks along the axes; the 8 symmetries of
    the square add orientation variety and are exact on a periodic map. (The families
    already put the tile seam at a random pattern phase.) Applied before the normals
    are computed, so the normals stay consistent with the moved height.
    """
    transpose = coin(gen, 0.5)
    flips = [d for d, flip in ((-2, coin(gen, 0.5)), (-1, coin(gen, 0.5))) if flip]
    if not transpose and not flips:
        return layers
    # One stacked [8, N, N] tensor: a single transpose / flip for all maps.
    t = torch.cat(list(layers), dim=0)
    if transpose:
        t = t.transpose(-1, -2)
    if flips:
        t = t.flip(flips)
    return Layers(*torch.split(t.contiguous(), [1, 3, 1, 3], dim=0))


def generate(
    seed: int,
    size: int = 256,
    family: str | None = None,
    *,
    glossy: bool | None = None,
    device: torch.device | str = "cpu",
) -> Material:
    """One procedural material, deterministic in (seed, size, family, glossy).

    Args:
        seed: non-negative int. Picks the family (when ``family`` is None), the glossy
            flag (when ``glossy`` is None) and every parameter of the material.
        size: side of the square maps in pixels, >= ``MIN_SIZE``; any value (e.g. 100,
            288). The same seed gives the same material at every size, sampled more or
            less finely (all random draws are independent of ``size``).
        family: one of ``FAMILIES``; None: ``family_of(seed)``.
        glossy: force the strongly specular finish on or off; None: ``glossy_of(seed)``.
        device: where the maps are computed and returned. Random numbers are drawn on
            the CPU, so every device gives the same material (up to float rounding).

    Returns:
        ``Material`` with unbatched maps ``[C, size, size]``, float32, linear values
        (ranges in the module docstring), tileable in both directions.

    Raises:
        ValueError: negative seed, size below ``MIN_SIZE``, unknown family.
    """
    seed = _check_seed(seed)
    if isinstance(size, bool) or not isinstance(size, int) or size < MIN_SIZE:
        raise ValueError(f"size must be an int >= {MIN_SIZE}, got {size!r}")
    if family is None:
        family = family_of(seed)
    elif family not in FAMILY_FUNCTIONS:
        raise ValueError(f"unknown family {family!r}; known families: {', '.join(FAMILIES)}")
    glossy = glossy_of(seed) if glossy is None else bool(glossy)

    gen = torch.Generator(device="cpu").manual_seed(_mix(seed, family))
    layers = FAMILY_FUNCTIONS[family](gen, size, glossy, device)
    layers = _place(gen, layers)
    normal = height_to_normal(layers.height)
    return Material(
        diffuse=layers.diffuse.float(),
        normal=normal.float(),
        roughness=layers.roughness.float(),
        specular=layers.specular.float(),
    )


def generate_batch(
    seeds: list[int],
    size: int = 256,
    family: str | None = None,
    *,
    glossy: bool | None = None,
    device: torch.device | str = "cpu",
) -> Material:
    """``generate`` for each seed, stacked: maps ``[B, C, size, size]``; element b is
    bit-identical to ``generate(seeds[b], size, family, glossy=glossy, device=device)``."""
    seeds = list(seeds)
    if not seeds:
        raise ValueError("generate_batch needs at least one seed")
    return Material.stack([generate(s, size, family, glossy=glossy, device=device) for s in seeds])
