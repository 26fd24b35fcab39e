"""Tables of the relighting diffusion model's settings: presets, ablations, bases, and the
arguments a new tiny-preset training run passes.

The architecture itself is ``RelightDiffusion``'s constructor (``relight.diffusion.model``):
its ``@register_to_config`` signature is the only copy of the fields, their defaults and
their checks, and a checkpoint's ``config.json`` holds its arguments.
"""

from __future__ import annotations

__all__ = ["ABLATIONS", "PRESETS", "BASES", "TINY_TRAINING_DEFAULTS"]

#: Paper Table 3 switches -> ConditionEncoder settings.
#: ``ori_ctrlnet``: ControlNet's own conditioning embedding on the photo (plain convs,
#: no BCE, no shuffle, no prior); ``wo_sbce``: no shuffle and no BCE (one MD branch);
#: ``wo_hamd``: plain convs instead of HA/MD; ``wo_prior``: no specular prior.
ABLATIONS: dict[str, dict] = {
    "full": dict(background="bce", conv="gated", prior=True, shuffle=True),
    "ori_ctrlnet": dict(background="plain", conv="plain", prior=False, shuffle=False),
    "wo_sbce": dict(background="md", conv="gated", prior=True, shuffle=False),
    "wo_hamd": dict(background="bce", conv="plain", prior=True, shuffle=True),
    "wo_prior": dict(background="bce", conv="gated", prior=False, shuffle=True),
}

PRESETS = ("tiny", "sd21")
#: What the tiny preset's residual and extra input channels are relative to.
BASES = ("photo", "lambertian")

#: Arguments of the shipped tiny model that differ from ``RelightDiffusion``'s defaults
#: (which keep the behaviour of checkpoints saved before each argument existed): the
#: current best values for a new tiny-preset run (``weights/diffusion/TRAINING.md``,
#: ``relight/DESIGN.md``). Until 2026-12-02 ``photo_concat``, ``residual`` and
#: ``data_scale`` took these values by default for the tiny preset.
TINY_TRAINING_DEFAULTS: dict = {
    "block_out_channels": (32, 64, 64),
    "photo_concat": True,
    "residual": True,
    "data_scale": 3.0,
    "base": "lambertian",
}
