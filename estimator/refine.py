"""Test-time refinement through the differentiable renderer (SPEC section 5).

Both functions fit SVBRDF maps to the input photos by minimising a rendering loss: the
maps re-rendered under the inputs' own lights and camera against the input images,
mean |log(x + 0.01) - log(y + 0.01)| (``kernels.rendering_loss``, Deschaintre et al. 2018).
The renderer is an argument (``render_loss_fn``): the fused Warp kernel by default, or
its pure-torch twin ``kernels.reference.rendering_loss`` (same signature).

- ``refine``: the estimator-based refinement of Luo et al. 2024. Stage 1 optimises an
  additive offset on the bottleneck latent (the decoder then maps it to consistent maps,
  a strong prior); stage 2 fine-tunes only the per-map adapter heads (and the shading
  head of the normals, ``SVBRDFEstimator.adapter_parameters``) on the decoder's (fixed)
  features. It works on a deep copy of the model, never the caller's.
- ``refine_maps``: direct per-pixel optimisation of the maps in an unconstrained space
  (logits for [0, 1] maps, slopes for normals), the classic inverse-rendering baseline.

Everything runs in float32. Each stage stops early when the best loss of the last
``window`` steps improved on the best before them by less than ``tol`` (relative), and
the parameters with the lowest loss seen are the ones returned.
"""

from __future__ import annotations

import copy
from collections.abc import Callable
from typing import NamedTuple

import torch
import torch.nn.functional as F
from tqdm.auto import tqdm

import kernels
from estimator.model import NORMAL_MIN_Z, SVBRDFEstimator, check_views
from materials.types import Material

__all__ = [
    "refine",
    "refine_maps",
    "RefineResult",
    "converged",
    "DEFAULT_TOL",
    "DEFAULT_WINDOW",
    "LATENT_LR",
    "HEAD_LR",
]

#: Early stop: relative improvement of the best loss over the last ``DEFAULT_WINDOW``
#: steps below 1e-4 (the log-L1 of a good fit is ~0.05-0.2; 1e-4 of it is far below the
#: differences the evaluation can see).
DEFAULT_TOL = 1e-4
DEFAULT_WINDOW = 20
#: Adam rates of ``refine``, measured on held-out materials with a checkpoint at step
#: 300-500 (8 inputs, 100 steps, 4 materials): heads at 2e-3 gave +2 dB held-out PSNR over
#: 5e-4; the latent at 1e-2 moved the loss by < 0.1% in 60 steps, 1e-1 by ~3%. The
#: latent is the 4 x 4 bottleneck of a U-Net whose skips carry most of the detail, so
#: stage 1 is a small, global correction; stage 2 does most of the work.
LATENT_LR = 1e-1
HEAD_LR = 2e-3
#: Clamp before taking logits so maps at exactly 0 or 1 stay finite (one 8-bit step is 4e-3).
LOGIT_EPS = 1e-3

RenderLossFn = Callable[..., torch.Tensor]


class RefineResult(NamedTuple):
    """Refined maps (a batched ``Material``, float32), the loss at every step, and how
    many of those steps were latent (stage 1) steps."""

    material: Material
    history: list[float]
    latent_steps: int


def converged(history: list[float], window: int, tol: float) -> bool:
    """True when min(history[-window:]) improved on min(history[:-window]) by less than
    ``tol`` relative (False until more than ``window`` values exist)."""
    if window < 1 or len(history) <= window:
        return False
    before, recent = min(history[:-window]), min(history[-window:])
    return (before - recent) <= tol * abs(before)


def _prepare(images, light_pos, camera_pos, device) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    images, light_pos, camera_pos = check_views(images, light_pos, camera_pos)
    return (t.detach().to(device=device, dtype=torch.float32).contiguous() for t in (images, light_pos, camera_pos))


def _loss_closure(render_loss_fn: RenderLossFn, images, light_pos, camera_pos, preset, overrides):
    def loss(material: Material) -> torch.Tensor:
        return render_loss_fn(*material.map_tensors(), images, light_pos, camera_pos, preset=preset, **overrides)

    return loss


def _optimise(params, make_loss, steps, lr, tol, window, bar, history, stage) -> tuple[list[torch.Tensor], int]:
    """Adam on ``params`` for up to ``steps``; return the best parameter values and the
    steps taken (losses appended to ``history``)."""
    opt = torch.optim.Adam(params, lr=lr)
    best, best_loss, local = [p.detach().clone() for p in params], float("inf"), []
    for _ in range(steps):
        loss = make_loss()
        opt.zero_grad(set_to_none=True)
        loss.backward()
        value = float(loss.detach())
        if value < best_loss:  # the loss belongs to the parameters before this step
            best_loss, best = value, [p.detach().clone() for p in params]
        opt.step()
        history.append(value)
        local.append(value)
        bar.update(1)
        bar.set_postfix(stage=stage, loss=f"{value:.5f}")
        if converged(local, window, tol):
            break
    final = float(make_loss().detach()) if local else float("inf")
    with torch.no_grad():
        if final < best_loss:
            best = [p.detach().clone() for p in params]
        for p, b in zip(params, best):
            p.copy_(b)
    return best, len(local)


def refine(
    model: SVBRDFEstimator,
    images: torch.Tensor,
    light_pos: torch.Tensor,
    camera_pos: torch.Tensor,
    *,
    steps: int = 200,
    latent_steps: int | None = None,
    latent_lr: float = LATENT_LR,
    head_lr: float = HEAD_LR,
    tol: float = DEFAULT_TOL,
    window: int = DEFAULT_WINDOW,
    render_loss_fn: RenderLossFn = kernels.rendering_loss,
    preset: str = "dgrsise",
    progress: bool = True,
    **render_overrides,
) -> RefineResult:
    """Refine the estimator's maps for one batch of captures (module docstring).

    Args:
        model: a trained ``SVBRDFEstimator``; deep-copied, never modified.
        images: ``[B, V, 3, H, W]`` linear radiance of the inputs.
        light_pos, camera_pos: ``[B, V, 3]`` (or ``[V, 3]``) positions of each input.
        steps: total optimisation steps (both stages).
        latent_steps: steps of stage 1 (latent offset); None: ``steps // 4``. Stage 2
            (adapter heads) gets the rest.
        latent_lr, head_lr: Adam learning rates of the two stages.
        tol, window: early stopping (``converged``), per stage.
        render_loss_fn: ``kernels.rendering_loss`` (Warp) or ``kernels.reference.rendering_loss``.
        preset, **render_overrides: scene conventions passed to ``render_loss_fn``.
        progress: show a tqdm bar.
    Returns:
        ``RefineResult(material, history, latent_steps)``; ``material`` maps ``[B, C, H, W]``.

    Example:
        >>> result = refine(model, images, light_pos, camera_pos, steps=50, progress=False)  # doctest: +SKIP
        >>> result.material.diffuse.shape, result.history[0] > result.history[-1]  # doctest: +SKIP
    """
    if steps < 0:
        raise ValueError(f"steps must be >= 0, got {steps}")
    latent_steps = steps // 4 if latent_steps is None else latent_steps
    if not 0 <= latent_steps <= steps:
        raise ValueError(f"latent_steps must lie in [0, steps={steps}], got {latent_steps}")
    work = copy.deepcopy(model).float().eval().requires_grad_(False)
    device = next(work.parameters()).device
    images, light_pos, camera_pos = _prepare(images, light_pos, camera_pos, device)
    loss_of = _loss_closure(render_loss_fn, images, light_pos, camera_pos, preset, render_overrides)
    history: list[float] = []

    with torch.no_grad():
        pyramid = work.encode(images, light_pos, camera_pos)
    with tqdm(total=steps, desc="refine", disable=not progress) as bar:
        offset = torch.zeros_like(pyramid[-1], requires_grad=True)
        _, taken = _optimise(
            [offset],
            lambda: loss_of(work.predict_maps(work.decode(pyramid, offset))),
            latent_steps,
            latent_lr,
            tol,
            window,
            bar,
            history,
            "latent",
        )
        with torch.no_grad():
            features = work.decode(pyramid, offset.detach())
        heads = list(work.adapter_parameters())
        for p in heads:
            p.requires_grad_(True)
        _optimise(
            heads,
            lambda: loss_of(work.predict_maps(features)),
            steps - latent_steps,
            head_lr,
            tol,
            window,
            bar,
            history,
            "heads",
        )
    with torch.no_grad():
        material = work.predict_maps(features)
    return RefineResult(material, history, taken)


def _logit(x: torch.Tensor) -> torch.Tensor:
    return torch.logit(x.clamp(LOGIT_EPS, 1 - LOGIT_EPS))


def refine_maps(
    material: Material,
    images: torch.Tensor,
    light_pos: torch.Tensor,
    camera_pos: torch.Tensor,
    *,
    steps: int = 200,
    lr: float = 1e-2,
    tol: float = DEFAULT_TOL,
    window: int = DEFAULT_WINDOW,
    render_loss_fn: RenderLossFn = kernels.rendering_loss,
    preset: str = "dgrsise",
    progress: bool = True,
    **render_overrides,
) -> RefineResult:
    """Direct per-pixel map optimisation from ``material`` (module docstring).

    Parametrisation: diffuse, roughness and specular as logits of their [0, 1] values
    (clamped to ``[LOGIT_EPS, 1 - LOGIT_EPS]`` first); normals as slopes
    ``(n_x / n_z, n_y / n_z)``, so every parameter value is a unit normal with z > 0.

    Args:
        material: batched initial maps ``[B, C, H, W]`` (e.g. the estimator's output).
        images, light_pos, camera_pos: as in ``refine`` (same B, V; H, W of the maps).
        steps, lr: Adam steps (upper bound, early stop by ``tol`` / ``window``) and rate.
        render_loss_fn, preset, **render_overrides, progress: as in ``refine``.
    Returns:
        ``RefineResult(material, history, 0)``.
    """
    if steps < 0:
        raise ValueError(f"steps must be >= 0, got {steps}")
    if not isinstance(material, Material) or material.diffuse.dim() != 4:
        raise ValueError("material must be a batched Material with maps [B, C, H, W]")
    images, light_pos, camera_pos = _prepare(images, light_pos, camera_pos, material.device)
    if images.shape[0] != material.diffuse.shape[0] or images.shape[-2:] != material.diffuse.shape[-2:]:
        raise ValueError(
            f"images {tuple(images.shape)} must match the material's batch and size "
            f"{tuple(material.diffuse.shape)} ([B, V, 3, H, W] vs [B, 3, H, W])"
        )
    m = material.to(torch.float32)
    n = F.normalize(m.normal.detach(), dim=1)
    # The estimator's own floor on normal z (~87 degree tilt) bounds the slopes.
    nz = n[:, 2:3].clamp_min(NORMAL_MIN_Z)
    params = [
        _logit(m.diffuse.detach()).requires_grad_(True),
        (n[:, :2] / nz).requires_grad_(True),
        _logit(m.roughness.detach()).requires_grad_(True),
        _logit(m.specular.detach()).requires_grad_(True),
    ]

    def to_material(p) -> Material:
        slope = p[1]
        normal = F.normalize(torch.cat([slope, torch.ones_like(slope[:, :1])], dim=1), dim=1)
        return Material(torch.sigmoid(p[0]), normal, torch.sigmoid(p[2]), torch.sigmoid(p[3]))

    loss_of = _loss_closure(render_loss_fn, images, light_pos, camera_pos, preset, render_overrides)
    history: list[float] = []
    with tqdm(total=steps, desc="refine maps", disable=not progress) as bar:
        _optimise(params, lambda: loss_of(to_material(params)), steps, lr, tol, window, bar, history, "maps")
    with torch.no_grad():
        return RefineResult(to_material(params), history, 0)
