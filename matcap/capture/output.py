"""What one capture produced: ``CaptureOutput``, the folder its ``save`` writes, and the
preview sheet (``_preview_sheet``: photo and relit views, maps, re-renders).
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

import torch
import torch.nn.functional as F

from kernels.tonemap import srgb_encode, tonemap
from matcap.capture.config import PROVENANCE_JSON
from matcap.capture.scene import CaptureScene
from materials.frame import Frame
from materials.io.encoding import encode_normal
from materials.io.photo import Photo
from materials.types import Capture, Material

# Side of one tile of the preview sheet, pixels.
_SHEET_TILE = 128


@dataclass
class CaptureOutput:
    """What one capture produced (tensors on the CPU, float32, linear unless stated).

    Attributes:
        material: ``Material`` ``[C, H, W]`` on the photo's pixel grid (refined).
        estimate: the estimator's maps ``[C, e, e]`` at the estimate size (``CaptureConfig.estimate_side``).
        relit: ``[K, 3, r, r]`` relit views at the relit size, the relighter's output (no falloff).
        confidence: ``[1, H, W]`` std across relighting samples on the photo's grid
            (high = uncertain), or None (fewer than 2 samples, or K = 0).
        renders: ``[1 + 7, 3, H, W]`` the refined maps re-rendered under the flash and the
            ``RENDER_LIGHTS``, on the photo's grid (in ``scene.render_kwargs``).
        capture: the step-4 ``Capture`` (estimate size, no-falloff convention): what
            the estimator saw.
        photo: the input ``Photo``; frame: its ``Frame``; scene: its ``CaptureScene``.
        preview: ``[3, h, w]`` display values: photo and relit views, maps, re-renders.
        refine_history: the refinement loss at every step.
        provenance: JSON-serialisable record (versions, weights, settings, timings, ...).
    """

    material: Material
    estimate: Material
    relit: torch.Tensor
    confidence: torch.Tensor | None
    renders: torch.Tensor
    capture: Capture
    photo: Photo
    frame: Frame
    scene: CaptureScene
    preview: torch.Tensor
    refine_history: list[float]
    provenance: dict

    def save(
        self,
        folder: str | os.PathLike,
        *,
        overwrite: bool = False,
        normal_convention: str = "opengl",
        tileable: bool = False,
    ) -> Path:
        """Write the capture's folder, atomically (nothing appears unless all of it does)::

        provenance.json     the record (marker of this folder)
        preview.png         photo + relit views / maps / re-renders (tone-mapped, sRGB maps)
        material/           ``export_material``: EXR + PNG maps, metallic-roughness, material.glb
                            (normal files in ``normal_convention``: "opengl" or "directx")
        material_tileable/  with ``tileable``: the same export of ``materials.tiling.make_tileable``
                            of the maps (offset-and-blend; its ``export.json`` records each
                            map's seam error before and after)
        renders/view_KK.exr/.png   re-renders on the photo's grid: 00 the flash, 01.. RENDER_LIGHTS
        relit/relit_KK.exr/.png    relit views at the relit size (no falloff)
        confidence.exr/.png        std across relighting samples (only with samples >= 2)
        capture/            our capture format (capture.json + 0.png ... K.png): the
                            estimator's input, so ``relight estimate capture/`` reruns it
        """
        from matcap.outputs import write_image_pair
        from materials.io import export_material, write_capture, write_exr, write_png
        from materials.io.atomic import atomic_folder
        from materials.io.encoding import chw_to_hwc
        from materials.tiling import make_tileable, seam_error

        folder = Path(folder)
        with atomic_folder(folder, overwrite=overwrite, marker=PROVENANCE_JSON) as tmp:
            made_by = {"made_by": "relight capture"}
            export_material(tmp / "material", self.material, normal_convention=normal_convention, provenance=made_by)
            if tileable:
                tiled = make_tileable(self.material)
                seams = {
                    name: {"before": round(seam_error(x), 3), "after": round(seam_error(tiled.maps()[name]), 3)}
                    for name, x in self.material.maps().items()
                }
                notes = {**made_by, "tileable": "materials.tiling.make_tileable", "seam_error": seams}
                export_material(tmp / "material_tileable", tiled, normal_convention=normal_convention, provenance=notes)
            (tmp / "renders").mkdir()
            for k, image in enumerate(self.renders):
                write_image_pair(tmp / "renders", f"view_{k:02d}", image)
            if len(self.relit):
                (tmp / "relit").mkdir()
                for k, image in enumerate(self.relit):
                    write_image_pair(tmp / "relit", f"relit_{k:02d}", image)
            if self.confidence is not None:
                write_exr(tmp / "confidence.exr", chw_to_hwc(self.confidence))
                peak = float(self.confidence.max())
                write_png(tmp / "confidence.png", chw_to_hwc(self.confidence / peak if peak > 0 else self.confidence))
            write_capture(tmp / "capture", self.capture)
            write_png(tmp / "preview.png", chw_to_hwc(self.preview))
            (tmp / PROVENANCE_JSON).write_text(json.dumps(self.provenance, indent=2) + "\n", encoding="utf-8")
        return folder


def _tiles(images: torch.Tensor, side: int) -> torch.Tensor:
    """``[N, C, h, w]`` display values (C = 1 or 3) -> ``[N, 3, side, side]``."""
    images = images.float()
    if images.shape[1] == 1:
        images = images.expand(-1, 3, -1, -1)
    if images.shape[-1] != side:
        images = F.interpolate(images, size=(side, side), mode="bilinear", antialias=True, align_corners=False)
    return images.clamp(0, 1)


def _preview_sheet(image, relit, refined: Material, estimate: Material, std, renders) -> torch.Tensor:
    """Rows, each tile labelled: photo + relit views; refined maps (diffuse and specular
    sRGB, normal (n + 1) / 2, roughness linear), the estimator's diffuse, the confidence;
    re-renders (view 0 under the flash, then ``RENDER_LIGHTS``). Empty slots are
    ``EMPTY_TILE_GREY``."""
    from matcap.outputs import EMPTY_TILE_GREY, contact_sheet, label_tiles

    t = _SHEET_TILE
    row1 = torch.cat([_tiles(tonemap(image[None]), t), *([_tiles(tonemap(relit), t)] if len(relit) else [])])
    labels1 = ["photo", *(f"relit {k + 1}" for k in range(len(relit)))]
    maps = [
        srgb_encode(refined.diffuse),
        encode_normal(refined.normal),
        refined.roughness,
        srgb_encode(refined.specular),
        srgb_encode(estimate.diffuse),
    ]
    labels2 = ["diffuse", "normal (OpenGL)", "roughness", "specular", "estimator diffuse"]
    if std is not None:
        spread = std.mean(dim=(0, 1))[None, None]
        maps.append(spread / spread.max().clamp_min(1e-8))
        labels2.append("confidence (std)")
    row2 = torch.cat([_tiles(m, t) for m in maps])
    row3 = _tiles(tonemap(renders), t)
    labels3 = ["render: flash", *(f"render: light {k}" for k in range(1, len(renders)))]
    columns = max(len(row1), len(row2), len(row3))

    def pad(row, labels):
        row = label_tiles(row, labels)
        return torch.cat([row, row.new_full((columns - len(row), 3, t, t), EMPTY_TILE_GREY)])

    rows = [pad(row1, labels1), pad(row2, labels2), pad(row3, labels3)]
    return contact_sheet(torch.cat(rows), columns=columns)
