"""``RelightPipeline``: one flash photo + target lights -> relit images (diffusers style).

Inference glue only: the model holds the weights, the scheduler holds the step rule.
A saved pipeline is the model's folder plus the scheduler's ``scheduler_config.json``
beside it (``save_pretrained`` / ``from_pretrained``); a folder without one (a training
checkpoint) samples with ``make_sample_scheduler()``.
"""

from __future__ import annotations

import os
from pathlib import Path

import torch
from diffusers import DDIMScheduler
from tqdm.auto import tqdm

from kernels.checks import FLOATING_DTYPES, ShapeDims, check_above_plane, check_finite, check_shape
from relight.diffusion.model import RelightDiffusion

__all__ = ["RelightPipeline", "DEFAULT_STEPS", "SCHEDULER_CONFIG_NAME", "make_sample_scheduler"]

#: The sampler's settings beside the weights (diffusers' ``SchedulerMixin`` file name).
SCHEDULER_CONFIG_NAME = DDIMScheduler.config_name

#: Sampling steps (SPEC section 4: about 20 steps, guidance 1).
DEFAULT_STEPS = 20


def make_sample_scheduler() -> DDIMScheduler:
    """DDIM with the training schedule's betas, v-prediction, deterministic (eta 0)."""
    return DDIMScheduler(
        num_train_timesteps=1000,
        beta_schedule="scaled_linear",
        beta_start=0.00085,
        beta_end=0.012,
        prediction_type="v_prediction",
        clip_sample=False,
        set_alpha_to_one=False,
        timestep_spacing="trailing",
    )


class RelightPipeline:
    """Relight one flash photo under K target lights with the diffusion model."""

    def __init__(self, model: RelightDiffusion, scheduler: DDIMScheduler | None = None):
        self.model = model
        self.scheduler = scheduler or make_sample_scheduler()

    @classmethod
    def from_pretrained(cls, folder: str | os.PathLike) -> RelightPipeline:
        """The model of ``folder`` (``RelightDiffusion.from_pretrained``, strict) and its
        sampler from ``scheduler_config.json`` there, or ``make_sample_scheduler()`` if
        the folder has none."""
        folder = Path(folder)
        model = RelightDiffusion.from_pretrained(folder)
        scheduler = DDIMScheduler.from_pretrained(folder) if (folder / SCHEDULER_CONFIG_NAME).is_file() else None
        return cls(model, scheduler)

    def save_pretrained(self, folder: str | os.PathLike, *, half: bool = False) -> None:
        """Write the model (``RelightDiffusion.save_pretrained``, ``half`` as there) and the
        scheduler's ``scheduler_config.json`` into ``folder``."""
        self.model.save_pretrained(folder, half=half)
        self.scheduler.save_pretrained(folder)

    @torch.no_grad()
    def __call__(
        self,
        photo: torch.Tensor,
        light_pos: torch.Tensor,
        camera_pos: torch.Tensor,
        *,
        num_inference_steps: int = DEFAULT_STEPS,
        num_samples: int = 1,
        generator: torch.Generator | None = None,
        progress: bool = True,
    ) -> torch.Tensor:
        """
        Args:
            photo: ``[3, H, W]`` linear radiance, lit by a flash at the camera; H = W =
                the model's resolution.
            light_pos: ``[K, 3]`` target light positions (z > 0), scene units.
            camera_pos: ``[3]`` camera (and flash) position (z > 0).
            num_samples: samples per target; the result is their mean (averaging
                reduces the sampler's variance).
        Returns:
            ``[K, 3, H, W]`` linear radiance (the mean over samples). All targets and
            samples are denoised in one batch.
        """
        model = self.model
        res = model.config.resolution
        # 1. Check the inputs (any floating dtype: they are cast to the model's).
        size = ShapeDims(H=res, W=res)
        size.sources.update(H="the model's config (resolution)", W="the model's config (resolution)")
        check_shape(photo, "3 H W", name="photo", dims=size, dtypes=FLOATING_DTYPES)
        k = check_shape(light_pos, "K 3", name="light_pos", dtypes=FLOATING_DTYPES)["K"]
        if k == 0:
            raise ValueError("light_pos must hold at least one target light (K >= 1)")
        check_shape(camera_pos, "3", name="camera_pos", dtypes=FLOATING_DTYPES)
        check_above_plane("light_pos", light_pos)
        check_above_plane("camera_pos", camera_pos)
        check_finite(photo=photo)
        if num_samples < 1 or num_inference_steps < 1:
            raise ValueError("num_samples and num_inference_steps must be at least 1")
        model.eval()
        device = next(model.parameters()).device
        n = k * num_samples
        # 2. Encode the condition once per target (the background is the photo itself).
        photos = photo.to(device)[None].expand(n, -1, -1, -1)
        target_pos = light_pos.to(device).repeat(num_samples, 1)
        cameras = camera_pos.to(device)[None].expand(n, 3)
        cond = model.encode_condition(photos, photos, target_pos, cameras)
        # 3. Start from noise.
        x = torch.randn((n, *model.sample_shape), generator=generator, device="cpu").to(device)
        # 4. Denoise.
        self.scheduler.set_timesteps(num_inference_steps, device=device)
        for t in tqdm(self.scheduler.timesteps, desc="relight", disable=not progress, leave=False):
            v = model.denoise(x, t.expand(n), *cond)
            x = self.scheduler.step(v, t, x).prev_sample
        # 5. Back to linear radiance; average the samples of each target.
        linear = model.to_linear(x, cond.base_x).reshape(num_samples, k, 3, res, res)
        return linear.mean(0)
