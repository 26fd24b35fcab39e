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

import kernels
from kernels import reference
from kernels.presets import get_preset
from kernels.reference import UNIT_ROUNDOFF, render_rtol

#: Devices the forward/VJP tests run on: the same tests run on CUDA when it is present.
DEVICES = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])
DTYPES = [torch.float32, torch.float64]
#: Largest tilt of the random normals: |n_xy| <= 0.9 n_z, i.e. atan(0.9) ~ 42 degrees.
MAX_NORMAL_SLOPE = 0.9
#: Roughness range of the random maps: above the 0.0993 floor, so the clamp is never hit.
ROUGHNESS_RANGE = (0.15, 1.0)
#: VJP error model, relative to the largest gradient entry: ``VJP_ERR_SCALE`` times the
#: forward's ``render_rtol`` (a derivative of D = alpha^2 / (pi d^2) carries d^3, 1.5x the
#: forward's relative sensitivity to d, plus the cotangent products), plus n^1.5 u for a
#: float32 sum of n terms: recursive summation errs by <= (n - 1) u sum |t_i|, and with
#: random-sign cotangents sum |t_i| ~ sqrt(n) |sum t_i|.
VJP_ERR_SCALE = 2.0
#: Kernel and twin in the same dtype are each within the bound of the exact value, so
#: they are within twice the bound of each other.
BOTH_SIDES = 2.0
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


def _roughness_min(roughness: torch.Tensor, preset: str = "dgrsise", **overrides) -> float:
    """The smallest roughness the BRDF sees: the map's minimum, clamped at the floor."""
    floor = get_preset(preset).with_overrides(**overrides).roughness_floor
    return max(float(roughness.detach().min()), floor)


def _assert_render_accurate(out: torch.Tensor, maps, light, camera, what: str = "", **kwargs) -> None:
    """``out`` = ``kernels.render(*maps, light, camera, **kwargs)`` is the formula's value
    within ``render_rtol``. float64: against the float64 twin, within BOTH_SIDES times the
    bound. float32: the kernel's output and the float32 twin's, each against the float64
    twin on the same (float32-valued) inputs, within the float32 bound; so a formula that
    is ill-conditioned in float32 fails even when kernel and twin share its error."""
    rtol = render_rtol(out.dtype, _roughness_min(maps[2], **kwargs))
    inputs = [*maps, light, camera]
    if out.dtype == torch.float64:
        _assert_close_to_max(out, reference.render(*inputs, **kwargs), BOTH_SIDES * rtol, f"{what} float64")
        return
    exact = reference.render(*(t.detach().double() for t in inputs), **kwargs)
    _assert_close_to_max(out.double(), exact, rtol, f"{what} kernel {out.dtype} vs float64")
    twin = reference.render(*inputs, **kwargs)
    _assert_close_to_max(twin.double(), exact, rtol, f"{what} reference {out.dtype} vs float64")


def _vjp_rtol(dtype: torch.dtype, roughness_min: float, n_sum: int) -> float:
    """Bound on max |VJP error| / max |VJP| of a render evaluated in ``dtype`` whose longest
    gradient sum has ``n_sum`` terms (``VJP_ERR_SCALE``)."""
    return VJP_ERR_SCALE * render_rtol(dtype, roughness_min) + UNIT_ROUNDOFF[dtype] * n_sum**1.5


#: Names of ``kernels.render``'s differentiable inputs, in order.
RENDER_INPUTS = ("diffuse", "normal", "roughness", "specular", "light_pos", "camera_pos")


def _assert_vjp_accurate(inputs, cot: torch.Tensor, n_sum: int, **kwargs) -> None:
    """VJPs of ``kernels.render(*inputs, **kwargs)`` with respect to the inputs that
    require grad, against the twin's, as ``_assert_render_accurate`` does for values, with
    the bound ``_vjp_rtol(dtype, roughness_min, n_sum)``; and each gradient is alive.
    ``inputs``: the six ``RENDER_INPUTS``; ``n_sum``: the longest sum a gradient entry is
    (lights for the maps, pixels, lights and batch items for broadcast positions)."""
    wanted = [i for i, t in enumerate(inputs) if t.requires_grad]
    dtype = inputs[0].dtype
    rtol = _vjp_rtol(dtype, _roughness_min(inputs[2], **kwargs), n_sum)

    def grads(render, xs, c):
        return torch.autograd.grad(render(*xs, **kwargs), [xs[i] for i in wanted], c)

    got = grads(kernels.render, inputs, cot)
    twin = grads(reference.render, inputs, cot)
    if dtype == torch.float64:
        for i, g, t in zip(wanted, got, twin):
            _assert_close_to_max(g, t, BOTH_SIDES * rtol, f"{RENDER_INPUTS[i]} float64")
            _assert_grad_alive(g, t, RENDER_INPUTS[i])
        return
    x64 = [t.detach().double().requires_grad_(t.requires_grad) for t in inputs]
    exact = grads(reference.render, x64, cot.double())
    for i, g, t, e in zip(wanted, got, twin, exact):
        _assert_close_to_max(g.double(), e, rtol, f"{RENDER_INPUTS[i]} kernel {dtype} vs float64")
        _assert_close_to_max(t.double(), e, rtol, f"{RENDER_INPUTS[i]} reference {dtype} vs float64")
        _assert_grad_alive(g, e, RENDER_INPUTS[i])


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
def assert_render_accurate():
    """``assert_render_accurate(out, maps, light, camera, what="", **render_kwargs)``:
    the render is within ``render_rtol`` of the formula's value (float64 evaluation)."""
    return _assert_render_accurate


@pytest.fixture
def assert_vjp_accurate():
    """``assert_vjp_accurate(inputs, cot, n_sum, **render_kwargs)``: render VJPs within
    ``_vjp_rtol`` of the formula's (float64 evaluation), and alive."""
    return _assert_vjp_accurate


@pytest.fixture
def roughness_min():
    """``roughness_min(roughness, preset="dgrsise", **overrides)``: smallest roughness after the floor."""
    return _roughness_min


@pytest.fixture
def vjp_rtol():
    """``vjp_rtol(dtype, roughness_min, n_sum)``: the VJP error bound (``VJP_ERR_SCALE``)."""
    return _vjp_rtol


@pytest.fixture
def assert_grad_alive():
    """``assert_grad_alive(grad, ref, what="")``: non-zero gradient, cosine with ref > GRAD_COSINE_MIN."""
    return _assert_grad_alive
