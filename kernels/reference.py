"""Pure-torch twins of every public kernel function, with the same names and semantics.

They define what the Warp kernels compute (tests compare forward values and gradients
against them) and are the baseline in the benchmarks. Plain eager torch, autograd by
torch; written for clarity, not speed or memory.
"""

from __future__ import annotations

import math

import torch

from kernels.brdf import FRESNEL_A, FRESNEL_B, NORMALIZE_EPS
from kernels.geometry import highlight_offsets
from kernels.presets import RenderPreset, get_preset

__all__ = [
    "render",
    "lvh_maps",
    "plane_points",
    "cook_torrance",
    "translate",
    "highlight_offsets",
    "log_l1_loss",
    "mse_loss",
    "rendering_loss",
    "LOG_EPS",
]

from kernels.loss import LOG_EPS


def _normalize(x: torch.Tensor, dim: int) -> torch.Tensor:
    return x / torch.sqrt((x * x).sum(dim, keepdim=True) + NORMALIZE_EPS)


def _positions(pos: torch.Tensor, batch: int, num: int | None = None) -> torch.Tensor:
    if pos.dim() == 1:
        pos = pos[None, None]
    elif pos.dim() == 2:
        pos = pos[None]
    return pos.expand(batch, pos.shape[1] if num is None else num, 3)


def plane_points(h: int, w: int, plane_size: float, *, dtype=torch.float32, device="cpu") -> torch.Tensor:
    """``[3, H, W]`` plane positions of the pixel centres (SPEC section 2; row 0 is +y)."""
    j = (torch.arange(w, dtype=dtype, device=device) + 0.5) / w - 0.5
    i = (torch.arange(h, dtype=dtype, device=device) + 0.5) / h - 0.5
    x = (j * plane_size)[None, :].expand(h, w)
    y = (-i * plane_size)[:, None].expand(h, w)
    return torch.stack([x, y, torch.zeros_like(x)])


def cook_torrance(n, l, v, rho_d, f0, rough, rough_floor: float) -> torch.Tensor:
    """BRDF times cosine (see ``kernels.brdf``); vectors on dim -3, broadcasting."""
    h = _normalize(l + v, -3)
    n_dot_l = (n * l).sum(-3, keepdim=True).clamp_min(0)
    n_dot_v = (n * v).sum(-3, keepdim=True).clamp_min(0)
    n_dot_h = (n * h).sum(-3, keepdim=True).clamp_min(0)
    v_dot_h = (v * h).sum(-3, keepdim=True).clamp_min(0)
    r = rough.clamp_min(rough_floor)
    alpha = r * r
    k = alpha * 0.5
    a2 = alpha * alpha
    d = a2 / (math.pi * (n_dot_h * n_dot_h * (a2 - 1) + 1) ** 2)
    fr = f0 + (1 - f0) * torch.exp2((FRESNEL_A * v_dot_h + FRESNEL_B) * v_dot_h)
    vis = 0.25 / ((n_dot_l * (1 - k) + k) * (n_dot_v * (1 - k) + k))
    return (rho_d * (1 - f0) / math.pi + fr * d * vis) * n_dot_l


def render(
    diffuse,
    normal,
    roughness,
    specular,
    light_pos,
    camera_pos,
    *,
    preset: str | RenderPreset = "dgrsise",
    return_lvh: bool = False,
    **overrides,
):
    """Reference for ``kernels.render``: ``[B, K, 3, H, W]`` linear radiance."""
    p = get_preset(preset).with_overrides(**overrides)
    b, _, h, w = diffuse.shape
    light = _positions(light_pos, b)
    camera = _positions(camera_pos, b, light.shape[1])
    x = plane_points(h, w, p.plane_size, dtype=diffuse.dtype, device=diffuse.device)  # [3, H, W]
    to_light = light[..., None, None] - x  # [B, K, 3, H, W]
    dist2 = (to_light * to_light).sum(2, keepdim=True) + NORMALIZE_EPS
    l = to_light / torch.sqrt(dist2)
    v = _normalize(camera[..., None, None] - x, 2)
    n = _normalize(normal, 1)[:, None]
    f = cook_torrance(n, l, v, diffuse[:, None], specular[:, None], roughness[:, None], p.roughness_floor)
    radiance = f * torch.tensor(p.intensity, dtype=diffuse.dtype, device=diffuse.device)[:, None, None]
    if p.inverse_square:
        radiance = radiance / dist2
    if return_lvh:
        return radiance, lvh_maps(light, camera, (h, w), preset=p)
    return radiance


def lvh_maps(light_pos, camera_pos, size, *, preset="dgrsise", plane_size=None) -> torch.Tensor:
    """Reference for ``kernels.lvh_maps``: ``[B, K, 9, H, W]`` unit l, v, h."""
    p = get_preset(preset).with_overrides(plane_size=plane_size)
    batch = light_pos.shape[0] if light_pos.dim() == 3 else 1
    light = _positions(light_pos, batch).detach()
    camera = _positions(camera_pos, batch, light.shape[1]).detach()
    h, w = size
    x = plane_points(h, w, p.plane_size, dtype=light.dtype, device=light.device)
    l = _normalize(light[..., None, None] - x, 2)
    v = _normalize(camera[..., None, None] - x, 2)
    return torch.cat([l, v, _normalize(l + v, 2)], dim=2)


def translate(features: torch.Tensor, offsets: torch.Tensor) -> torch.Tensor:
    """Reference for ``kernels.translate``: ``out(i, j) = features(i - dy, j - dx)``,
    bilinear, coordinates clamped to the map (edge values repeat)."""
    b, c, h, w = features.shape
    dtype, device = features.dtype, features.device
    jj = torch.arange(w, dtype=dtype, device=device)[None, None, :]
    ii = torch.arange(h, dtype=dtype, device=device)[None, :, None]
    sx = (jj - offsets[:, 0, None, None]).clamp(0, w - 1).expand(b, h, w)
    sy = (ii - offsets[:, 1, None, None]).clamp(0, h - 1).expand(b, h, w)
    x0 = sx.detach().floor().long().clamp(max=w - 1)
    y0 = sy.detach().floor().long().clamp(max=h - 1)
    x1, y1 = (x0 + 1).clamp(max=w - 1), (y0 + 1).clamp(max=h - 1)
    fx, fy = (sx - x0.to(dtype))[:, None], (sy - y0.to(dtype))[:, None]
    flat = features.reshape(b, c, h * w)

    def gather(y, x):
        return flat.gather(2, (y * w + x).reshape(b, 1, h * w).expand(b, c, h * w)).reshape(b, c, h, w)

    top = (1 - fx) * gather(y0, x0) + fx * gather(y0, x1)
    bottom = (1 - fx) * gather(y1, x0) + fx * gather(y1, x1)
    return (1 - fy) * top + fy * bottom


def log_l1_loss(x: torch.Tensor, y: torch.Tensor, eps: float = LOG_EPS) -> torch.Tensor:
    """Reference for ``kernels.log_l1_loss``."""
    return (torch.log(x + eps) - torch.log(y.detach() + eps)).abs().mean()


def mse_loss(x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """Reference for ``kernels.mse_loss``."""
    return ((x - y.detach()) ** 2).mean()


def rendering_loss(
    diffuse,
    normal,
    roughness,
    specular,
    target,
    light_pos,
    camera_pos,
    *,
    preset="dgrsise",
    eps: float = LOG_EPS,
    **overrides,
) -> torch.Tensor:
    """Reference for ``kernels.rendering_loss``: render, then log-L1 against target."""
    images = render(diffuse, normal, roughness, specular, light_pos, camera_pos, preset=preset, **overrides)
    return log_l1_loss(images, target, eps)
