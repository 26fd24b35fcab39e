"""Decoupled cross-attention (IP-Adapter style, Ye et al. 2023) for light/view tokens.

The encoder states handed to a cross-attention layer are ``[text tokens | light
tokens]``; the last ``num_tokens`` go through their own key/value projections and their
attention output is added (scale 1, SPEC section 4) to the text attention output:

    out = Attn(q, K_text, V_text) + scale * Attn(q, K_ip(light), V_ip(light))

``V_ip`` starts at zero, so installing the processor leaves a pretrained UNet's output
unchanged until training moves it. The processors are ``nn.Module``s held by their
attention layers, so their weights live in the model's ``state_dict``.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from diffusers.models.attention_processor import Attention
from torch import nn

__all__ = ["DecoupledAttnProcessor", "install_decoupled_attention", "decoupled_processors"]


class DecoupledAttnProcessor(nn.Module):
    """Cross-attention processor with a second key/value path for the last tokens."""

    def __init__(self, inner_dim: int, cross_attention_dim: int, num_tokens: int, scale: float = 1.0):
        super().__init__()
        self.to_k_ip = nn.Linear(cross_attention_dim, inner_dim, bias=False)
        self.to_v_ip = nn.Linear(cross_attention_dim, inner_dim, bias=False)
        nn.init.zeros_(self.to_v_ip.weight)
        self.num_tokens = num_tokens
        self.scale = scale

    @staticmethod
    def _attend(attn: Attention, q: torch.Tensor, k: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
        b, heads = q.shape[0], attn.heads
        split = lambda t: t.view(b, -1, heads, t.shape[-1] // heads).transpose(1, 2)  # noqa: E731
        out = F.scaled_dot_product_attention(split(q), split(k), split(v))
        return out.transpose(1, 2).reshape(b, -1, out.shape[1] * out.shape[-1])

    def __call__(self, attn: Attention, hidden_states, encoder_hidden_states=None, attention_mask=None, temb=None, **_):
        if encoder_hidden_states is None:
            raise ValueError("decoupled attention is for cross-attention layers (encoder states required)")
        if attention_mask is not None:
            raise ValueError("decoupled attention does not support attention masks")
        residual = hidden_states
        if attn.spatial_norm is not None:
            hidden_states = attn.spatial_norm(hidden_states, temb)
        ndim = hidden_states.ndim
        if ndim == 4:
            b, c, h, w = hidden_states.shape
            hidden_states = hidden_states.view(b, c, h * w).transpose(1, 2)
        if attn.group_norm is not None:
            hidden_states = attn.group_norm(hidden_states.transpose(1, 2)).transpose(1, 2)
        text = encoder_hidden_states[:, : -self.num_tokens]
        light = encoder_hidden_states[:, -self.num_tokens :]
        if attn.norm_cross:
            text = attn.norm_encoder_hidden_states(text)
        q = attn.to_q(hidden_states)
        out = self._attend(attn, q, attn.to_k(text), attn.to_v(text))
        out = out + self.scale * self._attend(attn, q, self.to_k_ip(light), self.to_v_ip(light))
        out = attn.to_out[1](attn.to_out[0](out.to(q.dtype)))
        if ndim == 4:
            out = out.transpose(-1, -2).reshape(b, c, h, w)
        if attn.residual_connection:
            out = out + residual
        return out / attn.rescale_output_factor


def install_decoupled_attention(model: nn.Module, num_tokens: int, scale: float = 1.0) -> int:
    """Give every cross-attention layer (``attn2``) of ``model`` a decoupled processor.

    Returns the number of layers changed. Call it before loading weights that include
    the processors (their keys are ``...attn2.processor.to_k_ip.weight``).
    """
    count = 0
    for name, module in model.named_modules():
        if isinstance(module, Attention) and module.is_cross_attention and name.endswith("attn2"):
            module.set_processor(
                DecoupledAttnProcessor(module.inner_dim, module.cross_attention_dim, num_tokens, scale)
            )
            count += 1
    if count == 0:
        raise ValueError(f"{type(model).__name__} has no cross-attention layers to decouple")
    return count


def decoupled_processors(model: nn.Module) -> list[DecoupledAttnProcessor]:
    return [m for m in model.modules() if isinstance(m, DecoupledAttnProcessor)]
