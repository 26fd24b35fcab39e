"""A smooth radial gain on the photo, fitted in the refinement with the maps
(``CaptureConfig.vignetting``): what a real flash photo has and the renderer does not.

The renderer's flash is an isotropic point light (with the 1/d^2 falloff when asked) and
its camera has no vignetting. A phone's flash has a beam narrower than a hemisphere and
its lens darkens the corners, so a real photo falls off from the point under the flash
faster than the render of a flat material: on the 9 real development photos the
refined diffuse map's ring means fell by 0.3-0.5 in log units from the centre to the
corners (the maps had absorbed the optics). The gain

    g(rho) = exp(sum_k a_k rho^(2k)),  k = 1 .. VIGNETTING_TERMS,

with ``rho`` the distance to the point under the flash in half-sides of the grid (1 at
the middle of an edge, sqrt 2 at a corner of a centred photo), multiplies the render of
the photo's view, or of every view (``CaptureConfig.vignetting`` ``"photo"`` / ``"all"``):
the relit views are made from the photo by a relighter trained without vignetting, which
takes the darkening for the material's and carries it into every relit image, so on the
photo alone the relit views pull the falloff back into the diffuse (a synthetic test:
corner-to-centre log diffuse -0.31 without the gain, -0.22 with it on the photo, 0.00 on
all views). Its coefficients ``a`` are fitted with the maps and held at ``a_k <= 0`` (a
gain that only darkens away from the flash point, as a beam and a lens do; projected
after each step): unconstrained, on the real photos the fit also took the materials' own
radial content (a sign brighter at its edges got a gain rising outwards). Even powers
keep ``g`` smooth at the flash point.

A gain and a radial profile of the diffuse explain the views equally well, so where the
fit ends depends on where it starts: at a least-squares fit of the initial diffuse's log
brightness (``fit_vignetting``), with that part divided out of the diffuse. Started at 0
beside a diffuse that has absorbed the falloff, with the maps' Adam rate, the
coefficients stayed within +-0.3 in 100 steps on the real photos (a 10x rate made the
loss of a synthetic test unstable).
"""

from __future__ import annotations

import itertools

import torch

#: Terms of the log-gain polynomial in rho^2: rho^2 and rho^4. Two are enough for a
#: cos^n-like beam and a lens's cos^4-like vignetting over a 45-degree field (both smooth
#: and monotone there), few enough not to follow a texture's own radial profile.
VIGNETTING_TERMS = 2
#: Added to the diffuse's luminance before the log in ``fit_vignetting`` (a black pixel).
FIT_LOG_EPS = 1e-3


def vignetting_basis(side: int, center: tuple[float, float], terms: int = VIGNETTING_TERMS) -> torch.Tensor:
    """``[terms, side, side]`` float32: ``rho^(2k)`` for k = 1 .. terms, ``rho`` the
    distance of each pixel centre from ``center`` (fractional ``(row, col)``, e.g.
    ``matcap.capture.priors.plane_to_grid``) in units of ``side / 2`` pixels.

    >>> b = vignetting_basis(4, (1.5, 1.5))
    >>> tuple(b.shape), round(float(b[0, 0, 0]), 4), round(float(b[1, 0, 0]), 4)
    ((2, 4, 4), 1.125, 1.2656)
    """
    if side < 1 or terms < 1:
        raise ValueError(f"side and terms must be positive, got {side}, {terms}")
    coord = torch.arange(side, dtype=torch.float64)
    rho2 = ((coord[:, None] - center[0]).square() + (coord[None, :] - center[1]).square()) / (side / 2) ** 2
    return torch.stack([rho2**k for k in range(1, terms + 1)]).float()


def fit_vignetting(diffuse: torch.Tensor, basis: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
    """``[terms]``, each <= 0: the least-squares coefficients of
    ``log(luminance(diffuse))`` over the ``basis`` plus a constant, on the pixels of
    ``mask`` (``[S, S]`` bool, None: all), under the darkening constraint (module
    docstring): the smooth radial falloff of a diffuse map's brightness, which the
    refinement starts the gain at (and divides out of the diffuse), since an estimator
    run on a vignetted photo bakes the vignetting into its diffuse. A diffuse brighter
    away from the flash point gets 0 (that is the material's, not the optics').

    The constrained problem is solved exactly by trying every set of free coefficients
    (the others held at 0: 2^terms small solves) and keeping the best feasible one.

    ``diffuse``: ``[1, 3, S, S]`` linear, Rec. 709 primaries.
    """
    lum = (diffuse[0].double() * torch.tensor([0.2126, 0.7152, 0.0722], dtype=torch.float64)[:, None, None]).sum(0)
    y = torch.log(lum + FIT_LOG_EPS).flatten()
    terms = basis.double().flatten(1)
    if mask is not None:
        keep = mask.flatten()
        y, terms = y[keep], terms[:, keep]
    best, best_residual = torch.zeros(basis.shape[0], dtype=torch.float64), float("inf")
    for free in itertools.product((False, True), repeat=basis.shape[0]):
        index = [k for k, f in enumerate(free) if f]
        design = torch.cat([torch.ones(1, y.numel(), dtype=torch.float64), terms[index]]).T
        solution = torch.linalg.lstsq(design, y[:, None]).solution[:, 0]
        if bool((solution[1:] > 0).any()):
            continue
        residual = float((design @ solution - y).square().sum())
        if residual < best_residual:
            best_residual, best = (
                residual,
                torch.zeros_like(best).index_copy(0, torch.tensor(index, dtype=torch.long), solution[1:]),
            )
    return best.to(basis.dtype)


def vignetting_gain(coefficients: torch.Tensor, basis: torch.Tensor) -> torch.Tensor:
    """``[side, side]``: ``exp(sum_k coefficients[k] * basis[k])``, the gain multiplying the
    photo's render (linear radiance, any colour space: one factor for all channels).

    ``coefficients``: ``[terms]`` (differentiable); ``basis``: ``vignetting_basis``'s.
    """
    if coefficients.shape != basis.shape[:1]:
        raise ValueError(f"coefficients must be [{basis.shape[0]}], got {tuple(coefficients.shape)}")
    return torch.exp(torch.tensordot(coefficients, basis, dims=1))
