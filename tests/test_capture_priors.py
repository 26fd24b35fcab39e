"""The refinement's flash-independence prior (``matcap.capture.priors.FlashRings``,
``flash_independence``): against a dense float64 reference, its invariances, its bounds,
its mask, the flash point's pixel, and its effect on a refinement."""

from __future__ import annotations

import math

import pytest
import torch

import kernels
from matcap.capture import CaptureConfig, refine_full_resolution
from matcap.capture.priors import (
    RADIAL_RINGS,
    FlashRings,
    flash_independence,
    plane_to_grid,
    radial_energy,
)
from materials.types import Material

#: float64 forward and gradient against the dense reference: the same sums in another
#: order, so agreement to ~1e-15 relative; 1e-10 leaves room for the sums' length.
REFERENCE_TOL = 1e-10
#: Energy of i.i.d. noise over its variance on a 128 px grid: each ring's mean of n
#: pixels has variance var / n, so the expected ratio is (rings used) / (pixels), about
#: 100 / 16384 = 0.006; 0.05 is 8x that and far below a disc's ~0.9.
NOISE_RATIO_TOL = 0.05
#: Block means against per-pixel ring weights for a disc with texture: a ring is 32 px
#: wide at 1024 px and a block 4 px, so a pixel's tent weight moves by at most ~1/16 of a
#: ring; measured 2e-4 relative. 2e-3 is 10x that and fails for rings centred 8 px (two
#: blocks) off (5e-3 measured; 16 px: 1.9e-2).
POOLED_ENERGY_TOL = 2e-3
#: A prior weight that dominates the photo's log-L1 in ``test_the_prior_holds_back...``:
#: there the disc's log-roughness profile costs ~0.08 at its full size, the photo's loss
#: it explains ~0.01.
PRIOR_WEIGHT = 10.0


def _dense_energy(x: torch.Tensor, center, mask, rings: int, centered: bool, factor: int = 1) -> torch.Tensor:
    """The prior written out pixel by pixel: a [n_rings, S * S] matrix of each pixel's
    linear (tent) weight in each ring, taken at the centre of its ``factor x factor``
    block, ring means, their weighted variance."""
    side = x.shape[-1]
    n_rings = int(math.hypot(side, side) * rings / side) + 4
    weights = torch.zeros(n_rings, side * side, dtype=torch.float64)
    for i in range(side):
        for j in range(side):
            if mask is not None and not bool(mask[i, j]):
                continue
            bi, bj = (i // factor) * factor + (factor - 1) / 2, (j // factor) * factor + (factor - 1) / 2
            t = math.hypot(bi - center[0], bj - center[1]) * rings / side
            for b in range(n_rings):
                weights[b, i * side + j] = max(0.0, 1.0 - abs(t - b))
    flat = x[0].flatten(1)  # [C, S * S]
    counts = weights.sum(1)
    used = counts > 0
    means = (flat @ weights.T)[:, used] / counts[used]
    total = counts.sum()
    g = (flat @ weights.T).sum(1, keepdim=True) / total if centered else 0.0
    return ((counts[used] * (means - g).square()).sum(1) / total).mean()


@pytest.mark.parametrize("centered", [True, False])
# 20 // 3 = 6 does not divide 20: blocks of 5.
@pytest.mark.parametrize(("side", "grid", "factor"), [(24, 24, 1), (24, 6, 4), (20, 3, 5)])
def test_flash_rings_match_the_dense_reference_forward_and_gradient(centered, side, grid, factor):
    torch.manual_seed(0)
    rings = 8
    center = (9.3, 14.6)  # off the grid's centre and between pixels
    mask = torch.ones(side, side, dtype=torch.bool)
    mask[:, 18:] = False  # padding, across a block at factors 4 and 5
    x = torch.rand(1, 3, side, side, dtype=torch.float64, requires_grad=True)
    flash_rings = FlashRings(side, center, mask, rings, torch.float64, grid=grid)
    assert flash_rings.factor == factor
    fast = flash_rings.energy(x, centered)
    ref = _dense_energy(x, center, mask, rings, centered, factor)
    assert float(fast.detach()) == pytest.approx(float(ref.detach()), rel=REFERENCE_TOL)
    (g_fast,) = torch.autograd.grad(fast, x)
    (g_ref,) = torch.autograd.grad(_dense_energy(x, center, mask, rings, centered, factor), x)
    torch.testing.assert_close(g_fast, g_ref, rtol=REFERENCE_TOL, atol=REFERENCE_TOL * float(g_ref.abs().max()))


@pytest.mark.parametrize("grid", [10, 5])
def test_flash_rings_gradcheck_float64(grid):
    torch.manual_seed(1)
    mask = torch.ones(10, 10, dtype=torch.bool)
    mask[7:] = False
    rings = FlashRings(10, (4.2, 5.7), mask, 5, torch.float64, grid=grid)
    x = torch.rand(1, 2, 10, 10, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda t: rings.energy(t), (x,))


def test_block_means_keep_the_full_resolution_profile():
    # The default grid at 1024 px (blocks of 4 px) against every pixel its own block:
    # a dark disc under the flash with texture on top costs nearly the same.
    side = 1024
    gen = torch.Generator().manual_seed(2)
    coord = torch.arange(side, dtype=torch.float64)
    r = torch.hypot(coord[:, None] - 400.0, coord[None, :] - 600.0)
    x = 0.5 - 0.3 * torch.exp(-((r / 120.0) ** 2)) + 0.05 * torch.rand(side, side, generator=gen, dtype=torch.float64)
    x = x[None, None]
    pooled = FlashRings(side, (400.0, 600.0), None, RADIAL_RINGS, torch.float64)
    full = FlashRings(side, (400.0, 600.0), None, RADIAL_RINGS, torch.float64, grid=side)
    assert (pooled.factor, full.factor) == (4, 1)
    assert float(pooled.energy(x)) == pytest.approx(float(full.energy(x)), rel=POOLED_ENERGY_TOL)


def test_energy_is_zero_for_what_does_not_depend_on_the_distance():
    side = 64
    center = (31.5, 31.5)
    # A constant, and a gradient across the sample: odd about the flash point, so every
    # ring averages the global mean exactly.
    assert float(radial_energy(torch.full((1, 1, side, side), 0.3, dtype=torch.float64), center)) < 1e-28
    ramp = torch.linspace(-1, 1, side, dtype=torch.float64)
    assert float(radial_energy((ramp[None, :] + 0.5 * ramp[:, None]).expand(1, 1, side, side), center)) < 1e-28
    # Texture (i.i.d. noise): only the sampling noise of each ring's mean is left.
    torch.manual_seed(2)
    noise = torch.rand(1, 1, 128, 128, dtype=torch.float64)
    ratio = float(radial_energy(noise, (63.5, 63.5))) / float(noise.var(unbiased=False))
    assert 0 < ratio < NOISE_RATIO_TOL


def test_energy_lies_between_zero_and_the_variance():
    # Cauchy-Schwarz on each ring's weighted mean: the profile cannot hold more variance
    # than the map; a pure disc holds nearly all of it.
    torch.manual_seed(3)
    side = 48
    rows, cols = torch.meshgrid(torch.arange(side), torch.arange(side), indexing="ij")
    r = torch.hypot(rows - 20.0, cols - 27.0).double()
    rings = FlashRings(side, (20.0, 27.0), None, 16, torch.float64)
    for _ in range(5):
        x = (torch.rand(1) * torch.exp(-r / 10) + 0.3 * torch.rand(side, side, dtype=torch.float64))[None, None]
        e = float(rings.energy(x))
        assert 0 <= e <= float(x.var(unbiased=False)) * (1 + 1e-12)
    disc = (r < 8).double()[None, None]
    assert float(rings.energy(disc)) > 0.8 * float(disc.var(unbiased=False))


def test_masked_pixels_neither_pay_nor_get_a_gradient():
    torch.manual_seed(4)
    side = 32
    mask = torch.ones(side, side, dtype=torch.bool)
    mask[24:] = False
    rings = FlashRings(side, (12.0, 15.5), mask, 16, torch.float64)
    x = torch.rand(1, 3, side, side, dtype=torch.float64)
    y = x.clone()
    y[..., 24:, :] = 100.0  # a bright padding
    assert float(rings.energy(x)) == pytest.approx(float(rings.energy(y)), rel=1e-12)
    x.requires_grad_(True)
    rings.energy(x).backward()
    assert float(x.grad[..., 24:, :].abs().max()) == 0.0 and float(x.grad[..., :24, :].abs().max()) > 0


def test_gradient_depends_on_the_distance_only():
    # dE/dx_p = sum_b w_pb 2 (m_b - g) / N: the same for pixels at the same distance, so
    # the prior moves ring means and never the texture within a ring. With the flash at
    # the grid's centre the mirror images of a pixel are at its distance.
    torch.manual_seed(5)
    side = 40
    x = torch.rand(1, 1, side, side, dtype=torch.float64, requires_grad=True)
    radial_energy(x, (19.5, 19.5), rings=10).backward()
    g = x.grad[0, 0]
    for flipped in (g.flip(0), g.flip(1), g.T):
        torch.testing.assert_close(flipped, g, rtol=1e-9, atol=1e-18)


def test_radial_slope_sees_domes_not_swirls():
    side = 32
    rings = FlashRings(side, (15.5, 15.5), None, 8, torch.float64)
    out = rings.outward.double()  # [2, S, S], unit
    dome = (0.3 * out)[None]
    swirl = torch.stack([-out[1], out[0]])[None] * 0.3  # perpendicular: round the flash
    # Uncentered: every ring of a dome averages 0.3, so the energy is 0.3^2.
    assert float(rings.energy(rings.radial_slope(dome), centered=False)) == pytest.approx(0.09, rel=1e-9)
    assert float(rings.energy(rings.radial_slope(swirl), centered=False)) < 1e-28


def test_plane_to_grid_finds_the_highlight_of_a_flash_off_centre():
    # A glossy flat plane under a co-located flash off the centre: its brightest pixel is
    # the one under the flash, which plane_to_grid names.
    side = 64
    flash = torch.tensor([1.1, -0.6, 3.0])
    maps = (
        torch.full((1, 3, side, side), 0.05),
        torch.tensor([0.0, 0.0, 1.0]).view(1, 3, 1, 1).expand(1, 3, side, side),
        torch.full((1, 1, side, side), 0.15),
        torch.full((1, 3, side, side), 0.5),
    )
    image = kernels.render(*maps, flash[None, None], flash)[0, 0].mean(0)
    peak = divmod(int(image.argmax()), side)
    row, col = plane_to_grid(float(flash[0]), float(flash[1]), side, kernels.get_preset("dgrsise").plane_size)
    assert abs(peak[0] - row) <= 0.5 and abs(peak[1] - col) <= 0.5


def test_flash_independence_of_a_flat_material_is_zero_and_of_a_disc_is_not():
    side = 32
    rings = FlashRings(side, (15.5, 15.5), None, RADIAL_RINGS)
    maps = {
        "diffuse": torch.full((1, 3, side, side), 0.4),
        "normal": torch.zeros(1, 2, side, side),
        "roughness": torch.full((1, 1, side, side), 0.5),
        "specular": torch.full((1, 3, side, side), 0.04),
    }
    assert float(flash_independence(rings, maps)) < 1e-10
    disc = maps["roughness"].clone()
    disc[..., 12:20, 12:20] = 0.9
    assert float(flash_independence(rings, {**maps, "roughness": disc})) > 0.01


def _flat(side: int, roughness: torch.Tensor | float = 0.4) -> Material:
    r = roughness if isinstance(roughness, torch.Tensor) else torch.full((1, 1, side, side), roughness)
    return Material(
        torch.full((1, 3, side, side), 0.3),
        torch.tensor([0.0, 0.0, 1.0]).view(1, 3, 1, 1).expand(1, 3, side, side).clone(),
        r,
        torch.full((1, 3, side, side), 0.04),
    )


def test_the_prior_holds_back_a_disc_under_the_flash():
    # A photo whose material has a rough disc under the flash (what a single flash view
    # of a uniform material can be fitted with, on real photos): refined from uniform
    # maps, the disc grows toward the photo's without the prior and far less with it:
    # the prior costs real radial structure too, which is why its weight is measured.
    side = 64
    camera = torch.tensor([0.0, 0.0, 4.83])
    rows, cols = torch.meshgrid(torch.arange(side), torch.arange(side), indexing="ij")
    disc = torch.hypot(rows - 31.5, cols - 31.5) < 10
    truth = _flat(side, torch.where(disc, 0.7, 0.4).float()[None, None])
    photo = kernels.render(*truth.map_tensors(), camera[None, None], camera)[0, 0]
    mask = torch.ones(side, side, dtype=torch.bool)
    empty = torch.zeros(0, 3, 64, 64)

    def grown_disc(radial: float) -> float:
        result = refine_full_resolution(
            _flat(side), photo, mask, empty, mask, camera[None], camera, radial=radial, steps=60
        )
        r = result.material.roughness[0, 0]
        return float(r[disc].mean() - r[~disc].mean())

    free = grown_disc(0.0)
    assert free > 0.02  # the photo does call for the disc (0.03 after 60 steps at the default rate)
    assert abs(grown_disc(PRIOR_WEIGHT)) < 0.5 * free


def test_radial_settings_are_checked():
    side = 16
    m = _flat(side)
    args = (m, torch.zeros(3, side, side), torch.ones(side, side, dtype=torch.bool), torch.zeros(0, 3, 16, 16))
    rest = (torch.ones(16, 16, dtype=torch.bool), torch.tensor([[0.0, 0.0, 4.0]]), torch.tensor([0.0, 0.0, 4.0]))
    with pytest.raises(ValueError, match="radial must be a finite number >= 0"):
        refine_full_resolution(*args, *rest, radial=-1.0, steps=1)
    with pytest.raises(ValueError, match="radial_maps must be names of"):
        refine_full_resolution(*args, *rest, radial=1.0, radial_maps=("gloss",), steps=1)
    with pytest.raises(ValueError, match="radial must be a finite number >= 0"):
        CaptureConfig(radial=float("inf"))
    with pytest.raises(ValueError, match="radial_maps must be distinct names"):
        CaptureConfig(radial_maps=("roughness", "roughness"))
    with pytest.raises(ValueError, match="x must be"):
        FlashRings(side, (0.0, 0.0)).energy(torch.zeros(1, 1, 8, 8))
    with pytest.raises(ValueError, match="mask must be"):
        FlashRings(side, (0.0, 0.0), torch.ones(8, 8, dtype=torch.bool))
