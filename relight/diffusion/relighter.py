"""The diffusion model behind the common ``Relighter`` interface (registry name
``"diffusion"``), so evaluations and the command line can swap it for the baselines."""

from __future__ import annotations

import os
from pathlib import Path

import torch
from diffusers import DDIMScheduler

from relight.diffusion.model import CONFIG_NAME, RelightDiffusion
from relight.diffusion.pipeline import DEFAULT_STEPS, RelightPipeline
from relight.interface import Relighter
from weights import weights_dir

__all__ = ["DiffusionRelighter", "load_diffusion_relighter"]


class DiffusionRelighter(Relighter):
    """Relights with ``RelightPipeline``; stochastic (seed it with ``generator``)."""

    name = "diffusion"
    stochastic = True

    def __init__(
        self,
        model: RelightDiffusion,
        steps: int = DEFAULT_STEPS,
        num_samples: int = 1,
        scheduler: DDIMScheduler | None = None,
    ):
        self.pipeline = RelightPipeline(model, scheduler)
        self.steps = steps
        self.num_samples = num_samples

    def _relight(self, photo, light_pos, camera_pos, *, generator=None):
        outs = [
            self.pipeline(
                photo[b].float(),
                light_pos[b].float(),
                camera_pos[b].float(),
                num_inference_steps=self.steps,
                num_samples=self.num_samples,
                generator=generator,
                progress=False,
            )
            for b in range(photo.shape[0])
        ]
        return torch.stack(outs).to(photo.device, photo.dtype)


def load_diffusion_relighter(checkpoint: str | os.PathLike | None = None) -> DiffusionRelighter:
    """From a ``save_pretrained`` folder, a training checkpoint (``.../latest``, the model in
    ``model/``), or (None) the shipped tiny model, ``weights_dir("diffusion")``; the sampler
    from the folder's ``scheduler_config.json`` when it has one (``RelightPipeline.from_pretrained``)."""
    folder = Path(checkpoint) if checkpoint is not None else weights_dir("diffusion")
    if not (folder / CONFIG_NAME).is_file():
        # A training checkpoint folder holds the model under model/.
        if not (folder / "model" / CONFIG_NAME).is_file():
            raise FileNotFoundError(f"{folder}: not a relighting checkpoint (no {CONFIG_NAME} there or in model/)")
        folder = folder / "model"
    pipeline = RelightPipeline.from_pretrained(folder)
    return DiffusionRelighter(pipeline.model, scheduler=pipeline.scheduler)
