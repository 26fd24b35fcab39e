"""Tone map and sRGB transfer functions (SPEC section 2): explicit, separate steps with
known values, inverses on their range, dtype/device preserved.
"""

from __future__ import annotations

import pytest
import torch

import kernels
from kernels.tonemap import TONEMAP_FLOOR

#: float64 round trips through x^(1/2.2) and the sRGB power segment: a few ulps.
ROUNDTRIP_ATOL_F64 = 1e-12
#: float32 sRGB round trips of x in [0, 1], in units of u = 2^-24: encode's pow (<= 2u),
#: scale (u) and the - 0.055 (u, magnified 2.4x since 1.055 x^(1/2.4) / y <= 2.4 above the
#: cutoff) leave y within ~6.4u relative; decode's + 0.055, / 1.055 and pow (2u) add ~4u,
#: and the power 2.4 multiplies the ~8.4u of its argument: <= 2.4 * 8.4u + 2u ~ 22u
#: relative, on values <= 1. Measured 4u (AMD EPYC). 32u ~ 1.9e-6.
ROUNDTRIP_ATOL_F32 = 32 * 2.0**-24
#: Published sRGB values (IEC 61966-2-1) are quoted to 4 decimals.
SRGB_TABLE_ATOL = 1e-4


def test_tonemap_is_clamp_then_gamma():
    x = torch.tensor([-1.0, 0.0, 0.25, 1.0, 3.0], dtype=torch.float64)
    black = TONEMAP_FLOOR ** (1 / 2.2)  # the lower clamp keeps the gradient finite
    expected = torch.tensor([black, black, 0.25 ** (1 / 2.2), 1.0, 1.0], dtype=torch.float64)
    torch.testing.assert_close(kernels.tonemap(x), expected, rtol=0, atol=ROUNDTRIP_ATOL_F64)
    assert black < 0.5 / 255  # black still quantises to 0 in 8 bits


def test_tonemap_gradient_is_finite_on_black():
    x = torch.tensor([0.0, 1e-12, 0.5], dtype=torch.float64, requires_grad=True)
    (g,) = torch.autograd.grad(kernels.tonemap(x).sum(), [x])
    assert bool(torch.isfinite(g).all())


def test_inverse_tonemap_round_trip():
    y = torch.linspace(TONEMAP_FLOOR ** (1 / 2.2), 1, 101, dtype=torch.float64)
    torch.testing.assert_close(kernels.tonemap(kernels.inverse_tonemap(y)), y, rtol=0, atol=ROUNDTRIP_ATOL_F64)


@pytest.mark.parametrize(
    "linear,encoded", [(0.0, 0.0), (0.0031308, 0.0404500), (0.18, 0.4613561), (0.5, 0.7353570), (1.0, 1.0)]
)
def test_srgb_known_values(linear, encoded):
    got = float(kernels.srgb_encode(torch.tensor(linear, dtype=torch.float64)))
    assert abs(got - encoded) <= SRGB_TABLE_ATOL
    back = float(kernels.srgb_decode(torch.tensor(encoded, dtype=torch.float64)))
    assert abs(back - linear) <= SRGB_TABLE_ATOL


def test_srgb_round_trip_and_dtype(dtype):
    x = torch.linspace(0, 1, 257, dtype=dtype)
    y = kernels.srgb_encode(x)
    assert y.dtype == dtype and y.shape == x.shape
    atol = ROUNDTRIP_ATOL_F64 if dtype == torch.float64 else ROUNDTRIP_ATOL_F32
    torch.testing.assert_close(kernels.srgb_decode(y), x, rtol=0, atol=atol)
    assert bool((y[1:] >= y[:-1]).all())  # monotone across the piecewise join
