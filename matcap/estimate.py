"""SVBRDF estimation from a capture held in memory: the function behind
``relight estimate``, also fed directly by the relighting output later.

The estimator sees the capture in the models' units (``materials.units.to_model_units``:
positions scaled to the ``dgrsise`` plane of side 4, each view's radiance converted to a
light of intensity pi without falloff, as in training), and so does the refinement, which
renders in that convention.
"""

from __future__ import annotations

from pathlib import Path

import torch
import torch.nn.functional as F

from estimator.model import SVBRDFEstimator
from estimator.refine import refine
from materials.types import Capture, Material
from materials.units import MODEL_PLANE_SIZE, to_model_units
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
    if model.config.plane_size != MODEL_PLANE_SIZE:
        raise ValueError(
            f"the estimator's plane is {model.config.plane_size}; the models' units have {MODEL_PLANE_SIZE}"
        )
    model_capture = to_model_units(capture)
    images = _to_multiple(model_capture.images, model.downsample_factor)[None]
    light_pos, camera_pos = model_capture.light_pos[None], model_capture.camera_pos[None]
    history: list[float] = []
    if refine_steps > 0:
        # In model units the photos are renders of the dgrsise convention (no falloff,
        # intensity pi), so the fit renders that way; the log-L1 loss is nearly
        # invariant to the per-pixel gain, so this is the fit in the capture's own lighting.
        result = refine(
            model,
            images,
            light_pos,
            camera_pos,
            steps=refine_steps,
            progress=progress,
            preset="dgrsise",
            plane_size=model.config.plane_size,
        )
        material, history = result.material, result.history
    else:
        with torch.no_grad():
            material = model(images, light_pos, camera_pos)
    return _resize_material(material, capture.shape)[0], history
