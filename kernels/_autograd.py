"""Autograd glue: torch ``autograd.Function`` wrappers around the Warp launches.

Both shading kernels (``render`` and the fused rendering loss) share one argument
prefix (maps, light, camera, scene constants, image width, chunk offsets), one chunked
launcher and one backward. The backward has two paths: the hand-written map gradients
(``kernels.brdf_grad``, fast, no atomics) when no position needs a gradient, else
Warp's generated adjoint, which also yields light and camera gradients. On the CPU the
forward and map-gradient launches shade 16 pixels per thread (``kernels.lanes``): the
per-pixel tensors are viewed as lane groups here. Warp traps handled here (Warp's
torch interop notes): the output adjoint handed to Warp is always a private copy (Warp
consumes it), gradients returned to torch are fresh buffers, and CUDA launches run on
torch's current stream.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import warp as wp

from kernels._grad_kernels import build_grad_kernels
from kernels._image_kernels import build_image_kernels, build_render_log_l1_kernel
from kernels._render_kernels import build_render_kernels
from kernels._warp import chunk_bounds, parallel_chunks, preload, warp_device, warp_scalar, wp_array
from kernels.lanes import CPU_LANES, build_lanes

__all__ = ["Scene", "RenderFunction", "RenderLogL1Function", "RowLossFunction"]


@dataclass(frozen=True)
class Scene:
    """Scene constants of one launch (a resolved RenderPreset)."""

    plane_size: float
    intensity: tuple[float, float, float]
    inverse_square: bool
    roughness_floor: float


def _stream(device: torch.device):
    return wp.stream_from_torch() if device.type == "cuda" else None


def _shading_chunks(batch: int, height: int, device: torch.device) -> tuple[str, list[tuple[int, int]]]:
    """Split over the batch when it feeds every thread, else over image rows."""
    by_batch = chunk_bounds(batch, device)
    by_rows = chunk_bounds(height, device)
    if len(by_batch) >= len(by_rows):
        return "batch", by_batch
    return "rows", by_rows


def _lanes(device: torch.device) -> int:
    """Pixels per thread of the forward and map-gradient launches: ``CPU_LANES`` on the CPU
    (kernels/lanes.py), 1 on CUDA, where a thread per pixel already fills the hardware's
    vector lanes. Warp's generated adjoint (position gradients) always runs one pixel per
    thread: the lane builds have no adjoint."""
    return CPU_LANES if device.type == "cpu" else 1


def _shading_kernel(name: str, dtype: torch.dtype, lanes: int = 1):
    F = warp_scalar(dtype)
    if name == "render":
        return F, build_render_kernels(F).V3, build_render_kernels(F, lanes).render
    return F, build_image_kernels(F).V3, build_render_log_l1_kernel(F, lanes)


def _to_wp(x):
    """Warp view of a tensor argument; scalars pass through."""
    return wp_array(x) if isinstance(x, torch.Tensor) else x


def _padded(t: torch.Tensor, width: int, copy: bool = True) -> torch.Tensor:
    """``t`` with its last dim zero-padded to ``width`` (``t`` itself when it has it);
    ``copy=False``: the padded buffer is all zeros (for an output)."""
    if t.shape[-1] == width:
        return t
    out = t.new_zeros((*t.shape[:-1], width))
    if copy:
        out[..., : t.shape[-1]] = t
    return out


def _lane_array(t: torch.Tensor, lanes: int):
    """Warp view of a contiguous per-pixel tensor ``[..., W]`` (W a multiple of ``lanes``)
    as ``[..., W / lanes]`` lane groups (one contiguous load or store per group)."""
    if lanes == 1:
        return wp_array(t)
    lane_type = build_lanes(warp_scalar(t.dtype), lanes).L
    return wp_array(t.view(*t.shape[:-1], t.shape[-1] // lanes, lanes), dtype=lane_type)


def _maps_only(ctx) -> bool:
    """True when no light or camera position needs a gradient: the backward then takes the
    hand-written map-gradient path (and the forward keeps the Fresnel weights for it)."""
    return not (ctx.needs_input_grad[4] or ctx.needs_input_grad[5])


def _launch_chunked(kernel, maps, light, camera, scene, tail, outputs, adjoint=None, lanes=1) -> None:
    """Launch a per-pixel shading kernel over the batch or row chunks of the thread split.

    Every shading kernel (forward, fused loss, their generated adjoints and the
    hand-written map gradients) takes the same argument prefix: the four maps, light,
    camera, the scene constants, the image width and the chunk offsets; ``tail``: its
    further inputs (torch tensors or scalars); ``outputs``: its output tensors.
    ``adjoint``: None, or ``index -> (adj_inputs, adj_outputs)`` to launch Warp's
    generated adjoint instead. ``lanes``: pixels per thread of ``kernel``; every tensor
    but the positions is per pixel (last dim W) and is viewed as lane groups, zero-padded
    to whole groups when W is not a multiple of ``lanes`` (padded outputs are copied back).
    """
    b, _, h, w = maps[0].shape
    device = maps[0].device
    F = warp_scalar(maps[0].dtype)
    V3 = build_render_kernels(F).V3
    axis, chunks = _shading_chunks(b, h, device)
    groups = -(-w // lanes)
    padded_w = groups * lanes

    def pixels(t: torch.Tensor):
        return _lane_array(_padded(t, padded_w), lanes)

    head = [*(pixels(t) for t in maps), wp_array(light), wp_array(camera)]
    consts = [V3(*scene.intensity), F(scene.plane_size), int(scene.inverse_square), F(scene.roughness_floor), w]
    tail = [pixels(x) if isinstance(x, torch.Tensor) else x for x in tail]
    out_buffers = [_padded(t, padded_w, copy=False) if t.shape[-1] == w else t for t in outputs]
    outs = [_lane_array(t, lanes) for t in out_buffers]

    def launch(index: int, start: int, count: int) -> None:
        offsets = [start, 0] if axis == "batch" else [0, start]
        dim = (count, h, groups) if axis == "batch" else (b, count, groups)
        kwargs = dict(
            dim=dim,
            inputs=[*head, *consts, *offsets, *tail],
            outputs=outs,
            device=warp_device(device),
            stream=_stream(device),
        )
        if adjoint is None:
            wp.launch(kernel, **kwargs)
        else:
            adj_inputs, adj_outputs = adjoint(index)
            wp.launch(kernel, **kwargs, adjoint=True, adj_inputs=adj_inputs, adj_outputs=adj_outputs)

    preload(kernel, warp_device(device))
    parallel_chunks(chunks, launch)
    for t, buf in zip(outputs, out_buffers):
        if buf is not t:
            t.copy_(buf[..., :w])


def _launch_shading(
    name, maps, light, camera, scene, extra, output, fresnel=None, *, grads=None, extra_adj=None, adj_output=None
):
    """Launch a shading kernel (forward, or Warp's generated adjoint when ``grads`` is given).

    ``extra``: the kernel's trailing inputs (torch tensors or scalars); ``fresnel``: None,
    or a ``[B*K, H, W]`` buffer the forward fills with its Fresnel weights for
    ``_maps_backward``; ``grads``: (four map gradient buffers, per-chunk light buffers,
    per-chunk camera buffers).
    """
    store = fresnel is not None
    tail = [*extra, int(store)]
    lanes = _lanes(maps[0].device) if grads is None else 1
    outputs = [output, fresnel if store else _placeholder(maps[0], lanes)]
    if grads is None:
        kernel = _shading_kernel(name, maps[0].dtype, lanes)[2]
        _launch_chunked(kernel, maps, light, camera, scene, tail, outputs, lanes=lanes)
        return
    # Position gradients: Warp's generated adjoint of the one-pixel-per-thread build.
    F, V3, kernel = _shading_kernel(name, maps[0].dtype)
    adj_maps = [wp_array(t) for t in grads[0]]
    adj_consts = [V3(F(0.0), F(0.0), F(0.0)), F(0.0), 0, F(0.0), 0]
    adj_tail = [_to_wp(x) for x in extra_adj] + [0]
    adj_out = [wp_array(adj_output), wp_array(_placeholder(maps[0], 1))]

    def adjoint(index: int):
        adj_pos = [wp_array(grads[1][index]), wp_array(grads[2][index])]
        return [*adj_maps, *adj_pos, *adj_consts, 0, 0, *adj_tail], adj_out

    _launch_chunked(kernel, maps, light, camera, scene, tail, outputs, adjoint)


def _placeholder(like: torch.Tensor, lanes: int) -> torch.Tensor:
    """A one-lane-group stand-in for the Fresnel buffer when the kernel does not write it."""
    return torch.zeros((1, 1, lanes), dtype=like.dtype, device=like.device)


def _fresnel_buffer(ctx, maps, num_lights: int, grad_enabled: bool) -> torch.Tensor | None:
    """``[B*K, H, W]`` for the forward's Fresnel weights when the backward will take the
    map-only path (some map needs a gradient, no position does), else None.
    ``grad_enabled``: torch's grad mode at the call (inside ``forward`` it is always off,
    and ``ctx.needs_input_grad`` does not see ``torch.no_grad()``).

    The weights depend on the positions only; keeping them (4 bytes per pixel and light)
    spares the map-gradient kernel an exp2 per pixel and light, ~15% of its time on the
    CPU (kernels/DESIGN.md)."""
    if grad_enabled and any(ctx.needs_input_grad[:4]) and _maps_only(ctx):
        b, _, h, w = maps[0].shape
        return torch.empty((b * num_lights, h, w), dtype=maps[0].dtype, device=maps[0].device)
    return None


def _maps_backward(name, maps, light, camera, scene, extra, fresnel, cotangent):
    """Hand-written gradients of the four maps only (light and camera get none).

    ``cotangent``: ``[B*K, 3, H, W]`` for "render", ``[B, H, W]`` for "loss"; ``extra``:
    the forward kernel's trailing inputs; ``fresnel``: the forward's Fresnel weights.
    Returns fresh gradient tensors.
    """
    lanes = _lanes(maps[0].device)
    kernel = getattr(build_grad_kernels(warp_scalar(maps[0].dtype), lanes), name)
    grads = [torch.empty_like(t) for t in maps]
    _launch_chunked(kernel, maps, light, camera, scene, [*extra, fresnel, cotangent.contiguous()], grads, lanes=lanes)
    return grads


def _shading_backward(name, maps, light, camera, scene, extra, extra_adj, output, grad_output):
    grads = [torch.zeros_like(t) for t in maps]
    axis, chunks = _shading_chunks(maps[0].shape[0], maps[0].shape[2], maps[0].device)
    # Row chunks of one batch item add into the same light/camera gradient: each chunk
    # gets its own buffer, summed after. Batch chunks write disjoint rows of one buffer.
    if axis == "batch":
        light_adj, camera_adj = [torch.zeros_like(light)] * len(chunks), [torch.zeros_like(camera)] * len(chunks)
        unique = 1
    else:
        light_adj = [torch.zeros_like(light) for _ in chunks]
        camera_adj = [torch.zeros_like(camera) for _ in chunks]
        unique = len(chunks)
    # Warp consumes (zeroes) the output adjoint it is given: hand it a private copy.
    _launch_shading(
        name,
        maps,
        light,
        camera,
        scene,
        extra,
        output,
        grads=(grads, light_adj, camera_adj),
        extra_adj=extra_adj,
        adj_output=grad_output.contiguous().clone(),
    )
    return grads, sum(light_adj[:unique]), sum(camera_adj[:unique])


class RenderFunction(torch.autograd.Function):
    """maps, light [B,K,3], camera [B,K,3], Scene, grad_enabled -> radiance [B,K,3,H,W]
    (``grad_enabled``: ``torch.is_grad_enabled()`` at the call)."""

    @staticmethod
    def forward(ctx, diffuse, normal, roughness, specular, light, camera, scene: Scene, grad_enabled: bool):
        maps = [t.contiguous() for t in (diffuse, normal, roughness, specular)]
        light, camera = light.contiguous(), camera.contiguous()
        b, _, h, w = diffuse.shape
        out = torch.empty((b, light.shape[1], 3, h, w), dtype=diffuse.dtype, device=diffuse.device)
        fresnel = _fresnel_buffer(ctx, maps, light.shape[1], grad_enabled)
        _launch_shading("render", maps, light, camera, scene, [], out.view(-1, 3, h, w), fresnel)
        ctx.scene = scene
        ctx.save_for_backward(*maps, light, camera, out, fresnel)
        return out

    @staticmethod
    def backward(ctx, grad_out):
        *maps, light, camera, out, fresnel = ctx.saved_tensors
        h, w = out.shape[-2:]
        if _maps_only(ctx):
            grads = _maps_backward("render", maps, light, camera, ctx.scene, [], fresnel, grad_out.reshape(-1, 3, h, w))
            return (*grads, None, None, None, None)
        grads, g_light, g_camera = _shading_backward(
            "render", maps, light, camera, ctx.scene, [], [], out.view(-1, 3, h, w), grad_out.reshape(-1, 3, h, w)
        )
        return (*grads, g_light, g_camera, None, None)


class RenderLogL1Function(torch.autograd.Function):
    """maps, light, camera, target [B,K,3,H,W], Scene, eps -> per-pixel sums [B,H,W] of
    |log(render + eps) - log(target + eps)| over lights and channels (target: no grad;
    ``grad_enabled`` as in ``RenderFunction``)."""

    @staticmethod
    def forward(
        ctx, diffuse, normal, roughness, specular, light, camera, target, scene: Scene, eps: float, grad_enabled: bool
    ):
        maps = [t.contiguous() for t in (diffuse, normal, roughness, specular)]
        light, camera = light.contiguous(), camera.contiguous()
        b, _, h, w = diffuse.shape
        target = target.detach().contiguous().view(-1, 3, h, w)
        partial = torch.empty((b, h, w), dtype=diffuse.dtype, device=diffuse.device)
        F = warp_scalar(diffuse.dtype)
        fresnel = _fresnel_buffer(ctx, maps, light.shape[1], grad_enabled)
        _launch_shading("loss", maps, light, camera, scene, [target, F(eps)], partial, fresnel)
        ctx.scene, ctx.eps = scene, eps
        ctx.save_for_backward(*maps, light, camera, target, partial, fresnel)
        return partial

    @staticmethod
    def backward(ctx, grad_partial):
        *maps, light, camera, target, partial, fresnel = ctx.saved_tensors
        F = warp_scalar(partial.dtype)
        if _maps_only(ctx):
            grads = _maps_backward("loss", maps, light, camera, ctx.scene, [target, F(ctx.eps)], fresnel, grad_partial)
            return (*grads, None, None, None, None, None, None)
        # The target takes no gradient; Warp still wants a buffer for its adjoint.
        grads, g_light, g_camera = _shading_backward(
            "loss",
            maps,
            light,
            camera,
            ctx.scene,
            [target, F(ctx.eps)],
            [torch.zeros_like(target), F(0.0)],
            partial,
            grad_partial,
        )
        return (*grads, g_light, g_camera, None, None, None, None)


class RowLossFunction(torch.autograd.Function):
    """x, y ``[R, C]`` -> per-row sums ``[R]`` of a pointwise loss ('log_l1' or 'mse');
    gradients to x only (y is the target)."""

    @staticmethod
    def forward(ctx, x, y, kind: str, eps: float):
        x, y = x.contiguous(), y.detach().contiguous()
        partial = torch.empty(x.shape[0], dtype=x.dtype, device=x.device)
        ctx.kind, ctx.eps = kind, eps
        _launch_rows(x, y, kind, eps, partial)
        ctx.save_for_backward(x, y, partial)
        return partial

    @staticmethod
    def backward(ctx, grad_partial):
        x, y, partial = ctx.saved_tensors
        gx = torch.zeros_like(x)
        _launch_rows(
            x,
            y,
            ctx.kind,
            ctx.eps,
            partial,
            adj=(gx, torch.zeros_like(y), grad_partial.contiguous().clone()),
        )
        return gx, None, None, None


def _launch_rows(x, y, kind, eps, partial, adj=None):
    F = warp_scalar(x.dtype)
    kernels = build_image_kernels(F)
    kernel = kernels.log_l1_rows if kind == "log_l1" else kernels.mse_rows
    scalars = [F(eps)] if kind == "log_l1" else []
    wx, wy, wp_partial = wp_array(x), wp_array(y), wp_array(partial)

    def launch(_index: int, start: int, count: int) -> None:
        kwargs = dict(
            dim=count,
            inputs=[wx, wy, *scalars, start],
            outputs=[wp_partial],
            device=warp_device(x.device),
            stream=_stream(x.device),
        )
        if adj is None:
            wp.launch(kernel, **kwargs)
        else:
            adj_scalars = [F(0.0)] if scalars else []
            wp.launch(
                kernel,
                **kwargs,
                adjoint=True,
                adj_inputs=[wp_array(adj[0]), wp_array(adj[1]), *adj_scalars, 0],
                adj_outputs=[wp_array(adj[2])],
            )

    preload(kernel, warp_device(x.device))
    parallel_chunks(chunk_bounds(x.shape[0], x.device), launch)
