"""``materials.tiling``: the seam measure and the offset-and-blend tileable variant."""

from __future__ import annotations

import pytest
import torch

from materials.procedural import generate
from materials.tiling import DEFAULT_BORDER, make_tileable, seam_error
from materials.types import Material

#: Unit normals after renormalising, float32.
UNIT_TOL = 1e-5
#: A seam no more visible than an ordinary pixel step: the wrap difference at most twice
#: the interior-neighbour mean (a seam-free random field scores about 1).
TILEABLE_SEAM = 2.0


def _window(size: int = 96, seed: int = 3) -> Material:
    """A window of a larger material: its maps do not wrap."""
    full = generate(seed, size=2 * size)
    return full.crop(size // 3, size // 5, size, size)


def test_a_ramp_has_a_seam_and_noise_has_none():
    x = torch.linspace(0, 1, 64).expand(1, 64, 64)
    assert seam_error(x) > 30  # a jump of 1 against steps of 1/63
    noise = torch.rand(1, 64, 64, generator=torch.Generator().manual_seed(0))
    assert seam_error(noise) == pytest.approx(1.0, abs=0.1)


def test_make_tileable_removes_the_seam_of_a_window():
    m = _window()
    before = {k: seam_error(v) for k, v in m.maps().items()}
    t = make_tileable(m)
    after = {k: seam_error(v) for k, v in t.maps().items()}
    assert t.shape == m.shape
    assert max(before.values()) > TILEABLE_SEAM  # the window did have a seam
    assert all(v <= TILEABLE_SEAM for v in after.values()), after
    torch.testing.assert_close(t.normal.norm(dim=0), torch.ones(m.shape), atol=UNIT_TOL, rtol=0)
    t.validate()


def test_interior_is_untouched_and_a_constant_stays_constant():
    m = _window(64)
    t = make_tileable(m)
    lo, hi = int(DEFAULT_BORDER * 64) + 1, 64 - int(DEFAULT_BORDER * 64) - 1
    torch.testing.assert_close(t.diffuse[:, lo:hi, lo:hi], m.diffuse[:, lo:hi, lo:hi], atol=0, rtol=0)
    flat = Material(
        diffuse=torch.full((3, 32, 32), 0.3),
        normal=torch.tensor([0.0, 0.0, 1.0])[:, None, None].expand(3, 32, 32).clone(),
        roughness=torch.full((1, 32, 32), 0.5),
        specular=torch.full((3, 32, 32), 0.04),
    )
    for a, b in zip(make_tileable(flat).map_tensors(), flat.map_tensors()):
        torch.testing.assert_close(a, b, atol=1e-6, rtol=0)
    with pytest.raises(ValueError, match="border"):
        make_tileable(m, border=0.7)
