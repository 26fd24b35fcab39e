"""The relighting diffusion model (paper section 4): settings tables, model, objective, pipeline."""

from relight.diffusion.config import ABLATIONS, BASES, PRESETS, TINY_TRAINING_DEFAULTS
from relight.diffusion.model import RelightDiffusion, make_train_scheduler
from relight.diffusion.pipeline import DEFAULT_STEPS, RelightPipeline, make_sample_scheduler

__all__ = [
    "ABLATIONS",
    "BASES",
    "PRESETS",
    "TINY_TRAINING_DEFAULTS",
    "RelightDiffusion",
    "RelightPipeline",
    "make_train_scheduler",
    "make_sample_scheduler",
    "DEFAULT_STEPS",
]

from relight.diffusion.relighter import DiffusionRelighter, load_diffusion_relighter
from relight.interface import register_relighter

# Importing this package makes the model available as get_relighter("diffusion").
register_relighter("diffusion", load_diffusion_relighter)
__all__ += ["DiffusionRelighter", "load_diffusion_relighter"]
