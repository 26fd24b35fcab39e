"""Stable Diffusion 2.1 from a local diffusers folder: the frozen parts of the ``sd21`` preset.

Nothing is downloaded: the folder must hold the diffusers layout (``unet/``, ``vae/``,
``text_encoder/``, ``tokenizer/``), e.g. a copy of ``stabilityai/stable-diffusion-2-1``
made on a machine with network access. The UNet and VAE are frozen; the text encoder
runs once, for the fixed prompt (SPEC section 4), and is then dropped.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import torch
from diffusers import AutoencoderKL, UNet2DConditionModel

__all__ = ["SD21_SUBFOLDERS", "FrozenSD21", "check_sd21_folder", "load_frozen_sd21", "encode_prompt"]

#: Subfolders of a diffusers Stable Diffusion folder that the preset reads.
SD21_SUBFOLDERS = ("unet", "vae", "text_encoder", "tokenizer")


@dataclass
class FrozenSD21:
    """The frozen UNet and VAE (``requires_grad`` off) and the prompt's text embedding
    ``[1, T, D]`` (T = 77 for SD 2.1, D = the UNet's cross-attention width)."""

    unet: UNet2DConditionModel
    vae: AutoencoderKL
    prompt_embeds: torch.Tensor


def check_sd21_folder(path: str | os.PathLike) -> Path:
    """The folder as a Path, or a ``FileNotFoundError`` naming what is missing."""
    folder = Path(path)
    if not folder.is_dir():
        raise FileNotFoundError(f"sd21_path {folder}: no such folder (a local diffusers Stable Diffusion 2.1 copy)")
    missing = [s for s in SD21_SUBFOLDERS if not (folder / s).is_dir()]
    if missing:
        raise FileNotFoundError(f"sd21_path {folder}: missing subfolder(s) {missing}; expected {list(SD21_SUBFOLDERS)}")
    return folder


@torch.no_grad()
def encode_prompt(path: str | os.PathLike, prompt: str) -> torch.Tensor:
    """Text-encoder hidden states ``[1, T, D]`` of ``prompt`` (padded to the tokenizer's
    maximum length, as Stable Diffusion conditions on)."""
    from transformers import CLIPTextModel, CLIPTokenizer  # only the sd21 preset needs transformers

    folder = check_sd21_folder(path)
    tokenizer = CLIPTokenizer.from_pretrained(folder / "tokenizer")
    encoder = CLIPTextModel.from_pretrained(folder / "text_encoder").eval()
    ids = tokenizer(
        prompt, padding="max_length", max_length=tokenizer.model_max_length, truncation=True, return_tensors="pt"
    ).input_ids
    return encoder(ids)[0].detach().float()


def load_frozen_sd21(path: str | os.PathLike, prompt: str) -> FrozenSD21:
    """Load the UNet and VAE (frozen, eval mode) and embed the fixed prompt."""
    folder = check_sd21_folder(path)
    unet = UNet2DConditionModel.from_pretrained(folder / "unet")
    vae = AutoencoderKL.from_pretrained(folder / "vae")
    for module in (unet, vae):
        module.requires_grad_(False)
        module.eval()
    return FrozenSD21(unet=unet, vae=vae, prompt_embeds=encode_prompt(folder, prompt))
