"""Typed configuration of the relighting diffusion model: presets and ablations."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

__all__ = ["RelightConfig", "ABLATIONS", "PRESETS", "BASES"]

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


@dataclass(frozen=True)
class RelightConfig:
    """Architecture of the relighting model.

    Attributes:
        preset: "tiny" (pixel space, trained from scratch on the CPU) or "sd21" (Stable
            Diffusion 2.1 from a local folder, latent space, frozen UNet/VAE/text encoder).
        resolution: image side in pixels.
        block_out_channels, layers_per_block, attention_head_dim, cross_attention_dim:
            the tiny UNet (ignored by sd21, which reads its own).
        num_light_tokens: light/view tokens per image (decoupled cross-attention).
        condition_widths: branch widths of the condition encoder (ControlNet's are
            16, 16, 32, 32, 96, 96; the tiny preset halves them and caps at 32, since in
            pixel space the branches run at full resolution and would dominate a step).
        ablation: one of ``ABLATIONS``.
        plane_size: scene plane side (dgrsise preset: 4), for the prior's translation.
        prompt: the fixed text prompt of the sd21 preset (SPEC section 4).
        sd21_path: local diffusers folder of Stable Diffusion 2.1 (sd21 only).
        photo_concat: also feed the photo (model space) to the UNet and ControlNet as
            extra input channels (tiny only: its UNet is trained from scratch, so its
            input layer is free to change; sd21's frozen UNet keeps 4 latent channels).
            None: the preset's default (tiny: on, sd21: off).
        residual: diffuse the difference between the target and the photo (model space)
            instead of the target itself; the texture the two share needs no generating.
            None: the preset's default (tiny: on, sd21: off).
        base: what ``photo_concat`` and ``residual`` use as "the photo": ``"photo"``, the
            flash photo itself, or ``"lambertian"``, its analytic relighting under the
            target light (``relight.shading``; the ``lambertian`` baseline's output). The
            latter starts the model from the better of the two baselines (Table 1: 23.9
            vs 20.3 dB), leaving it highlights and specular shading to generate. Tiny only.
        data_scale: the tiny preset diffuses ``data_scale`` times its pixel-space variable
            (tone-mapped [-1, 1], or the residual). Our renders have a standard deviation
            near 0.3 there (residuals 0.35, measured on 24 training groups); 3 brings it
            near 1, the variance the noise schedule was designed for (SD scales its
            latents the same way). At 1, the last DDIM step starts below SNR 1 and its
            leftover noise stays in the samples.
    """

    preset: str = "tiny"
    resolution: int = 64
    block_out_channels: tuple[int, ...] = (32, 64, 128)
    layers_per_block: int = 1
    attention_head_dim: int = 8
    cross_attention_dim: int = 64
    num_light_tokens: int = 4
    condition_widths: tuple[int, ...] = (8, 8, 16, 16, 32, 32)
    ablation: str = "full"
    plane_size: float = 4.0
    prompt: str = "a photo taken of the surface of an object"
    sd21_path: str | None = None
    photo_concat: bool | None = None
    residual: bool | None = None
    data_scale: float = 3.0
    base: str = "photo"
    extra: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.preset not in PRESETS:
            raise ValueError(f"unknown preset {self.preset!r}; known: {PRESETS}")
        if self.ablation not in ABLATIONS:
            raise ValueError(f"unknown ablation {self.ablation!r}; known: {sorted(ABLATIONS)}")
        if self.preset == "sd21" and not self.sd21_path:
            raise ValueError("the sd21 preset needs sd21_path, a local diffusers folder of Stable Diffusion 2.1")
        tiny = self.preset == "tiny"
        for name in ("photo_concat", "residual"):
            if getattr(self, name) is None:
                object.__setattr__(self, name, tiny)  # frozen dataclass: resolve the preset default once
            elif getattr(self, name) and not tiny:
                raise ValueError(f"{name} needs a UNet trained from scratch (preset 'tiny'), not {self.preset!r}")
        if self.base not in BASES:
            raise ValueError(f"unknown base {self.base!r}; known: {BASES}")
        if self.base != "photo" and not tiny:
            raise ValueError(f"base {self.base!r} needs the tiny preset, not {self.preset!r}")
        if self.resolution % 8:
            raise ValueError(f"resolution must be a multiple of 8, got {self.resolution}")

    def to_dict(self) -> dict:
        d = asdict(self)
        d["block_out_channels"] = list(self.block_out_channels)
        d["condition_widths"] = list(self.condition_widths)
        return d

    @staticmethod
    def from_dict(d: dict) -> RelightConfig:
        d = dict(d)
        # Checkpoints written before these switches existed used neither.
        d.setdefault("photo_concat", False)
        d.setdefault("residual", False)
        d.setdefault("data_scale", 1.0)
        d.setdefault("base", "photo")
        d["block_out_channels"] = tuple(d["block_out_channels"])
        d["condition_widths"] = tuple(d["condition_widths"])
        return RelightConfig(**d)
