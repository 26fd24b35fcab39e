"""The estimator on photos larger than its training crops, window by window (issue 16:
resolution-free estimation).

The estimator is convolutional, but its GroupNorm statistics and global-context term are
taken over the whole image, and it was trained on 64 px crops: on a 1024 px photo run
whole, every normalisation sees 256 times the pixels it learned from, and the forward
needs several GB (``benchmarks/bench_estimate.py --forward-sizes``). ``tiled_estimate``
runs it on ``tile x tile`` windows of the plane instead (``materials.windows``), each in
its own exact frame (the cameras and lights moved into the window's, as the training
crops do), and blends the maps across the overlaps; normals are renormalised after the
blend. Windows go through the network in batches of ``batch``, so the memory is that of
``batch`` crops whatever the photo's size.

Shapes: ``images [B, V, 3, S, S]`` linear radiance in the models' units (no falloff,
``materials.units``); ``light_pos``, ``camera_pos [B, V, 3]`` on a plane of side
``plane_size``. Output: a batched ``Material`` ``[B, C, S, S]``.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from estimator.model import SVBRDFEstimator
from materials.capture_domain import crop_geometry
from materials.types import Material
from materials.windows import DEFAULT_OVERLAP, TileBlend, plane_windows

__all__ = ["tiled_estimate", "DEFAULT_TILE", "DEFAULT_BATCH"]

#: The estimator's training crop side (``estimator.train``'s ``--size`` default).
DEFAULT_TILE = 64
#: Windows per forward pass: 16 crops of 8 views at 64 px hold ~0.3 GB of activations.
DEFAULT_BATCH = 16


@torch.no_grad()
def tiled_estimate(
    model: SVBRDFEstimator,
    images: torch.Tensor,
    light_pos: torch.Tensor,
    camera_pos: torch.Tensor,
    *,
    tile: int = DEFAULT_TILE,
    overlap: int = DEFAULT_OVERLAP,
    plane_size: float | None = None,
    batch: int = DEFAULT_BATCH,
) -> Material:
    """Estimate the maps of ``images [B, V, 3, S, S]`` window by window (module docstring).

    Args:
        model: the estimator (its ``config.plane_size`` is the frame each window is put in).
        images, light_pos, camera_pos: the views and their positions ``[B, V, 3]``.
        tile, overlap: window side (a multiple of the model's downsample factor) and the
            least overlap of neighbours, pixels. S == tile: one forward pass.
        plane_size: side of the photographed plane in the positions' units (None: the
            model's).
        batch: windows per forward pass.
    Returns:
        The blended maps, a batched ``Material`` ``[B, C, S, S]``.
    """
    b, v, _, h, w = images.shape
    if h != w:
        raise ValueError(f"tiled estimation needs square views, got {h} x {w}")
    if tile % model.downsample_factor:
        raise ValueError(f"tile {tile} is not a multiple of the estimator's {model.downsample_factor}")
    if batch < 1:
        raise ValueError(f"batch must be at least 1, got {batch}")
    model_plane = model.config.plane_size
    plane = model_plane if plane_size is None else plane_size
    windows = plane_windows(h, tile, overlap, plane)
    blended = []
    for i in range(b):
        blend = TileBlend(h, tile, overlap, dtype=images.dtype)
        for start in range(0, len(windows), batch):
            chunk = windows[start : start + batch]
            crops, lights, cameras = [], [], []
            for win in chunk:
                crops.append(images[i, :, :, win.top : win.top + tile, win.left : win.left + tile])
                light, camera, _ = crop_geometry(
                    light_pos[i], camera_pos[i], win.center, win.side, plane_size=model_plane
                )
                lights.append(light)
                cameras.append(camera)
            maps = model(torch.stack(crops), torch.stack(lights), torch.stack(cameras)).stacked()
            for win, m in zip(chunk, maps):
                blend.add(win, m)
        blended.append(blend.result())
    material = Material.from_stacked(torch.stack(blended))
    # The blend of unit normals is shorter than 1 inside the overlaps.
    return Material(material.diffuse, F.normalize(material.normal, dim=1), material.roughness, material.specular)
