"""The diffusion model behind the common ``Relighter`` interface (registry name
``"diffusion"``), so evaluations and the command line can swap it for the baselines."""

from __future__ import annotations

import os
from pathlib import Path

import torch

from relight.diffusion.model import CONFIG_NAME, RelightDiffusion
from relight.diffusion.pipeline import DEFAULT_STEPS, RelightPipeline
from relight.interface import SHIPPED_WEIGHTS, Relighter

__all__ = ["DiffusionRelighter", "load_diffusion_relighter"]


class DiffusionRelighter(Relighter):
    """Relights with ``RelightPipeline``; stochastic (seed it with ``generator``)."""

    name = "diffusion"
    stochastic = True

    def __init__(self, model: RelightDiffusion, steps: int = DEFAULT_STEPS, num_samples: int = 1):
        self.pipeline = RelightPipeline(model)
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
    """From a ``save_pretrained`` folder, a training checkpoint (``.../latest``), or
    (None) the shipped tiny model in ``relight/weights/diffusion``."""
    folder = Path(checkpoint) if checkpoint is not None else SHIPPED_WEIGHTS / "diffusion"
    if not (folder / CONFIG_NAME).is_file() and (folder / "model" / CONFIG_NAME).is_file():
        folder = folder / "model"
    return DiffusionRelighter(RelightDiffusion.from_pretrained(folder))
