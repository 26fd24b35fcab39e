"""The estimator as a relighting baseline (registry name ``"estimator"``): estimate the
SVBRDF maps from the flash photo alone, then render them under the target lights.

This is the Table-1 row "the estimator's 1-input maps re-rendered under the target
light" (issue 4). It lives in ``matcap`` because it joins two sibling packages,
``estimator`` and ``relight``, which must not import each other; ``register()`` adds it
to ``relight.interface``'s open registry.
"""

from __future__ import annotations

import os
from pathlib import Path

import torch

import kernels
from estimator.model import SVBRDFEstimator
from matcap.estimate import estimate_material, load_estimator
from materials.types import Capture
from relight.interface import Relighter, register_relighter

__all__ = ["EstimatorRelighter", "load_estimator_relighter", "register"]


class EstimatorRelighter(Relighter):
    """One flash photo -> estimated maps (no refinement) -> renders under the targets.

    Deterministic. The photo is taken as lit from the camera (the relighting contract);
    maps and renders use the ``dgrsise`` preset (``preset``), as the relighting inputs do.
    """

    name = "estimator"
    stochastic = False

    def __init__(self, model: SVBRDFEstimator, preset: str = "dgrsise"):
        self.model = model.eval()
        self.preset = preset

    def _relight(self, photo, light_pos, camera_pos, *, generator=None):
        out, k = [], light_pos.shape[1]
        for b in range(photo.shape[0]):
            cam = camera_pos[b : b + 1].float()
            capture = Capture(photo[b : b + 1].float(), cam, cam, preset=self.preset)
            material, _ = estimate_material(capture, self.model, progress=False)
            with torch.no_grad():
                rendered = kernels.render(
                    *(t[None] for t in material.map_tensors()),
                    light_pos[b : b + 1].float(),
                    cam[:, None].expand(1, k, 3).contiguous(),
                    preset=self.preset,
                )
            out.append(rendered[0])
        return torch.stack(out).to(photo.device, photo.dtype)


def load_estimator_relighter(checkpoint: str | os.PathLike | None = None) -> EstimatorRelighter:
    """From an estimator folder (``save_pretrained`` layout); None: the shipped weights."""
    return EstimatorRelighter(load_estimator(Path(checkpoint) if checkpoint is not None else None))


def register() -> None:
    """Make ``get_relighter("estimator")`` available (idempotent)."""
    register_relighter("estimator", load_estimator_relighter)
