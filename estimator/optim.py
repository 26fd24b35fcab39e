"""Adam for per-pixel maps with a choice of how far each pixel may step
(``MapAdam``).

Stock Adam divides each element's step by the root of that element's own mean squared
gradient. For a per-pixel map this makes every pixel step by about the learning rate in
the sign of its gradient, however weak its evidence. When the renderer cannot reproduce
the target, the gradient does not vanish at the optimum. The flash highlight of a real
photo is the case in point: its shape differs from the model's lobe. The normals' slope
gradient is then a smooth radial field about the flash point, and per-element Adam turns
its x and y components into sign(x) and sign(y) fields. That draws two sharp creases
across the normal map, one horizontal and one vertical, through the flash point.

With the second moment shared by all pixels of a channel (the mean of the squared
gradient over the map), a pixel's step is proportional to its gradient. The step keeps
the gradient's spatial shape, smooth where it is smooth, and pixels with little evidence
move little. Adam's per-parameter scale invariance is kept per channel, so the same
learning rate still serves maps of any resolution (a mean loss's per-pixel gradient
shrinks with the pixel count): ``lr`` is then the root-mean-square step over the
channel's pixels, not every pixel's step.

Two guards come with the shared moment:
- a ``mask`` of the pixels that count, so that pixels no loss can reach (a photo's
  padding) do not dilute the mean and inflate the real pixels' steps;
- ``max_step``, a cap on any element's step in units of ``lr``. One pixel holding most
  of a channel's gradient would otherwise step by up to ``lr * sqrt(H * W)``.
"""

from __future__ import annotations

from collections.abc import Iterable

import torch

__all__ = ["MapAdam"]


class MapAdam(torch.optim.Optimizer):
    """Adam (Kingma and Ba 2015, bias-corrected, no weight decay) over per-pixel maps.

    Parameters are tensors ``[..., C, H, W]``. In a param group with ``shared=True``, the
    second moment has shape ``[..., C, 1, 1]``: per channel, the mean squared gradient
    over the pixels where ``mask`` is True. In a group with ``shared=False``, it is per
    element, which is ``torch.optim.Adam``'s update (the tests hold it to that).

    Args:
        params: tensors, or param-group dicts (each may set ``shared``, ``mask``,
            ``max_step``).
        lr, betas, eps: as ``torch.optim.Adam``.
        shared: the default for groups that do not set it.
        mask: ``[H, W]`` bool, the pixels the shared mean runs over (None: all).
        max_step: cap on any element's step, in units of ``lr`` (None: no cap).
        share_channels: in shared groups, one second moment for all channels too
            (``[..., 1, 1, 1]``), so a vector map's channels (a normal's x and y slopes)
            are scaled alike and the step keeps the gradient's direction.
    """

    def __init__(
        self,
        params: Iterable[torch.Tensor] | Iterable[dict],
        lr: float = 1e-3,
        betas: tuple[float, float] = (0.9, 0.999),
        eps: float = 1e-8,
        shared: bool = True,
        mask: torch.Tensor | None = None,
        max_step: float | None = None,
        share_channels: bool = False,
    ):
        if not lr > 0:
            raise ValueError(f"lr must be positive, got {lr}")
        if not (0 <= betas[0] < 1 and 0 <= betas[1] < 1):
            raise ValueError(f"betas must be in [0, 1), got {betas}")
        if not eps >= 0:
            raise ValueError(f"eps must be >= 0, got {eps}")
        defaults = dict(
            lr=lr, betas=betas, eps=eps, shared=shared, mask=mask, max_step=max_step, share_channels=share_channels
        )
        super().__init__(params, defaults)

    def add_param_group(self, param_group: dict) -> None:
        """torch's, plus the checks of ``shared``, ``mask`` and ``max_step``; a mask is
        stored as float weights normalised to sum to 1 (the shared mean's weights)."""
        super().add_param_group(param_group)
        group = self.param_groups[-1]
        if group["max_step"] is not None and not group["max_step"] > 0:
            raise ValueError(f"max_step must be positive, got {group['max_step']}")
        mask = group["mask"]
        if mask is not None and not group["shared"]:
            raise ValueError("mask applies to shared groups only")
        for p in group["params"]:
            if group["shared"] and p.dim() < 3:
                raise ValueError(f"shared groups hold [..., C, H, W] maps, got shape {tuple(p.shape)}")
            if mask is not None and tuple(mask.shape) != tuple(p.shape[-2:]):
                raise ValueError(f"mask must be [H, W] = {tuple(p.shape[-2:])}, got {tuple(mask.shape)}")
        if mask is not None:
            if not bool(mask.any()):
                raise ValueError("mask selects no pixel")
            weights = mask.to(group["params"][0].dtype)
            group["mask"] = weights / weights.sum()

    @torch.no_grad()
    def step(self, closure=None):  # type: ignore[override]
        """One update of every parameter that has a gradient (``closure`` as in torch)."""
        loss = None
        if closure is not None:
            with torch.enable_grad():
                loss = closure()
        for group in self.param_groups:
            beta1, beta2 = group["betas"]
            for p in group["params"]:
                if p.grad is None:
                    continue
                state = self.state[p]
                if not state:
                    state["step"] = 0
                    state["exp_avg"] = torch.zeros_like(p)
                    if not group["shared"]:
                        v_shape = p.shape
                    elif group["share_channels"]:
                        v_shape = (*p.shape[:-3], 1, 1, 1)
                    else:
                        v_shape = (*p.shape[:-2], 1, 1)
                    state["exp_avg_sq"] = p.new_zeros(v_shape)
                state["step"] += 1
                t = state["step"]
                grad = p.grad
                state["exp_avg"].lerp_(grad, 1 - beta1)
                square = grad.square()
                if group["shared"]:
                    weights = group["mask"]
                    if weights is None:
                        square = square.mean(dim=(-2, -1), keepdim=True)
                    else:
                        square = (square * weights).sum(dim=(-2, -1), keepdim=True)
                    if group["share_channels"]:
                        square = square.mean(dim=-3, keepdim=True)
                state["exp_avg_sq"].mul_(beta2).add_(square, alpha=1 - beta2)
                # torch's Adam: p -= lr / (1 - b1^t) * m / (sqrt(v) / sqrt(1 - b2^t) + eps)
                denom = (state["exp_avg_sq"].sqrt() / (1 - beta2**t) ** 0.5).add_(group["eps"])
                if group["max_step"] is None:
                    p.addcdiv_(state["exp_avg"], denom, value=-group["lr"] / (1 - beta1**t))
                else:
                    step = (state["exp_avg"] / denom).mul_(1 / (1 - beta1**t))
                    p.sub_(step.clamp_(-group["max_step"], group["max_step"]), alpha=group["lr"])
        return loss
