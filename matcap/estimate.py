"""SVBRDF estimation from a capture held in memory: the function behind
``relight estimate``, also fed directly by the relighting output later.

Positions are converted to the estimator's scene units (the ``dgrsise`` plane of side
4) by scaling with 4 / plane_size; refinement renders in the capture's own preset, so
the fit is against the photos' real lighting (falloff and intensity included).
"""

from __future__ import annotations

from pathlib import Path

import torch
import torch.nn.functional as F

from estimator.model import SVBRDFEstimator
from estimator.refine import refine
from kernels.presets import get_preset
from materials.types import Capture, Material
from weights import weights_dir

__all__ = ["estimate_material", "load_estimator"]


def load_estimator(path: str | Path | None = None) -> SVBRDFEstimator:
    """Load an estimator folder (``save_pretrained`` layout); None: the shipped one,
    ``weights.weights_dir("estimator")``."""
    folder = Path(path) if path is not None else weights_dir("estimator")
    if not (folder / "config.json").is_file():
        raise FileNotFoundError(f"{folder}: no estimator checkpoint (config.json missing)")
    return SVBRDFEstimator.from_pretrained(folder).eval()


def _to_multiple(images: torch.Tensor, multiple: int) -> torch.Tensor:
    h, w = images.shape[-2:]
    th, tw = max(multiple, round(h / multiple) * multiple), max(multiple, round(w / multiple) * multiple)
    if (th, tw) == (h, w):
        return images
    return F.interpolate(images, size=(th, tw), mode="bilinear", antialias=True, align_corners=False)


def _resize_material(m: Material, size: tuple[int, int]) -> Material:
    if m.shape == size:
        return m
    maps = {
        k: F.interpolate(v, size=size, mode="bilinear", antialias=True, align_corners=False)
        for k, v in m.maps().items()
    }
    maps["normal"] = F.normalize(maps["normal"], dim=1)
    return Material(**maps)


def estimate_material(
    capture: Capture,
    model: SVBRDFEstimator,
    *,
    refine_steps: int = 0,
    progress: bool = True,
) -> tuple[Material, list[float]]:
    """Estimate the maps of one captured material.

    Args:
        capture: V linear photos ``[V, 3, H, W]`` with their positions.
        model: a trained estimator.
        refine_steps: test-time refinement steps through the Warp renderer (0: none).
    Returns:
        (unbatched ``Material`` at the capture's resolution, refinement loss history).
    """
    preset = get_preset(capture.preset)
    plane = capture.plane_size or preset.plane_size
    scale = model.config.plane_size / plane
    images = _to_multiple(capture.images, model.downsample_factor)[None]
    light_pos, camera_pos = capture.light_pos[None] * scale, capture.camera_pos[None] * scale
    history: list[float] = []
    if refine_steps > 0:
        # Refinement renders in model units with the capture's intensity and falloff;
        # the 1/d^2 falloff is scale-dependent, so the intensity is rescaled to match.
        intensity = capture.intensity or preset.intensity
        if preset.inverse_square:
            intensity = tuple(v * scale * scale for v in intensity)
        result = refine(
            model,
            images,
            light_pos,
            camera_pos,
            steps=refine_steps,
            progress=progress,
            preset=preset,
            plane_size=model.config.plane_size,
            intensity=intensity,
        )
        material, history = result.material, result.history
    else:
        with torch.no_grad():
            material = model(images, light_pos, camera_pos)
    return _resize_material(material, capture.shape)[0], history
