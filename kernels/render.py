"""Public rendering functions on torch tensors, backed by the Warp kernels.

``render`` validates once at the boundary, then runs the Warp kernel through a torch
``autograd.Function``: tensors are shared with Warp without copies (``wp.from_torch``),
the backward pass launches Warp's generated adjoint kernel. ``kernels.reference.render``
is the pure-torch twin that defines the semantics.
"""

from __future__ import annotations

import torch
import warp as wp

from kernels._autograd import RenderFunction, Scene
from kernels._render_kernels import build_render_kernels
from kernels._warp import ensure_init, warp_device, warp_scalar, wp_array
from kernels.checks import ShapeDims, broadcast_positions, check_finite, check_same, check_shape
from kernels.presets import RenderPreset, get_preset

__all__ = ["render", "lvh_maps", "resolve_preset", "check_maps"]


def resolve_preset(preset: str | RenderPreset, **overrides) -> RenderPreset:
    """The preset with keyword overrides (plane_size, intensity, inverse_square, roughness_floor)."""
    unknown = set(overrides) - {"plane_size", "intensity", "inverse_square", "roughness_floor"}
    if unknown:
        raise TypeError(f"unknown render override(s): {sorted(unknown)}")
    return get_preset(preset).with_overrides(**overrides)


def check_maps(diffuse, normal, roughness, specular) -> tuple[int, int, int]:
    """Validate the four SVBRDF maps; return (B, H, W)."""
    dims = ShapeDims()
    check_shape(diffuse, "B 3 H W", name="diffuse", dims=dims)
    check_shape(normal, "B 3 H W", name="normal", dims=dims)
    check_shape(roughness, "B 1 H W", name="roughness", dims=dims)
    check_shape(specular, "B 3 H W", name="specular", dims=dims)
    check_same("diffuse", diffuse, normal=normal, roughness=roughness, specular=specular)
    b, h, w = dims["B"], dims["H"], dims["W"]
    if b == 0 or h == 0 or w == 0:
        raise ValueError(f"maps must be non-empty, got diffuse shape {tuple(diffuse.shape)}")
    check_finite(diffuse=diffuse, normal=normal, roughness=roughness, specular=specular)
    return b, h, w


def render(
    diffuse: torch.Tensor,
    normal: torch.Tensor,
    roughness: torch.Tensor,
    specular: torch.Tensor,
    light_pos: torch.Tensor,
    camera_pos: torch.Tensor,
    *,
    preset: str | RenderPreset = "dgrsise",
    return_lvh: bool = False,
    **overrides,
) -> torch.Tensor | tuple[torch.Tensor, torch.Tensor]:
    """Render SVBRDF maps under K point lights (Cook-Torrance / GGX, SPEC section 2).

    Args:
        diffuse: ``[B, 3, H, W]`` linear RGB albedo, float32 or float64.
        normal: ``[B, 3, H, W]`` tangent-space normals (OpenGL, +y up); normalised here,
            so gradients are those of the normalised vector.
        roughness: ``[B, 1, H, W]`` in [0, 1]; clamped below at the preset's floor.
        specular: ``[B, 3, H, W]`` linear RGB F0.
        light_pos: ``[B, K, 3]`` or ``[K, 3]`` point-light positions (scene units).
        camera_pos: ``[B, K, 3]``, ``[K, 3]``, ``[1, 3]`` or ``[3]`` camera positions.
        preset: ``"dgrsise"``, ``"materialgan"``, ``"deschaintre"`` or a RenderPreset.
        return_lvh: also return the ``[B, K, 9, H, W]`` unit l, v, h vectors (no grad).
        **overrides: ``plane_size``, ``intensity``, ``inverse_square``, ``roughness_floor``.

    Returns:
        ``[B, K, 3, H, W]`` linear radiance (no clamp, no tone map), differentiable with
        respect to the four maps and both positions; with ``return_lvh``, also the l/v/h maps.

    Example:
        >>> import torch, kernels
        >>> d = torch.full((1, 3, 4, 4), 0.5); n = torch.zeros(1, 3, 4, 4); n[:, 2] = 1
        >>> img = kernels.render(d, n, torch.full((1, 1, 4, 4), 0.5), torch.full((1, 3, 4, 4), 0.04),
        ...                      torch.tensor([[0.0, 0.0, 4.0]]), torch.tensor([0.0, 0.0, 4.0]))
        >>> img.shape
        torch.Size([1, 1, 3, 4, 4])
    """
    ensure_init()
    b, h, w = check_maps(diffuse, normal, roughness, specular)
    light = broadcast_positions("light_pos", light_pos, b, diffuse)
    camera = broadcast_positions("camera_pos", camera_pos, b, diffuse, num=light.shape[1])
    p = resolve_preset(preset, **overrides)
    scene = Scene(p.plane_size, p.intensity, p.inverse_square, p.roughness_floor)
    out = RenderFunction.apply(diffuse, normal, roughness, specular, light, camera, scene, torch.is_grad_enabled())
    if return_lvh:
        return out, _lvh(light.detach(), camera.detach(), p.plane_size, h, w)
    return out


def _lvh(light: torch.Tensor, camera: torch.Tensor, plane_size: float, h: int, w: int) -> torch.Tensor:
    b, k, _ = light.shape
    out = torch.empty((b, k, 9, h, w), dtype=light.dtype, device=light.device)
    F = warp_scalar(light.dtype)
    kern = build_render_kernels(F).lvh
    stream = wp.stream_from_torch() if light.device.type == "cuda" else None
    wp.launch(
        kern,
        dim=(b, k, h, w),
        inputs=[wp_array(light.contiguous()), wp_array(camera.contiguous()), F(plane_size), h, w],
        outputs=[wp_array(out.view(b * k, 9, h, w))],
        device=warp_device(light.device),
        stream=stream,
    )
    return out


def lvh_maps(
    light_pos: torch.Tensor,
    camera_pos: torch.Tensor,
    size: tuple[int, int],
    *,
    preset: str | RenderPreset = "dgrsise",
    plane_size: float | None = None,
) -> torch.Tensor:
    """Per-pixel unit light, view and half vectors for K light/camera pairs.

    Args:
        light_pos: ``[B, K, 3]`` or ``[K, 3]`` positions (scene units).
        camera_pos: ``[B, K, 3]``, ``[K, 3]`` or ``[3]``.
        size: (H, W) of the image.
    Returns:
        ``[B, K, 9, H, W]``: channels l (0-2), v (3-5), h (6-8), unit vectors, no grad.
    """
    ensure_init()
    check_shape(light_pos, "* 3", name="light_pos")
    h, w = size
    if h <= 0 or w <= 0:
        raise ValueError(f"size must be positive, got {size}")
    batch = light_pos.shape[0] if light_pos.dim() == 3 else 1
    light = broadcast_positions("light_pos", light_pos, batch, light_pos)
    camera = broadcast_positions("camera_pos", camera_pos, batch, light_pos, num=light.shape[1])
    p = get_preset(preset).with_overrides(plane_size=plane_size)
    return _lvh(light.detach(), camera.detach(), p.plane_size, h, w)
