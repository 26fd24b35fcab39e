"""The training objective: v-prediction MSE on groups of renders of one material."""

from __future__ import annotations

import torch
import torch.nn.functional as F
from diffusers import DDPMScheduler

from relight.modules import shuffle_within_groups

__all__ = ["diffusion_loss", "pure_noise_velocity"]


def diffusion_loss(
    model: torch.nn.Module,
    scheduler: DDPMScheduler,
    batch: dict,
    generator: torch.Generator | None = None,
    terminal_fraction: float = 0.0,
) -> torch.Tensor:
    """v-prediction MSE for a batch of groups (SPEC section 4).

    ``batch``: ``images [B, V, 3, H, W]`` linear (view 0: the flash photo), ``light_pos`` /
    ``camera_pos`` ``[B, V, 3]``, and optionally ``clean [B, V, 3, H, W]``
    (``materials.domain_groups.DomainGroups``: ``images`` are then the degraded photos and
    ``clean`` the same views before noise, clipping and quantisation). Every view of a group
    is a target (``clean`` when given, else ``images``); all are conditioned on the group's
    flash photo ``images[:, 0]`` (specular prior, residual base) and on background features
    of the group's ``images``, shuffled within the group (training-time feature shuffle):
    the model sees what a photo gives it and is asked for the unclipped radiance. ``model``
    is a ``RelightDiffusion``, possibly wrapped for distributed training (called, never
    unwrapped).

    ``terminal_fraction``: the share of targets whose timestep is the last one instead of a
    uniform draw. One-step sampling (trailing DDIM) asks the model only at that timestep,
    which uniform sampling visits once in ``num_train_timesteps`` draws. 0 draws nothing
    extra, so the random stream of a run without it is unchanged. With a share, every
    target at the last timestep starts from pure noise (``pure_noise_velocity``).
    """
    images, light_pos, camera_pos = batch["images"], batch["light_pos"], batch["camera_pos"]
    b, v = images.shape[:2]
    backgrounds = images.flatten(0, 1)
    targets = batch["clean"].flatten(0, 1) if "clean" in batch else backgrounds
    photo = images[:, :1].expand(-1, v, -1, -1, -1).flatten(0, 1)
    perm = shuffle_within_groups(b * v, v, generator).to(images.device)
    unwrapped = getattr(model, "module", model)  # DistributedDataParallel keeps the model in .module
    light_pos, camera_pos = light_pos.flatten(0, 1), camera_pos.flatten(0, 1)
    # One base for the target x0 and the UNet's extra channels (the condition).
    base_x = unwrapped.residual_base(photo, light_pos, camera_pos)
    x0 = unwrapped.to_model_space(targets, base_x)
    noise = torch.randn(x0.shape, generator=generator).to(x0.device)
    last = scheduler.config.num_train_timesteps - 1
    t = torch.randint(0, last + 1, (x0.shape[0],), generator=generator)
    if terminal_fraction > 0:
        t = torch.where(torch.rand(t.shape, generator=generator) < terminal_fraction, last, t)
    t = t.to(x0.device)
    x_t = scheduler.add_noise(x0, noise, t)
    target = scheduler.get_velocity(x0, noise, t)
    if terminal_fraction > 0:
        # Trained as one-step sampling is run: from pure noise. The schedule leaves
        # sqrt(alpha_bar) = 0.068 of x0 in x_t at the last timestep, a trace the model
        # could learn to read and never gets at inference.
        pure = (t == last).view(-1, 1, 1, 1)
        alpha_bar = scheduler.alphas_cumprod[last].to(x0)
        x_t = torch.where(pure, noise, x_t)
        target = torch.where(pure, pure_noise_velocity(x0, noise, alpha_bar), target)
    pred = model(x_t, t, photo, backgrounds, light_pos, camera_pos, perm, base_x)
    return F.mse_loss(pred, target)


def pure_noise_velocity(x0: torch.Tensor, noise: torch.Tensor, alpha_bar: torch.Tensor) -> torch.Tensor:
    """The v target for input ``x_t = noise`` (no trace of ``x0``) at a timestep with
    cumulative alpha ``alpha_bar``: the v whose DDIM estimate of x0,
    ``sqrt(alpha_bar) x_t - sqrt(1 - alpha_bar) v``, is ``x0`` exactly. Any shape."""
    return (alpha_bar.sqrt() * noise - x0) / (1 - alpha_bar).sqrt()
