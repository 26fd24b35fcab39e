"""Training loss of the estimator: map L1 plus a rendering loss (SPEC section 5).

``L = map_weight * (L1_diffuse + normal_weight * L1_normal + L1_roughness + L1_specular)
    + render_weight * rendering``

- Map L1: mean absolute error of each map against the ground truth, summed over the
  four maps (each map counts once whatever its channel count; Deschaintre et al. 2018
  and Luo et al. 2024 train on per-map L1).
- Rendering: ``kernels.map_rendering_loss``, mean |log(x + 0.01) - log(y + 0.01)| between
  the predicted and the true maps rendered under 9 random light/camera pairs (3 diffuse,
  6 mirror-specular configurations, Deschaintre et al. 2018). It ties the maps to their
  appearance, which the per-map L1 alone does not (e.g. normal vs. albedo trade-offs).

Both weights default to 1.0: at initialisation the summed map L1 and the rendering loss
are both ~1.0 (measured on the first training steps), so neither term dominates; no
tuning beyond that was done for the first training run. ``normal_weight`` (default 1)
was raised for the fine-tuning run of the shipped model (``weights/estimator/TRAINING.md``):
procedural normals are close to flat, so their L1 is the smallest of the four terms and
its gradient the weakest, and the 8-view model had not learnt to read relief from the
extra lightings.

``normal_loss="mse"`` (the default since 2026-12-02; ``"l1"`` is what stages 1-3 of the
shipped weights were trained with) replaces the normal L1 by ``NORMAL_MSE_SCALE`` times its
mean squared error. Why: procedural relief is sparse (most pixels near flat, a few steep grooves), and
the L1-optimal guess under uncertain evidence is the per-pixel median, i.e. flat; a network
trained with L1 settles there, while the evaluation's normal MSE rewards the mean, which
moves off flat as soon as the shading carries any evidence (measured: ``estimator/DESIGN.md``,
"The normal map").
"""

from __future__ import annotations

from collections.abc import Callable

import torch

import kernels
from materials.types import Material

__all__ = [
    "map_l1",
    "estimator_loss",
    "MAP_WEIGHT",
    "RENDER_WEIGHT",
    "NORMAL_WEIGHT",
    "NORMAL_MSE_SCALE",
    "NORMAL_LOSSES",
]

#: Default weight of the summed per-map L1 (module docstring).
MAP_WEIGHT = 1.0
#: Default weight of the rendering loss (module docstring).
RENDER_WEIGHT = 1.0
#: Default weight of the normal map's L1 inside the map term (module docstring).
NORMAL_WEIGHT = 1.0
#: Scale of the normal MSE (``normal_loss="mse"``) so that it is of the size of the L1 it
#: replaces: held-out normal residuals are ~0.045 rms (flat-map MSE 0.002, L1 0.021), so
#: 10 x MSE ~ 0.02 ~ L1, and its gradient per element (20 r ~ 0.9) ~ the L1's (1).
NORMAL_MSE_SCALE = 10.0
#: Accepted ``normal_loss`` values.
NORMAL_LOSSES = ("l1", "mse")


def map_l1(pred: Material, target: Material) -> dict[str, torch.Tensor]:
    """Mean absolute error per map: ``{"diffuse", "normal", "roughness", "specular"}`` -> scalar."""
    return {name: (p - t).abs().mean() for (name, p), t in zip(pred.maps().items(), target.map_tensors())}


def estimator_loss(
    pred: Material,
    target: Material,
    *,
    map_weight: float = MAP_WEIGHT,
    render_weight: float = RENDER_WEIGHT,
    normal_weight: float = NORMAL_WEIGHT,
    normal_loss: str = "mse",
    generator: torch.Generator | None = None,
    map_render_loss_fn: Callable[..., torch.Tensor] = kernels.map_rendering_loss,
) -> dict[str, torch.Tensor]:
    """The training loss and its parts.

    Args:
        pred, target: batched Materials ``[B, C, H, W]`` (linear maps, unit normals).
        map_weight, render_weight: weights of the two terms (module docstring).
        normal_weight: weight of the normal term inside the map term.
        normal_loss: ``"mse"`` (``NORMAL_MSE_SCALE`` x the normal MSE; module docstring)
            or ``"l1"`` (the normal L1, like the other maps).
        generator: drives the random lights of the rendering loss (a fixed seed gives
            fixed lights, e.g. for an overfitting test).
        map_render_loss_fn: ``kernels.map_rendering_loss`` or a function with its signature.
    Returns:
        dict with ``loss`` (the weighted total, differentiable), ``map`` (the map term,
        normal term weighted by ``normal_weight``), ``render``, the four per-map L1s and
        ``normal_mse``, all scalars.
    Raises:
        ValueError: an unknown ``normal_loss``.
    """
    if normal_loss not in NORMAL_LOSSES:
        raise ValueError(f"normal_loss must be one of {NORMAL_LOSSES}, got {normal_loss!r}")
    parts = map_l1(pred, target)
    normal_mse = ((pred.normal - target.normal) ** 2).mean()
    normal_term = parts["normal"] if normal_loss == "l1" else NORMAL_MSE_SCALE * normal_mse
    map_total = sum(normal_weight * normal_term if name == "normal" else v for name, v in parts.items())
    render = (
        map_render_loss_fn(pred.map_tensors(), target.map_tensors(), generator=generator)
        if render_weight
        else torch.zeros((), dtype=pred.dtype, device=pred.device)
    )
    loss = map_weight * map_total + render_weight * render
    return {"loss": loss, "map": map_total, "render": render, **parts, "normal_mse": normal_mse}
