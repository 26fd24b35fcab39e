"""The relighting diffusion model: UNet + ControlNet (diffusers) conditioned by the
condition encoder (BCE + translated specular prior) and light/view tokens.

Data flow for N target images (SPEC section 4):

    photo, background photos, light_pos/camera_pos --> ConditionEncoder --> [N, C, h, w]
        (replaces ControlNet's conditioning embedding: added to its conv_in output)
    l/v/h maps of the targets --> LightTokenEncoder --> [N, L, D] light tokens
    [null text | light tokens] --> decoupled cross-attention in UNet and ControlNet
    [x_t | base], t --> ControlNet residuals --> UNet --> v-prediction

The tiny preset works in pixel space on tone-mapped images scaled to [-1, 1]. Two
switches of the tiny preset (``photo_concat``, ``residual``; on in the shipped model and
in new training runs, ``TINY_TRAINING_DEFAULTS``) depart from the paper's SD 2.1 set-up,
whose frozen UNet can only be steered through ControlNet: the photo also enters the UNet
as extra input channels, and the model diffuses the difference target - photo rather
than the target. A checkpoint trained without them
placed highlights correctly but generated its own texture (relight/DESIGN.md). With
``base="lambertian"``, "the photo" in both switches is its analytic Lambertian
relighting under the target light instead (``relight.shading``).

Persistence is diffusers': ``save_pretrained`` writes ``config.json`` (the constructor's
arguments) and ``diffusion_pytorch_model.safetensors``; ``from_pretrained`` rebuilds the
model from the config (the decoupled-attention processors are installed in ``__init__``,
so their weights load like any other) and refuses a missing or unexpected key. The sd21
preset's checkpoints hold only the trained weights: the frozen UNet and VAE are re-read
from ``sd21_path`` by ``__init__``.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path
from typing import NamedTuple

import torch
from diffusers import ControlNetModel, DDPMScheduler, UNet2DConditionModel
from diffusers.configuration_utils import ConfigMixin, register_to_config
from diffusers.models.modeling_utils import ModelMixin
from diffusers.utils import CONFIG_NAME, SAFETENSORS_WEIGHTS_NAME
from safetensors.torch import save_file
from torch import nn

import kernels
from kernels.presets import get_preset
from relight.diffusion.config import ABLATIONS, BASES, PRESETS
from relight.diffusion.sd21 import load_frozen_sd21
from relight.modules import ConditionEncoder, LightTokenEncoder, install_decoupled_attention
from relight.shading import lambertian_relight
from weights import StrictLoadingMixin

__all__ = ["RelightDiffusion", "Condition", "CONFIG_NAME", "WEIGHTS_NAME", "make_train_scheduler"]

#: File names of a saved model, diffusers' standard ones: ``CONFIG_NAME`` ("config.json")
#: and this ("diffusion_pytorch_model.safetensors").
WEIGHTS_NAME = SAFETENSORS_WEIGHTS_NAME


def make_train_scheduler() -> DDPMScheduler:
    """DDPM training noise schedule, v-prediction (SPEC section 4; SD 2.1's settings)."""
    return DDPMScheduler(
        num_train_timesteps=1000,
        beta_schedule="scaled_linear",
        beta_start=0.00085,
        beta_end=0.012,
        prediction_type="v_prediction",
        clip_sample=False,
    )


class Condition(NamedTuple):
    """Everything ``denoise`` needs besides ``x_t`` and ``t``, computed once per target.

    feats: ``[N, C, h, w]`` condition-encoder features (added to ControlNet's conv_in).
    states: ``[N, 1 + L, D]`` null text + light tokens for the cross-attention.
    base_x: ``[N, 3, H, W]`` the residual base in model space ([-1, 1], tone-mapped): the
        photo, or its Lambertian relighting (``RelightDiffusion`` argument ``base``).
    """

    feats: torch.Tensor
    states: torch.Tensor
    base_x: torch.Tensor


def _tiny_unet(
    resolution: int,
    in_channels: int,
    block_out_channels: tuple[int, ...],
    layers_per_block: int,
    attention_head_dim: int,
    cross_attention_dim: int,
) -> UNet2DConditionModel:
    n = len(block_out_channels)
    # Self/cross-attention only below full resolution (<= 32x32 at 64 px): full-res
    # attention costs most of a CPU step for little gain.
    down = ("DownBlock2D",) + ("CrossAttnDownBlock2D",) * (n - 1)
    up = ("CrossAttnUpBlock2D",) * (n - 1) + ("UpBlock2D",)
    return UNet2DConditionModel(
        sample_size=resolution,
        in_channels=in_channels,
        out_channels=3,
        down_block_types=down,
        up_block_types=up,
        block_out_channels=tuple(block_out_channels),
        layers_per_block=layers_per_block,
        attention_head_dim=attention_head_dim,
        cross_attention_dim=cross_attention_dim,
        norm_num_groups=8,
    )


def _is_frozen_sd21_key(key: str) -> bool:
    """State-dict keys of the sd21 preset's frozen parts (re-read from ``sd21_path``, never
    saved): the UNet's and VAE's own weights, not the decoupled-attention processors."""
    return key.startswith("vae.") or (key.startswith("unet.") and ".processor." not in key)


class RelightDiffusion(StrictLoadingMixin, ModelMixin, ConfigMixin):
    """All trainable and frozen parts of the relighting model (module docstring).

    The arguments are the architecture; each one added after checkpoints were saved
    defaults to what those checkpoints were (``photo_concat``, ``residual``, ``data_scale``,
    ``base``), so an older ``config.json`` without it loads as it was trained. A new
    tiny-preset run passes ``relight.diffusion.config.TINY_TRAINING_DEFAULTS``.

    Args:
        preset: ``"tiny"`` (pixel space, trained from scratch on the CPU) or ``"sd21"``
            (Stable Diffusion 2.1 from a local folder, latent space, frozen UNet/VAE/text
            encoder); ``relight.diffusion.config.PRESETS``.
        resolution: image side in pixels (a multiple of 8).
        block_out_channels, layers_per_block, attention_head_dim, cross_attention_dim:
            the tiny UNet (ignored by sd21, which reads its own).
        num_light_tokens: light/view tokens per image (decoupled cross-attention).
        condition_widths: branch widths of the condition encoder (ControlNet's are
            16, 16, 32, 32, 96, 96; the tiny preset halves them and caps at 32, since in
            pixel space the branches run at full resolution and would dominate a step).
        ablation: one of ``relight.diffusion.config.ABLATIONS`` (paper Table 3).
        plane_size: scene plane side (dgrsise preset: 4), for the prior's translation.
        prompt: the fixed text prompt of the sd21 preset (SPEC section 4).
        sd21_path: local diffusers folder of Stable Diffusion 2.1 (sd21 only, required
            there). The frozen UNet and VAE are read from it on every construction,
            ``from_pretrained`` included, so sd21 checkpoints hold only trained weights.
        photo_concat: also feed the photo (model space) to the UNet and ControlNet as
            extra input channels (tiny only: its UNet is trained from scratch, so its
            input layer is free to change; sd21's frozen UNet keeps 4 latent channels).
            False: the first shipped checkpoints, which predate it.
        residual: diffuse the difference between the target and the photo (model space)
            instead of the target itself; the texture the two share needs no generating.
            Tiny only. False: as checkpoints saved before it.
        data_scale: the tiny preset diffuses ``data_scale`` times its pixel-space variable
            (tone-mapped [-1, 1], or the residual). Our renders have a standard deviation
            near 0.3 there (residuals 0.35, measured on 24 training groups); 3 brings it
            near 1, the variance the noise schedule was designed for (SD scales its
            latents the same way). At 1 (checkpoints saved before it), the last DDIM step
            starts below SNR 1 and its leftover noise stays in the samples.
        base: what ``photo_concat`` and ``residual`` use as "the photo": ``"photo"``, the
            flash photo itself, or ``"lambertian"``, its analytic relighting under the
            target light (``relight.shading``; the ``lambertian`` baseline's output). The
            latter starts the model from the better of the two baselines (Table 1: 23.9
            vs 20.3 dB), leaving it highlights and specular shading to generate. Tiny only.
    Raises:
        ValueError: an unknown preset, ablation or base, a tiny-only switch with sd21,
            sd21 without ``sd21_path``, a resolution not a multiple of 8, or a
            non-positive ``data_scale``; naming the argument.
        FileNotFoundError: sd21 with an ``sd21_path`` that is not a diffusers SD folder.

    Example:
        >>> model = RelightDiffusion(resolution=16, block_out_channels=(8, 16), cross_attention_dim=16,
        ...     attention_head_dim=4, num_light_tokens=2, condition_widths=(4, 4, 4, 4, 8, 8))
        >>> model.sample_shape
        (3, 16, 16)
    """

    @register_to_config
    def __init__(
        self,
        preset: str = "tiny",
        resolution: int = 64,
        block_out_channels: tuple[int, ...] = (32, 64, 128),
        layers_per_block: int = 1,
        attention_head_dim: int = 8,
        cross_attention_dim: int = 64,
        num_light_tokens: int = 4,
        condition_widths: tuple[int, ...] = (8, 8, 16, 16, 32, 32),
        ablation: str = "full",
        plane_size: float = 4.0,
        prompt: str = "a photo taken of the surface of an object",
        sd21_path: str | None = None,
        photo_concat: bool = False,
        residual: bool = False,
        data_scale: float = 1.0,
        base: str = "photo",
    ):
        super().__init__()
        if preset not in PRESETS:
            raise ValueError(f"preset: unknown preset {preset!r}; known: {PRESETS}")
        if ablation not in ABLATIONS:
            raise ValueError(f"ablation: unknown ablation {ablation!r}; known: {sorted(ABLATIONS)}")
        if base not in BASES:
            raise ValueError(f"base: unknown base {base!r}; known: {BASES}")
        if preset == "sd21" and not sd21_path:
            raise ValueError("the sd21 preset needs sd21_path, a local diffusers folder of Stable Diffusion 2.1")
        if preset != "tiny":
            for name, value in (("photo_concat", photo_concat), ("residual", residual)):
                if value:
                    raise ValueError(f"{name} needs a UNet trained from scratch (preset 'tiny'), not {preset!r}")
            if base != "photo":
                raise ValueError(f"base {base!r} needs the tiny preset, not {preset!r}")
        if resolution % 8:
            raise ValueError(f"resolution must be a multiple of 8, got {resolution}")
        if not data_scale > 0:
            raise ValueError(f"data_scale must be positive, got {data_scale}")
        if preset == "tiny":
            self.unet = _tiny_unet(
                resolution,
                6 if photo_concat else 3,
                block_out_channels,
                layers_per_block,
                attention_head_dim,
                cross_attention_dim,
            )
            self.vae = None
            # No text encoder in the tiny preset: one learned token fills the text slot.
            self.null_text = nn.Parameter(torch.zeros(1, 1, cross_attention_dim))
        else:
            frozen = load_frozen_sd21(sd21_path, prompt)
            self.unet, self.vae = frozen.unet, frozen.vae
            self.register_buffer("prompt_embeds", frozen.prompt_embeds, persistent=False)
        self.controlnet = ControlNetModel.from_unet(self.unet, load_weights_from_unet=True)
        self.controlnet.requires_grad_(True)  # copied from a frozen UNet, trained
        # Our condition encoder takes the conditioning embedding's place: its output is
        # added to ControlNet's conv_in output, as the embedding's would be.
        self.controlnet.controlnet_cond_embedding = nn.Identity()
        # Installed after freezing (the new key/value projections are trainable), and here
        # in __init__, so that from_pretrained finds their keys in the model it builds.
        install_decoupled_attention(self.unet, num_light_tokens)
        install_decoupled_attention(self.controlnet, num_light_tokens)
        self.condition = ConditionEncoder(
            out_channels=self.unet.config.block_out_channels[0],
            downsample=self.vae is not None,
            widths=tuple(condition_widths),
            **ABLATIONS[ablation],
        )
        self.light_tokens = LightTokenEncoder(
            token_dim=self.unet.config.cross_attention_dim, num_tokens=num_light_tokens
        )

    @property
    def text_embeds(self) -> torch.Tensor:
        """``[1, T, D]``: the learned null token (tiny) or the fixed prompt's embedding (sd21)."""
        return self.null_text if self.vae is None else self.prompt_embeds

    @property
    def latent_scale(self) -> int:
        """Image pixels per model-space pixel: 8 through the VAE (sd21), 1 in pixel space."""
        return 8 if self.vae is not None else 1

    @property
    def sample_shape(self) -> tuple[int, int, int]:
        """(C, h, w) of the diffused variable for one image."""
        side = self.config.resolution // self.latent_scale
        return (self.unet.config.out_channels, side, side)

    # ------------------------------------------------------------------ conditioning
    def feature_size(self) -> tuple[int, int]:
        """(h, w) of the condition features: ControlNet's conv_in resolution."""
        return self.sample_shape[1:]

    def encode_condition(
        self,
        photo: torch.Tensor,
        background: torch.Tensor,
        light_pos: torch.Tensor,
        camera_pos: torch.Tensor,
        permutation: torch.Tensor | None = None,
        base_x: torch.Tensor | None = None,
    ) -> Condition:
        """Conditioning for N targets.

        Args:
            photo: ``[N, 3, H, W]`` linear flash photo (per target).
            background: ``[N, 3, H, W]`` linear photos for the BCE (the photo at inference).
            light_pos, camera_pos: ``[N, 3]`` target light and camera positions.
            permutation: training-time shuffle of BCE features (``shuffle_within_groups``).
            base_x: ``residual_base(photo, light_pos, camera_pos)`` when the caller already has it
                (training: the objective needs it for the target too); None computes it.
        Returns:
            ``Condition`` (features, encoder states ``[N, T + L, D]``, residual base).
        """
        offsets = kernels.highlight_offsets(light_pos, camera_pos, self.config.plane_size, self.feature_size())
        feats = self.condition(background, photo, offsets, permutation)
        lvh = kernels.lvh_maps(
            light_pos[:, None], camera_pos[:, None], photo.shape[-2:], plane_size=self.config.plane_size
        )
        tokens = self.light_tokens(lvh[:, 0])
        states = torch.cat([self.text_embeds.expand(tokens.shape[0], -1, -1), tokens], dim=1)
        if base_x is None:
            base_x = self.residual_base(photo, light_pos, camera_pos)
        return Condition(feats, states, base_x)

    def residual_base(self, photo: torch.Tensor, light_pos: torch.Tensor, camera_pos: torch.Tensor) -> torch.Tensor:
        """What ``residual`` and ``photo_concat`` use as the photo, in model space ``[N, 3, H, W]``:
        the tone-mapped photo, or (``base="lambertian"``) its Lambertian relighting under
        ``light_pos`` ``[N, 3]`` (camera ``camera_pos`` ``[N, 3]``), tone-mapped."""
        if self.config.base == "lambertian":
            # The training groups are rendered with the dgrsise preset (falloff 1); a
            # model for another preset's data would need the falloff in its config.
            preset = get_preset("dgrsise").with_overrides(plane_size=self.config.plane_size)
            photo = lambertian_relight(photo, light_pos[:, None], camera_pos, preset)[:, 0]
        return self.tonemapped(photo)

    def unet_input(self, x_t: torch.Tensor, base_x: torch.Tensor) -> torch.Tensor:
        """``x_t`` ``[N, 3, H, W]``, with the base's channels appended if ``photo_concat``."""
        return torch.cat([x_t, base_x], dim=1) if self.config.photo_concat else x_t

    def denoise(
        self, x_t: torch.Tensor, t: torch.Tensor, feats: torch.Tensor, states: torch.Tensor, base_x: torch.Tensor
    ) -> torch.Tensor:
        """v-prediction ``[N, 3, H, W]`` for noisy targets ``x_t`` at timesteps ``t``
        (the remaining arguments: a ``Condition``, splatted)."""
        x_in = self.unet_input(x_t, base_x)
        down, mid = self.controlnet(x_in, t, encoder_hidden_states=states, controlnet_cond=feats, return_dict=False)
        return self.unet(
            x_in,
            t,
            encoder_hidden_states=states,
            down_block_additional_residuals=down,
            mid_block_additional_residual=mid,
        ).sample

    def forward(
        self,
        x_t: torch.Tensor,
        t: torch.Tensor,
        photo: torch.Tensor,
        background: torch.Tensor,
        light_pos: torch.Tensor,
        camera_pos: torch.Tensor,
        permutation: torch.Tensor | None = None,
        base_x: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """Training forward: condition + denoise in one call, so a DistributedDataParallel
        wrapper sees (and synchronises) every gradient. Shapes as in ``encode_condition``
        and ``denoise``; returns the v-prediction ``[N, 3, H, W]``."""
        return self.denoise(
            x_t, t, *self.encode_condition(photo, background, light_pos, camera_pos, permutation, base_x)
        )

    # ------------------------------------------------------------------ image space
    @staticmethod
    def tonemapped(linear: torch.Tensor) -> torch.Tensor:
        """Linear radiance -> tone-mapped -> [-1, 1] (the tiny preset's pixel space)."""
        return kernels.tonemap(linear) * 2 - 1

    def to_model_space(self, linear: torch.Tensor, base_x: torch.Tensor) -> torch.Tensor:
        """Targets ``[N, 3, H, W]`` linear -> the diffused variable ``x0``: tone-mapped in
        [-1, 1], minus the base ``base_x`` (``residual_base``) if ``residual``, times ``data_scale``; sd21: the VAE latent mean
        ``[N, 4, H/8, W/8]`` times the VAE's scaling factor."""
        x = self.tonemapped(linear)
        if self.vae is not None:
            with torch.no_grad():
                return self.vae.encode(x).latent_dist.mean * self.vae.config.scaling_factor
        return (x - base_x if self.config.residual else x) * self.config.data_scale

    def to_linear(self, x: torch.Tensor, base_x: torch.Tensor) -> torch.Tensor:
        """Inverse of ``to_model_space``: linear radiance, clamped to the tone map's range."""
        if self.vae is not None:
            x = self.vae.decode(x / self.vae.config.scaling_factor).sample
        else:
            x = x / self.config.data_scale
            if self.config.residual:
                x = x + base_x
        return kernels.inverse_tonemap((x.clamp(-1, 1) + 1) / 2)

    # ------------------------------------------------------------------ persistence
    def save_pretrained(self, save_directory: str | os.PathLike, *, half: bool = False, **kwargs) -> None:
        """Write ``config.json`` and ``diffusion_pytorch_model.safetensors`` (diffusers'
        layout, the decoupled-attention processors included) into ``save_directory``.

        Two departures from ``ModelMixin.save_pretrained``, hence the override: the sd21
        preset leaves out the frozen UNet and VAE weights (``__init__`` re-reads them from
        ``sd21_path``), and ``half`` stores float16 weights (halves a shipped checkpoint;
        loading casts them back to the model's float32). Training checkpoints keep full
        precision. ``kwargs`` are accepted for diffusers' call signature and must be empty.
        """
        if kwargs:
            raise TypeError(f"RelightDiffusion.save_pretrained: unsupported arguments {sorted(kwargs)}")
        folder = Path(save_directory)
        folder.mkdir(parents=True, exist_ok=True)
        frozen = self.config.preset == "sd21"
        dtype = torch.float16 if half else None
        state = {
            k: (v.detach().to(dtype) if dtype is not None and v.is_floating_point() else v.detach()).contiguous()
            for k, v in self.state_dict().items()
            if not (frozen and _is_frozen_sd21_key(k))
        }
        # metadata "format": "pt" is what diffusers' own save writes and its loader checks.
        save_file(state, str(folder / WEIGHTS_NAME), metadata={"format": "pt"})
        self.save_config(folder)

    @classmethod
    def from_pretrained(cls, pretrained_model_name_or_path: str | os.PathLike, **kwargs):
        """diffusers' ``from_pretrained``, strict (``weights.StrictLoadingMixin``). For sd21
        the model is built on real tensors (``low_cpu_mem_usage=False``), so the frozen
        weights ``__init__`` reads from ``sd21_path`` stay and only they may be absent
        from the file."""
        config = cls.load_config(pretrained_model_name_or_path, subfolder=kwargs.get("subfolder"))
        if config.get("preset") == "sd21":
            kwargs.setdefault("low_cpu_mem_usage", False)
        return super().from_pretrained(pretrained_model_name_or_path, **kwargs)

    @classmethod
    def _may_be_missing(cls, key: str, config: Mapping) -> bool:
        return config["preset"] == "sd21" and _is_frozen_sd21_key(key)
