"""The relighting diffusion model: UNet + ControlNet (diffusers) conditioned by the
condition encoder (BCE + translated specular prior) and light/view tokens.

Data flow for N target images (SPEC section 4):

    photo, background photos, light_pos/camera_pos --> ConditionEncoder --> [N, C, h, w]
        (replaces ControlNet's conditioning embedding: added to its conv_in output)
    l/v/h maps of the targets --> LightTokenEncoder --> [N, L, D] light tokens
    [null text | light tokens] --> decoupled cross-attention in UNet and ControlNet
    [x_t | base], t --> ControlNet residuals --> UNet --> v-prediction

The tiny preset works in pixel space on tone-mapped images scaled to [-1, 1]. Two
switches of the tiny preset (both on by default, see ``RelightConfig``) depart from the
paper's SD 2.1 set-up, whose frozen UNet can only be steered through ControlNet: the
photo also enters the UNet as extra input channels, and the model diffuses the
difference target - photo rather than the target. A checkpoint trained without them
placed highlights correctly but generated its own texture (relight/DESIGN.md). With
``base="lambertian"``, "the photo" in both switches is its analytic Lambertian
relighting under the target light instead (``relight.shading``).
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import NamedTuple

import torch
from diffusers import ControlNetModel, DDPMScheduler, UNet2DConditionModel
from safetensors.torch import load_file, save_file
from torch import nn

import kernels
from kernels.presets import get_preset
from relight.diffusion.config import ABLATIONS, RelightConfig
from relight.diffusion.sd21 import load_frozen_sd21
from relight.modules import ConditionEncoder, LightTokenEncoder, install_decoupled_attention
from relight.shading import lambertian_relight

__all__ = ["RelightDiffusion", "Condition", "CONFIG_NAME", "WEIGHTS_NAME", "make_train_scheduler"]

CONFIG_NAME = "relight_config.json"
WEIGHTS_NAME = "relight.safetensors"


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
        photo, or its Lambertian relighting (``RelightConfig.base``).
    """

    feats: torch.Tensor
    states: torch.Tensor
    base_x: torch.Tensor


def _tiny_unet(cfg: RelightConfig) -> UNet2DConditionModel:
    n = len(cfg.block_out_channels)
    # Self/cross-attention only below full resolution (<= 32x32 at 64 px): full-res
    # attention costs most of a CPU step for little gain.
    down = ("DownBlock2D",) + ("CrossAttnDownBlock2D",) * (n - 1)
    up = ("CrossAttnUpBlock2D",) * (n - 1) + ("UpBlock2D",)
    return UNet2DConditionModel(
        sample_size=cfg.resolution,
        in_channels=6 if cfg.photo_concat else 3,
        out_channels=3,
        down_block_types=down,
        up_block_types=up,
        block_out_channels=cfg.block_out_channels,
        layers_per_block=cfg.layers_per_block,
        attention_head_dim=cfg.attention_head_dim,
        cross_attention_dim=cfg.cross_attention_dim,
        norm_num_groups=8,
    )


class RelightDiffusion(nn.Module):
    """All trainable and frozen parts of the relighting model, saved as one checkpoint
    (sd21: only the trained parts; the frozen ones are re-read from ``sd21_path``)."""

    def __init__(self, config: RelightConfig):
        super().__init__()
        self.config = config
        if config.preset == "tiny":
            self.unet = _tiny_unet(config)
            self.vae = None
            # No text encoder in the tiny preset: one learned token fills the text slot.
            self.null_text = nn.Parameter(torch.zeros(1, 1, config.cross_attention_dim))
        else:
            frozen = load_frozen_sd21(config.sd21_path, config.prompt)
            self.unet, self.vae = frozen.unet, frozen.vae
            self.register_buffer("prompt_embeds", frozen.prompt_embeds, persistent=False)
        self.controlnet = ControlNetModel.from_unet(self.unet, load_weights_from_unet=True)
        self.controlnet.requires_grad_(True)  # copied from a frozen UNet, trained
        # Our condition encoder takes the conditioning embedding's place: its output is
        # added to ControlNet's conv_in output, as the embedding's would be.
        self.controlnet.controlnet_cond_embedding = nn.Identity()
        # Installed after freezing: the new key/value projections are trainable.
        install_decoupled_attention(self.unet, config.num_light_tokens)
        install_decoupled_attention(self.controlnet, config.num_light_tokens)
        self.condition = ConditionEncoder(
            out_channels=self.unet.config.block_out_channels[0],
            downsample=self.vae is not None,
            widths=config.condition_widths,
            **ABLATIONS[config.ablation],
        )
        self.light_tokens = LightTokenEncoder(
            token_dim=self.unet.config.cross_attention_dim, num_tokens=config.num_light_tokens
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
    def save_pretrained(self, folder: str | os.PathLike, *, half: bool = False) -> None:
        """Write ``relight_config.json`` and ``relight.safetensors`` (all weights, the
        decoupled-attention processors included) into ``folder`` (created).

        ``half``: store float16 weights (halves a shipped checkpoint; loading casts them
        back to the model's float32). Training checkpoints keep full precision.
        """
        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        dtype = torch.float16 if half else None
        state = {
            k: (v.detach().to(dtype) if dtype is not None and v.is_floating_point() else v.detach()).contiguous()
            for k, v in self.state_dict().items()
            if not self._is_frozen_key(k)
        }
        save_file(state, str(folder / WEIGHTS_NAME))
        (folder / CONFIG_NAME).write_text(json.dumps(self.config.to_dict(), indent=2))

    @classmethod
    def from_pretrained(cls, folder: str | os.PathLike) -> RelightDiffusion:
        """Rebuild from a folder written by ``save_pretrained``: the architecture comes
        from the config, then every weight is loaded strictly (a missing or unexpected
        key is an error, never a silent warning)."""
        folder = Path(folder)
        if not (folder / CONFIG_NAME).is_file() or not (folder / WEIGHTS_NAME).is_file():
            raise FileNotFoundError(f"{folder}: not a relighting checkpoint (needs {CONFIG_NAME} and {WEIGHTS_NAME})")
        config = RelightConfig.from_dict(json.loads((folder / CONFIG_NAME).read_text()))
        model = cls(config)
        missing, unexpected = model.load_state_dict(load_file(str(folder / WEIGHTS_NAME)), strict=False)
        missing = [k for k in missing if not model._is_frozen_key(k)]
        if missing or unexpected:
            raise RuntimeError(
                f"{folder}: checkpoint does not match the model; missing {missing[:5]}, unexpected {unexpected[:5]}"
            )
        return model

    def _is_frozen_key(self, key: str) -> bool:
        """State-dict keys of the frozen sd21 parts (re-read from ``sd21_path``, never
        saved): the UNet's and VAE's own weights, not the decoupled-attention processors."""
        if self.vae is None:
            return False
        return key.startswith("vae.") or (key.startswith("unet.") and ".processor." not in key)
