"""Fixtures for the kernel tests: the devices and dtypes to run on, random SVBRDF maps and
light/camera positions, and comparison assertions.

The suite runs with ``--import-mode=importlib``, so shared helpers reach the test modules
as fixtures (factories and assertion functions), not as imports.

Random data stays away from the BRDF's kinks so that gradients are well defined: normals
are tilted at most ~42 degrees, roughness is in [0.15, 1] (above every preset's floor of
0.0993), lights and cameras sit well above the plane.
"""

from __future__ import annotations

import math

import pytest
import torch

#: Devices the forward/VJP tests run on: the same tests run on CUDA when it is present.
DEVICES = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])
DTYPES = [torch.float32, torch.float64]
#: Largest tilt of the random normals: |n_xy| <= 0.9 n_z, i.e. atan(0.9) ~ 42 degrees.
MAX_NORMAL_SLOPE = 0.9
#: Roughness range of the random maps: above the 0.0993 floor, so the clamp is never hit.
ROUGHNESS_RANGE = (0.15, 1.0)
#: Cosine-similarity floor between kernel and reference gradients ("not silently zero",
#: gsplat's habit): any real disagreement shows up far below it.
GRAD_COSINE_MIN = 0.999


def _random_maps(
    batch: int,
    height: int,
    width: int,
    *,
    dtype: torch.dtype = torch.float32,
    device: str = "cpu",
    seed: int = 0,
    requires_grad: bool = False,
) -> list[torch.Tensor]:
    """(diffuse, normal, roughness, specular) with the layout of ``kernels.render``:
    diffuse/specular U[0, 1] linear RGB, unit normals tilted <= ~42 degrees, roughness
    U[0.15, 1]."""
    g = torch.Generator().manual_seed(seed)
    shape = (batch, 3, height, width)
    diffuse = torch.rand(shape, generator=g, dtype=torch.float64)
    slope = (torch.rand((batch, 2, height, width), generator=g, dtype=torch.float64) * 2 - 1) * (
        MAX_NORMAL_SLOPE / math.sqrt(2)
    )
    normal = torch.cat([slope, torch.ones(batch, 1, height, width, dtype=torch.float64)], 1)
    normal = normal / normal.norm(dim=1, keepdim=True)
    lo, hi = ROUGHNESS_RANGE
    roughness = lo + (hi - lo) * torch.rand((batch, 1, height, width), generator=g, dtype=torch.float64)
    specular = torch.rand(shape, generator=g, dtype=torch.float64)
    maps = [t.to(dtype=dtype, device=device) for t in (diffuse, normal, roughness, specular)]
    if requires_grad:
        maps = [t.requires_grad_() for t in maps]
    return maps


def _random_positions(
    shape: tuple[int, ...],
    *,
    plane_size: float = 4.0,
    dtype: torch.dtype = torch.float32,
    device: str = "cpu",
    seed: int = 1,
    requires_grad: bool = False,
) -> torch.Tensor:
    """Positions ``[*shape, 3]`` above a plane of side ``plane_size``: x, y within the
    plane's half-width, z in [1, 1.5] plane sizes (SPEC section 3's U[4, 8] range, scaled)."""
    g = torch.Generator().manual_seed(seed)
    half = plane_size / 2
    xy = (torch.rand((*shape, 2), generator=g, dtype=torch.float64) * 2 - 1) * half
    z = plane_size * (1.0 + 0.5 * torch.rand((*shape, 1), generator=g, dtype=torch.float64))
    pos = torch.cat([xy, z], -1).to(dtype=dtype, device=device)
    return pos.requires_grad_() if requires_grad else pos


def _assert_close_to_max(actual: torch.Tensor, expected: torch.Tensor, rtol: float, what: str = "") -> None:
    """max |actual - expected| <= rtol * max |expected| (an error scaled by the tensor's
    magnitude, robust to entries that are nearly zero)."""
    assert actual.shape == expected.shape, f"{what}: shape {tuple(actual.shape)} != {tuple(expected.shape)}"
    assert actual.dtype == expected.dtype, f"{what}: dtype {actual.dtype} != {expected.dtype}"
    actual, expected = actual.detach(), expected.detach()
    scale = float(expected.abs().max())
    err = float((actual - expected).abs().max())
    assert err <= rtol * max(scale, torch.finfo(expected.dtype).tiny), (
        f"{what}: max abs error {err:.3e} > {rtol:.1e} * max |expected| ({scale:.3e})"
    )


def _assert_grad_alive(grad: torch.Tensor, ref: torch.Tensor, what: str = "") -> None:
    """The gradient is not silently zero and points where the reference's does."""
    g, r = grad.detach().double().flatten(), ref.detach().double().flatten()
    assert float(g.norm()) > 0, f"{what}: gradient is identically zero"
    assert float(r.norm()) > 0, f"{what}: reference gradient is identically zero (bad test data)"
    cos = float(g @ r / (g.norm() * r.norm()))
    assert cos > GRAD_COSINE_MIN, f"{what}: cosine with the reference gradient {cos:.6f} <= {GRAD_COSINE_MIN}"


@pytest.fixture(autouse=True)
def _two_kernel_threads(monkeypatch):
    """Pin the CPU thread split to two threads (this machine's budget), so B=1 always
    takes the row-split path and B>=2 the batch split, whatever the host's core count.
    Tests that study the thread count override it."""
    monkeypatch.setenv("DGRSISE_KERNEL_THREADS", "2")


@pytest.fixture(params=DEVICES)
def device(request) -> str:
    """Every device present: 'cpu', and 'cuda' when torch sees a GPU."""
    return request.param


@pytest.fixture(params=DTYPES, ids=["float32", "float64"])
def dtype(request) -> torch.dtype:
    """float32 and float64 (the kernels are built for both)."""
    return request.param


@pytest.fixture
def make_maps():
    """Factory: ``make_maps(B, H, W, dtype=, device=, seed=, requires_grad=)`` ->
    [diffuse, normal, roughness, specular]."""
    return _random_maps


@pytest.fixture
def make_positions():
    """Factory: ``make_positions(shape, plane_size=, dtype=, device=, seed=, requires_grad=)``
    -> ``[*shape, 3]`` positions above the plane."""
    return _random_positions


@pytest.fixture
def assert_close_to_max():
    """``assert_close_to_max(actual, expected, rtol, what="")``: max error <= rtol * max |expected|."""
    return _assert_close_to_max


@pytest.fixture
def assert_grad_alive():
    """``assert_grad_alive(grad, ref, what="")``: non-zero gradient, cosine with ref > GRAD_COSINE_MIN."""
    return _assert_grad_alive
