"""The photo's radial gain fitted in the refinement (``matcap.capture.vignetting``,
``refine_full_resolution(vignetting=True)``): the basis against its formula, the gain's
gradient, and a refinement that puts a vignetted photo's falloff into the gain rather
than into the diffuse."""

from __future__ import annotations

import math

import pytest
import torch

import kernels
from matcap.capture import DEFAULT_RADIAL, MAP_NAMES, CaptureConfig, refine_full_resolution
from matcap.capture.priors import plane_to_grid
from matcap.capture.vignetting import FIT_LOG_EPS, VIGNETTING_TERMS, fit_vignetting, vignetting_basis, vignetting_gain
from materials.types import Material

#: float64 gradcheck of the gain (an exp of a dot product): torch's default tolerances.
GRADCHECK_ATOL = 1e-6
#: The vignetting test's true log-gain at the corners: exp(-0.3 * 2 - 0.05 * 4) = 0.45,
#: a phone flash photo's corner-to-centre ratio (the real development photos' refined
#: diffuse maps were 0.3-0.5 log units darker at the corners).
TRUE_COEFFICIENTS = (-0.3, -0.05)
#: The fitted coefficients against the true ones for a texture of 20% log-normal
#: contrast: its own projection on rho^2, rho^4 is (-0.021, 0.006) for the test's seed;
#: 0.05 is more than twice that and a sixth of the first true coefficient.
FIT_ATOL = 0.05
#: The refined gain at the corners against the true one, relative: the fit starts there
#: and the refinement moves it little (measured 0.5%); 10% would flag a gain that drifts.
GAIN_TOL = 0.1
#: The refined diffuse's corner-to-centre log ratio with the gain (measured -0.002;
#: without it -0.27).
FLAT_TOL = 0.03
#: The constrained fit's squared residual over a grid search's best, absolute: both in
#: float64 over 2304 pixels of a residual ~1 (rounding ~1e-13); the grid's spacing can
#: only make the grid worse, so any excess beyond rounding is a wrong fit.
LSQ_SLACK = 1e-9


def test_basis_is_the_squared_distance_in_half_sides():
    side, center = 10, (3.2, 6.7)
    basis = vignetting_basis(side, center, terms=3)
    for i, j in ((0, 0), (3, 7), (9, 2)):
        rho2 = ((i - center[0]) ** 2 + (j - center[1]) ** 2) / (side / 2) ** 2
        for k in range(3):
            assert math.isclose(float(basis[k, i, j]), rho2 ** (k + 1), rel_tol=1e-6)


def test_zero_coefficients_are_no_gain_and_the_gradient_checks():
    basis = vignetting_basis(8, (3.5, 3.5)).double()
    assert torch.equal(
        vignetting_gain(torch.zeros(VIGNETTING_TERMS, dtype=torch.float64), basis),
        torch.ones(8, 8, dtype=torch.float64),
    )
    a = torch.tensor([-0.2, 0.05], dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda c: vignetting_gain(c, basis), (a,), atol=GRADCHECK_ATOL)
    with pytest.raises(ValueError, match="coefficients must be"):
        vignetting_gain(torch.zeros(3), basis)
    with pytest.raises(ValueError, match="side and terms must be positive"):
        vignetting_basis(0, (0.0, 0.0))


def _uniform(side: int, diffuse: float = 0.3) -> Material:
    return Material(
        torch.full((1, 3, side, side), diffuse),
        torch.tensor([0.0, 0.0, 1.0]).view(1, 3, 1, 1).expand(1, 3, side, side).clone(),
        torch.full((1, 1, side, side), 0.5),
        torch.full((1, 3, side, side), 0.04),
    )


def _corner_to_centre(diffuse: torch.Tensor) -> float:
    """Mean log diffuse beyond rho = 1 minus inside rho = 0.5 (``[1, 3, S, S]``)."""
    side = diffuse.shape[-1]
    rho2 = vignetting_basis(side, ((side - 1) / 2, (side - 1) / 2))[0]
    log_d = diffuse[0].mean(0).log()
    return float(log_d[rho2 > 1].mean() - log_d[rho2 < 0.25].mean())


def test_fit_recovers_the_gain_of_a_textured_diffuse():
    # A stationary texture times a known gain: the fit returns the gain's coefficients
    # (the texture's radial projection is small), with and without a mask.
    side = 64
    basis = vignetting_basis(side, (20.0, 40.0))
    texture = 0.3 * torch.exp(0.2 * torch.randn(1, 1, side, side, generator=torch.Generator().manual_seed(0)))
    diffuse = (texture * vignetting_gain(torch.tensor(TRUE_COEFFICIENTS), basis)).expand(1, 3, side, side)
    mask = torch.ones(side, side, dtype=torch.bool)
    mask[:, 48:] = False
    for m in (None, mask):
        fitted = fit_vignetting(diffuse, basis, m)
        assert torch.allclose(fitted, torch.tensor(TRUE_COEFFICIENTS), atol=FIT_ATOL)
    assert torch.allclose(fit_vignetting(texture.expand(1, 3, side, side), basis), torch.zeros(2), atol=FIT_ATOL)


def test_the_fit_only_darkens():
    # A diffuse brighter away from the point (a material's own content, not optics) gets
    # no gain; one that falls then rises gets the best falloff with each coefficient <= 0,
    # which beats every other feasible candidate on the grid.
    side = 48
    basis = vignetting_basis(side, (23.5, 23.5))
    brighter = 0.2 * vignetting_gain(torch.tensor([0.4, 0.1]), basis).expand(1, 3, side, side)
    assert torch.equal(fit_vignetting(brighter, basis), torch.zeros(2))
    mixed = 0.2 * vignetting_gain(torch.tensor([-0.6, 0.3]), basis).expand(1, 3, side, side)
    fitted = fit_vignetting(mixed, basis)
    assert bool((fitted <= 0).all()) and float(fitted[0]) < 0

    def residual(a: torch.Tensor) -> float:
        log_d = (mixed[0, 0].double() + FIT_LOG_EPS).log() - torch.tensordot(a.double(), basis.double(), dims=1)
        return float((log_d - log_d.mean()).square().sum())

    grid = [torch.tensor([x, y]) for x in torch.linspace(-1, 0, 21) for y in torch.linspace(-1, 0, 21)]
    assert residual(fitted) <= min(residual(a) for a in grid) + LSQ_SLACK


def _vignetted_scene(side: int, lights: torch.Tensor, camera: torch.Tensor) -> tuple[torch.Tensor, Material]:
    """A uniform material rendered under ``lights [K, 3]`` through the true vignetting
    gain about the flash point: ``views [K, 3, side, side]`` (linear) and the maps whose
    diffuse has absorbed the gain (what the estimator returns for such a photo)."""
    truth = _uniform(side)
    basis = vignetting_basis(side, plane_to_grid(0.0, 0.0, side, 4.0))
    gain = vignetting_gain(torch.tensor(TRUE_COEFFICIENTS), basis)
    views = kernels.render(*truth.map_tensors(), lights[None], camera)[0] * gain
    return views, Material(truth.diffuse * gain, truth.normal, truth.roughness, truth.specular)


def test_the_gain_takes_a_vignetted_photo_s_falloff_off_the_diffuse():
    # A uniform material photographed through a vignetting gain, refined from maps whose
    # diffuse has absorbed it (what the estimator returns for such a photo), with the
    # diffuse in the flash-independence prior at its default weight: without the gain
    # the diffuse keeps most of the falloff (or the photo goes unexplained); with it the
    # gain ends near the true one and the diffuse flat.
    side = 64
    camera = torch.tensor([0.0, 0.0, 4.83])
    views, baked = _vignetted_scene(side, camera[None], camera)
    photo = views[0]
    mask = torch.ones(side, side, dtype=torch.bool)
    empty = torch.zeros(0, 3, side, side)

    def refine(vignetting: str):
        return refine_full_resolution(
            baked, photo, mask, empty, mask, camera[None], camera, radial=DEFAULT_RADIAL, radial_maps=MAP_NAMES,
            vignetting=vignetting, steps=50,
        )  # fmt: skip

    without, with_gain = refine("off"), refine("photo")
    assert without.vignetting == ()
    true_corner = TRUE_COEFFICIENTS[0] * 2 + TRUE_COEFFICIENTS[1] * 4  # the log gain at rho^2 = 2
    fitted_corner = with_gain.vignetting[0] * 2 + with_gain.vignetting[1] * 4
    assert abs(fitted_corner - true_corner) < GAIN_TOL * abs(true_corner)
    # Measured: -0.27 log units without the gain (the baked maps' -0.43 cut by the
    # prior), 0.00 with it.
    assert _corner_to_centre(without.material.diffuse) < -0.1
    assert abs(_corner_to_centre(with_gain.material.diffuse)) < FLAT_TOL
    assert min(with_gain.history) < min(without.history)
    assert all(a <= 0 for a in with_gain.vignetting)


def test_vignetting_is_a_config_choice():
    assert CaptureConfig().vignetting == "off"
    assert CaptureConfig(vignetting="all").to_dict()["vignetting"] == "all"
    with pytest.raises(ValueError, match="vignetting must be one of"):
        CaptureConfig(vignetting=True)


def test_on_all_views_the_gain_needs_no_diffuse_prior():
    # The relit views are made from the photo and carry its darkening. With the gain on
    # every view and the diffuse outside the flash-independence prior (the default
    # maps), nothing pulls the fitted falloff back into the diffuse.
    # Measured (50 steps): corner-to-centre log diffuse -0.306 without the gain, -0.215
    # with it on the photo only (the relit views, at equal weight here, pull the falloff
    # back into the diffuse), -0.002 on all views.
    side = 64
    camera = torch.tensor([0.0, 0.0, 4.83])
    lights = torch.tensor([[0.0, 0.0, 4.83], [2.0, 1.0, 4.0], [-1.0, -2.0, 4.0]])
    views, baked = _vignetted_scene(side, lights, camera)
    mask = torch.ones(side, side, dtype=torch.bool)
    result = refine_full_resolution(
        baked, views[0], mask, views[1:], mask, lights, camera, relit_weight=1.0, radial=DEFAULT_RADIAL,
        vignetting="all", steps=50,
    )  # fmt: skip
    true_corner = TRUE_COEFFICIENTS[0] * 2 + TRUE_COEFFICIENTS[1] * 4
    fitted_corner = result.vignetting[0] * 2 + result.vignetting[1] * 4
    assert abs(fitted_corner - true_corner) < GAIN_TOL * abs(true_corner)
    assert abs(_corner_to_centre(result.material.diffuse)) < FLAT_TOL
