"""Image metrics of the evaluations (SPEC section 7: Table 1, relighting; Table 2,
the estimator's re-renderings), in one place below both model packages.

Every metric compares *tone-mapped* images: display values in [0, 1], in the project's
display space (``kernels.tonemap``: clamp then x^(1/2.2) of linear RGB radiance, SPEC
section 2; not sRGB-encoded), laid out ``[..., 3, H, W]`` (the leading dims are
flattened into N), and returns one value per image ``[N]`` (float64, computed on the
CPU in float64) so callers can average over images, materials or lights as they like.

- ``mse``, ``rmse`` (square root of each image's MSE), ``psnr`` (peak 1):
  ``10 log10(1 / MSE)``, with MSE floored at ``MSE_FLOOR`` so identical images give a
  finite 100 dB; ``psnr_from_mse`` for an MSE pooled over several images (the
  estimator's per-material PSNR over all its lights).
- ``ssim``: ``kornia.metrics.ssim``, 11 x 11 Gaussian window (sigma 1.5, Wang et al.
  2004), averaged over pixels and channels.
- ``flip``: mean LDR-FLIP (Andersson et al. 2020, ``flip_evaluator``). FLIP wants
  ``H x W x C`` numpy arrays and silently misreads ``C x H x W`` ones, so the
  conversion happens here, once. Our tone map is a 2.2 gamma, close to the sRGB curve
  FLIP assumes for LDR input; values are passed as they are.
- ``lpips``: only when LPIPS weights are available locally (``lpips_available``); they
  cannot be downloaded here (SPEC section 7), so the evaluation reports "n/a" without them.
"""

from __future__ import annotations

import importlib.util

import numpy as np
import torch
from kornia.metrics import ssim as _kornia_ssim

from kernels.checks import check_shape

__all__ = [
    "mse",
    "rmse",
    "psnr",
    "psnr_from_mse",
    "ssim",
    "flip",
    "lpips_available",
    "METRICS",
    "SSIM_WINDOW",
    "MSE_FLOOR",
]

#: SSIM Gaussian window side (Wang et al. 2004: 11 x 11, sigma 1.5; kornia's sigma).
SSIM_WINDOW = 11
#: Smallest MSE used in PSNR: identical images score 100 dB instead of inf.
MSE_FLOOR = 1e-10


def _pair(pred: torch.Tensor, target: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Images ``[..., 3, H, W]`` (any dtype) flattened to ``[N, 3, H, W]`` float64 on the
    CPU; the two must hold the same N images of the same size."""
    dims = check_shape(pred, "* 3 H W", name="pred", dtypes=None)
    check_shape(target, "* 3 H W", name="target", dims=dims, dtypes=None)
    p, t = pred.reshape(-1, *pred.shape[-3:]), target.reshape(-1, *target.shape[-3:])
    if p.shape[0] != t.shape[0]:
        raise ValueError(f"pred and target must hold as many images, got {tuple(pred.shape)} and {tuple(target.shape)}")
    return p.detach().double().cpu(), t.detach().double().cpu()


def mse(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Mean squared error per image ``[N]`` of tone-mapped ``[..., 3, H, W]`` images."""
    p, t = _pair(pred, target)
    return ((p - t) ** 2).mean(dim=(1, 2, 3))


def rmse(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Root mean squared error per image ``[N]``."""
    return mse(pred, target).sqrt()


def psnr(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """PSNR in dB per image ``[N]`` for values in [0, 1] (peak 1)."""
    return psnr_from_mse(mse(pred, target))


def psnr_from_mse(mse: torch.Tensor | float) -> torch.Tensor:
    """PSNR in dB (peak 1) of mean squared errors of [0, 1] images, floored at
    ``MSE_FLOOR``: ``-10 log10(max(mse, MSE_FLOOR))``, elementwise, float64."""
    return -10.0 * torch.log10(torch.as_tensor(mse, dtype=torch.float64).clamp_min(MSE_FLOOR))


def ssim(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Mean SSIM per image ``[N]`` (kornia, 11 x 11 Gaussian window, data range 1)."""
    p, t = _pair(pred, target)
    window = min(SSIM_WINDOW, *[s - (1 - s % 2) for s in p.shape[-2:]])  # odd, <= image side
    return _kornia_ssim(p, t, window, max_val=1.0).mean(dim=(1, 2, 3))


def flip(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Mean LDR-FLIP error per image ``[N]`` (lower is better), via ``flip_evaluator``."""
    import flip_evaluator

    p, t = _pair(pred, target)
    out = []
    for pi, ti in zip(p, t):
        # CHW -> HWC, contiguous float32 in [0, 1]: the layout flip_evaluator expects.
        ref = np.ascontiguousarray(ti.clamp(0, 1).permute(1, 2, 0).numpy().astype(np.float32))
        test = np.ascontiguousarray(pi.clamp(0, 1).permute(1, 2, 0).numpy().astype(np.float32))
        _, mean_error, _ = flip_evaluator.evaluate(ref, test, "LDR", applyMagma=False)
        out.append(float(mean_error))
    return torch.tensor(out, dtype=torch.float64)


def lpips_available() -> bool:
    """True when the ``lpips`` package is installed (its weights ship inside it)."""
    return importlib.util.find_spec("lpips") is not None


#: Name -> (function, higher is better), in table order.
METRICS = {
    "MSE": (mse, False),
    "RMSE": (rmse, False),
    "PSNR": (psnr, True),
    "SSIM": (ssim, True),
    "FLIP": (flip, False),
}
