"""The diffusion model behind the common ``Relighter`` interface (registry name
``"diffusion"``), so evaluations and the command line can swap it for the baselines."""

from __future__ import annotations

import os
from pathlib import Path

import torch
from diffusers import DDIMScheduler

from kernels.presets import get_preset
from relight.detail import detail_relight
from relight.diffusion.model import CONFIG_NAME, RelightDiffusion
from relight.diffusion.pipeline import DEFAULT_STEPS, RelightPipeline
from relight.interface import Relighter
from relight.tiling import DEFAULT_OVERLAP, tiled_relight
from weights import weights_dir

__all__ = ["DiffusionRelighter", "load_diffusion_relighter"]


class DiffusionRelighter(Relighter):
    """Relights with ``RelightPipeline``; stochastic (seed it with ``generator``).

    A photo of the model's resolution is relit whole. A larger square one (any side >=
    the resolution), by ``large``:

    - ``"global"`` (default): the whole plane at the model's resolution, the photo's detail
      carried by the Lambertian re-shading at full size (``relight.detail``); at 256 px on
      8 held-out materials 31.3 dB against 27.0 in tiles (``results/relight_detail/``);
    - ``"tiles"``: tile by tile, each tile a window of the plane in its own frame, blended
      across ``overlap`` pixels (``relight.tiling``). The model sees windows of the plane
      at the scale it was trained on only if its training included such crops (the
      capture-domain runs: ``CaptureDomain.p_crop``).
    """

    name = "diffusion"
    stochastic = True

    def __init__(
        self,
        model: RelightDiffusion,
        steps: int = DEFAULT_STEPS,
        num_samples: int = 1,
        scheduler: DDIMScheduler | None = None,
        overlap: int = DEFAULT_OVERLAP,
        large: str = "global",
    ):
        if large not in self.large_modes:
            raise ValueError(f"large must be one of {self.large_modes}, got {large!r}")
        self.pipeline = RelightPipeline(model, scheduler)
        self.steps = steps
        self.num_samples = num_samples
        self.overlap = overlap
        self.large = large

    #: ``large`` values this relighter accepts (``relight.detail.LARGE_MODES``).
    large_modes = ("global", "tiles")

    @property
    def resolution(self) -> int:
        """The model's native tile side in pixels."""
        return int(self.pipeline.model.config.resolution)

    def _relight(self, photo, light_pos, camera_pos, *, generator=None):
        res = self.resolution
        h, w = photo.shape[-2:]
        if h != w or h < res:
            raise ValueError(
                f"photo must be square with a side of at least the model's resolution {res} "
                f"(larger ones are relit in tiles), got {h} x {w}"
            )

        def one(image: torch.Tensor, light: torch.Tensor, camera: torch.Tensor) -> torch.Tensor:
            return self.pipeline(
                image,
                light,
                camera,
                num_inference_steps=self.steps,
                num_samples=self.num_samples,
                generator=generator,
                progress=False,
            )

        plane = float(self.pipeline.model.config.plane_size)
        if h > res and self.large == "global":
            # The re-shading's preset is the one the model's residual base uses.
            preset = get_preset("dgrsise").with_overrides(plane_size=plane)

            def native(small: torch.Tensor, light: torch.Tensor, camera: torch.Tensor) -> torch.Tensor:
                return torch.stack([one(small[b], light[b], camera[b]) for b in range(small.shape[0])])

            out = detail_relight(native, photo.float(), light_pos.float(), camera_pos.float(), size=res, preset=preset)
            return out.to(photo.device, photo.dtype)
        outs = []
        for b in range(photo.shape[0]):
            image, light, camera = photo[b].float(), light_pos[b].float(), camera_pos[b].float()
            if h == res:
                outs.append(one(image, light, camera))
            else:
                outs.append(tiled_relight(one, image, light, camera, tile=res, overlap=self.overlap, plane_size=plane))
        return torch.stack(outs).to(photo.device, photo.dtype)


def load_diffusion_relighter(checkpoint: str | os.PathLike | None = None) -> DiffusionRelighter:
    """From a ``save_pretrained`` folder, a training checkpoint (``.../latest``, the model in
    ``model/``), or (None) the shipped tiny model, ``weights_dir("diffusion")``; the sampler
    from the folder's ``scheduler_config.json`` when it has one (``RelightPipeline.from_pretrained``)."""
    folder = Path(checkpoint) if checkpoint is not None else weights_dir("diffusion")
    if not (folder / CONFIG_NAME).is_file():
        # A training checkpoint folder holds the model under model/.
        if not (folder / "model" / CONFIG_NAME).is_file():
            raise FileNotFoundError(f"{folder}: not a relighting checkpoint (no {CONFIG_NAME} there or in model/)")
        folder = folder / "model"
    pipeline = RelightPipeline.from_pretrained(folder)
    return DiffusionRelighter(pipeline.model, scheduler=pipeline.scheduler)
