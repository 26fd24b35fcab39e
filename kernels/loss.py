"""Losses evaluated by the Warp kernels, reduced in two stages (per-row/per-pixel sums in
the kernel, then a float64 sum in torch), so means stay accurate over millions of terms.

- ``log_l1_loss`` / ``mse_loss``: image-space losses between any two same-shape tensors.
- ``rendering_loss``: renders SVBRDF maps under K lights and compares them with target
  images through mean |log(x + 0.01) - log(y + 0.01)| in one fused kernel (Deschaintre
  et al. 2018); gradients flow to the maps (and light/camera positions).
- ``map_rendering_loss``: the same against target *maps*, under lights given or sampled
  as in Deschaintre et al. 2018 (``sample_loss_lights``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import cast

import torch

from kernels._autograd import RenderLogL1Function, RowLossFunction, Scene
from kernels._warp import ensure_init
from kernels.checks import broadcast_positions, check_finite, check_same, check_shape
from kernels.presets import RenderPreset
from kernels.render import check_maps, render, resolve_preset

__all__ = [
    "log_l1_loss",
    "mse_loss",
    "rendering_loss",
    "map_rendering_loss",
    "sample_loss_lights",
    "LOG_EPS",
]

#: Offset inside the log (Deschaintre et al. 2018, log(x + 0.01)): compresses the
#: dynamic range of highlights so dark texture still drives the gradient.
LOG_EPS = 0.01


def _pair(x: torch.Tensor, y: torch.Tensor) -> None:
    check_shape(x, "*", name="x")
    check_shape(y, "*", name="y")
    check_same("x", x, y=y)
    if x.shape != y.shape:
        raise ValueError(f"x and y must have the same shape, got {tuple(x.shape)} and {tuple(y.shape)}")
    if x.numel() == 0:
        raise ValueError("x and y must be non-empty")
    check_finite(x=x, y=y)


#: Longest row one kernel thread reduces: bounds the rows of a flat or wide tensor so the
#: work splits over threads and each row's partial sum stays short.
MAX_ROW = 1024


def _rows(x: torch.Tensor) -> torch.Tensor:
    """View ``x`` as ``[R, C]`` rows, C the largest divisor of numel that is <= MAX_ROW."""
    n = x.numel()
    width = next(d for d in range(min(n, MAX_ROW), 0, -1) if n % d == 0)
    return x.reshape(-1, width)


def _mean(partial: torch.Tensor, count: int) -> torch.Tensor:
    return (partial.sum(dtype=torch.float64) / count).to(partial.dtype)


def log_l1_loss(x: torch.Tensor, y: torch.Tensor, eps: float = LOG_EPS) -> torch.Tensor:
    """Mean |log(x + eps) - log(y + eps)| over all elements; x, y linear radiance of any
    (same) shape, non-negative. Gradient to ``x`` only (``y`` is the target). Scalar."""
    ensure_init()
    _pair(x, y)
    if float(x.detach().min()) <= -eps or float(y.detach().min()) <= -eps:
        raise ValueError(f"log_l1_loss needs x, y > -eps ({eps}); got values below it")
    return _mean(RowLossFunction.apply(_rows(x), _rows(y), "log_l1", eps), x.numel())


def mse_loss(x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """Mean squared error over all elements of two same-shape tensors; gradient to ``x``."""
    ensure_init()
    _pair(x, y)
    return _mean(RowLossFunction.apply(_rows(x), _rows(y), "mse", 0.0), x.numel())


def rendering_loss(
    diffuse: torch.Tensor,
    normal: torch.Tensor,
    roughness: torch.Tensor,
    specular: torch.Tensor,
    target: torch.Tensor,
    light_pos: torch.Tensor,
    camera_pos: torch.Tensor,
    *,
    preset: str | RenderPreset = "dgrsise",
    eps: float = LOG_EPS,
    **overrides,
) -> torch.Tensor:
    """Mean log-L1 between the maps rendered under K lights and target images.

    Args:
        diffuse, normal, roughness, specular: predicted maps, as in ``kernels.render``.
        target: ``[B, K, 3, H, W]`` linear radiance to match (e.g. the input photos);
            no gradient flows to it.
        light_pos, camera_pos: positions as in ``kernels.render`` (K of them).
        preset, overrides: scene conventions, as in ``kernels.render``.
    Returns:
        Scalar mean over B*K*3*H*W of |log(x + eps) - log(y + eps)|, differentiable with
        respect to the maps and positions. The rendering is never stored (fused kernel).
    """
    ensure_init()
    b, h, w = check_maps(diffuse, normal, roughness, specular)
    light = broadcast_positions("light_pos", light_pos, b, diffuse)
    camera = broadcast_positions("camera_pos", camera_pos, b, diffuse, num=light.shape[1])
    k = light.shape[1]
    check_shape(target, "B K 3 H W", name="target", dims={"B": b, "K": k, "H": h, "W": w})
    check_same("diffuse", diffuse, target=target)
    check_finite(target=target)
    if float(target.detach().min()) <= -eps:
        raise ValueError(f"target must be > -eps ({eps}) for the log; found {float(target.detach().min()):.4g}")
    p = resolve_preset(preset, **overrides)
    scene = Scene(p.plane_size, p.intensity, p.inverse_square, p.roughness_floor)
    partial = RenderLogL1Function.apply(
        diffuse, normal, roughness, specular, light, camera, target, scene, eps, torch.is_grad_enabled()
    )
    return _mean(partial, b * k * 3 * h * w)


def sample_loss_lights(
    batch: int,
    *,
    plane_size: float = 4.0,
    n_diffuse: int = 3,
    n_specular: int = 6,
    generator: torch.Generator | None = None,
    dtype: torch.dtype = torch.float32,
    device: torch.device | str = "cpu",
) -> tuple[torch.Tensor, torch.Tensor]:
    """Light/camera pairs for the rendering loss, after Deschaintre et al. 2018.

    ``n_diffuse`` configurations place light and camera independently (cosine-weighted
    directions over the hemisphere, distances log-normal around the plane size);
    ``n_specular`` place the light at the camera's mirror image through a random plane
    point, so a highlight lands on the material. Returns (light, camera), each
    ``[batch, n_diffuse + n_specular, 3]`` in scene units of a plane of ``plane_size``.
    """
    half = plane_size / 2

    def rand(*shape):
        return torch.rand(*shape, generator=generator, dtype=torch.float64)

    def hemisphere(n):  # cosine-weighted unit directions, z > 0
        u, phi = rand(batch, n), 2 * math.pi * rand(batch, n)
        r, z = torch.sqrt(u), torch.sqrt(1 - u).clamp_min(0.1)
        return torch.stack([r * torch.cos(phi), r * torch.sin(phi), z], -1)

    def distance(n):  # log-normal, median 2 half-widths: light and camera off the plane
        return half * torch.exp(0.5 + 0.5 * torch.randn(batch, n, 1, generator=generator, dtype=torch.float64))

    light_d = hemisphere(n_diffuse) * distance(n_diffuse)
    camera_d = hemisphere(n_diffuse) * distance(n_diffuse)
    camera_s = hemisphere(n_specular) * distance(n_specular)
    centre = (rand(batch, n_specular, 2) * 2 - 1) * half * 0.75
    shift = torch.cat([centre, torch.zeros(batch, n_specular, 1, dtype=torch.float64)], -1)
    light_s = (
        camera_s
        * torch.tensor([-1.0, -1.0, 1.0], dtype=torch.float64)
        * (distance(n_specular) / camera_s.norm(dim=-1, keepdim=True))
    )
    light = torch.cat([light_d, light_s + shift], 1)
    camera = torch.cat([camera_d, camera_s + shift], 1)
    return light.to(dtype=dtype, device=device), camera.to(dtype=dtype, device=device)


def map_rendering_loss(
    pred: Sequence[torch.Tensor],
    target: Sequence[torch.Tensor],
    light_pos: torch.Tensor | None = None,
    camera_pos: torch.Tensor | None = None,
    *,
    generator: torch.Generator | None = None,
    preset: str | RenderPreset = "dgrsise",
    eps: float = LOG_EPS,
    **overrides,
) -> torch.Tensor:
    """Rendering loss between predicted and target maps (each a (diffuse, normal,
    roughness, specular) sequence, shapes as in ``kernels.render``), under the given
    lights or, when None, lights from ``sample_loss_lights``. Scalar; grads to ``pred``."""
    if len(pred) != 4 or len(target) != 4:
        raise ValueError("pred and target must each be (diffuse, normal, roughness, specular)")
    if (light_pos is None) != (camera_pos is None):
        raise ValueError("give both light_pos and camera_pos, or neither")
    p = resolve_preset(preset, **overrides)
    if light_pos is None or camera_pos is None:  # both None (checked above)
        light_pos, camera_pos = sample_loss_lights(
            pred[0].shape[0],
            plane_size=p.plane_size,
            generator=generator,
            dtype=pred[0].dtype,
            device=pred[0].device,
        )
    with torch.no_grad():
        d, n, r, s = (t.detach() for t in target)
        # return_lvh=False: one tensor (``render``'s return type also covers the pair).
        target_images = cast(torch.Tensor, render(d, n, r, s, light_pos, camera_pos, preset=p))
    diffuse, normal, roughness, specular = pred
    return rendering_loss(diffuse, normal, roughness, specular, target_images, light_pos, camera_pos, preset=p, eps=eps)
