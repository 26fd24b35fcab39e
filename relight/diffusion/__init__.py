"""The relighting diffusion model (paper section 4): config, model, objective, pipeline."""

from relight.diffusion.config import ABLATIONS, RelightConfig
from relight.diffusion.model import RelightDiffusion, make_train_scheduler
from relight.diffusion.pipeline import DEFAULT_STEPS, RelightPipeline, make_sample_scheduler

__all__ = [
    "RelightConfig",
    "ABLATIONS",
    "RelightDiffusion",
    "RelightPipeline",
    "make_train_scheduler",
    "make_sample_scheduler",
    "DEFAULT_STEPS",
]
