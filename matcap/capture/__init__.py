"""``CapturePipeline``: one flash photo -> relit views -> SVBRDF maps at the photo's resolution.

Inference glue in the diffusers style: the components (a relighter, an estimator) are
registered in ``__init__``, the settings are a typed ``CaptureConfig``, ``__call__``
reads as numbered steps and returns a ``CaptureOutput`` (``CaptureOutput.save`` writes
the folder). The steps:

1. check the inputs (photo size, settings, components);
2. prepare the photo (``materials.frame.prepare_photo``): pad it to a square whose side is
   a multiple of the working resolution (so the area downsampling below is exact), and
   area-downsample it to the working resolution of the networks (64: the diffusion
   relighter's only size, and the estimator's training size); the ``Frame`` records how;
3. relight the working photo to K lights (default the 7 ``EVAL_LIGHTS``); with
   ``samples >= 2`` the per-pixel standard deviation across samples is the confidence
   map (high = uncertain; README "Relighting": it correlates with the error);
4. one ``Capture``: the working photo as view 0, the relit views after it;
5. the estimator on the 1 + K views at the estimate size; the maps named in
   ``CaptureConfig.photo_maps`` (default diffuse and normal) come from a second pass on
   the photo alone: relit views smaller than the estimate size would blur the detail
   maps, while they do tell roughness and specular (``results/capture_views``);
6. refinement at the photo's full resolution (``refine_full_resolution``): per-pixel maps,
   initialised from the estimator's maps upsampled, fitted through the Warp renderer to
   the full-resolution photo and to the relit views compared at *their* resolution
   (render at full resolution, area-downsample, then the loss), a weight per view (the
   relit views' default weight is 0.03 against the photo's 1: fitting them harder cost
   re-render accuracy), routed to the maps of ``relit_maps`` (default all but the
   normals, which they tilted on real photos, ``results/capture_relit_maps``), the
   padded pixels masked out, and optionally the relit views' pixels over the photo's
   flash highlight (``relit_highlight``, off by default); Adam per pixel, except for the normals, whose step size is
   shared by their pixels (``shared_step_maps``, ``estimator.optim.MapAdam``: per-pixel
   steps creased them through the flash point, ``results/capture_steps``);
7. the maps mapped back to the photo's pixel grid (``Frame.material_to_photo``);
8. re-renders under the flash and the 7 evaluation lights, and a preview sheet.

Scene convention for a phone photo (the pipeline owns it; README "Capture a material").
The material plane is the ``dgrsise`` plane (side 4, z = 0); the prepared square spans it,
so the photo covers a centred rectangle of it (``Frame.photo_plane_size``). The camera,
and the flash next to its lens, sit above the photo's centre at the height where the
photo's long side spans the field of view (``materials.camera``): 45 degrees by default
(the field's convention, Deschaintre et al. 2018), the EXIF 35 mm focal length when the
file has one (``fov_from_exif``), ``CaptureConfig.fov`` when given; ``CaptureConfig.camera``
sets the position outright. A square photo at 45 degrees puts the camera at
(0, 0, 4.83). By default (``CaptureConfig.flash_point="auto"``) the camera moves over
the flash highlight located in the photo (``flash.locate_flash``: photos are rarely taken
exactly over the centre; the centre is kept when there is no clear highlight);
``flash_point="centre"`` keeps the convention as it is. The relit views' lights are positions in the same units.

Falloff. A real flash's light falls off with 1 / d^2 across the photo; the relighter and
the estimator were trained without falloff (SPEC section 2, preset ``dgrsise``).
``falloff="inverse-square"`` converts at the boundary: the photo is divided by the flash's
falloff factor ``h^2 / |p_flash - x|^2`` (1 under the camera, h its height) before
relighting and estimation (the no-falloff convention); the relit views are multiplied by
their target light's factor ``h^2 / |p_k - x|^2``; and the refinement renders with 1 / d^2
at intensity ``pi h^2``, which equals the no-falloff convention's radiance under the
camera. ``falloff="none"`` takes the photo as it is (the models' convention).
``DEFAULT_FALLOFF`` says which one is the default and the measurement behind it.

Package layout, one job a module, each importing only from those before it in this list:
``config`` the constants and ``CaptureConfig``; ``flash`` locating the point under the
flash in a photo; ``scene`` ``CaptureScene``, the falloff
factor and the area downsampling; ``photo`` photos without a file (``photo_from_tensor``,
``builtin_photo``); ``relighting`` step 3; ``refine`` step 6; ``output``
``CaptureOutput``, its folder and the preview sheet; ``provenance`` the record's parts;
``pipeline`` ``CapturePipeline``. Everything public is imported from here.

Example:
    >>> pipe = CapturePipeline(relighter=get_relighter("diffusion"), estimator=load_estimator())  # doctest: +SKIP
    >>> out = pipe(read_photo("wood.jpg"))  # doctest: +SKIP
    >>> out.material.diffuse.shape  # the photo's (H, W)  # doctest: +SKIP
    >>> out.save("out/wood")  # doctest: +SKIP
"""

from __future__ import annotations

# Besides ``__all__``, the private helpers (the ``name as name`` imports) stay importable
# from here as from the single module this package replaced: tests import
# ``_masked_log_l1``, docs name ``_Stages``.
from matcap.capture.config import (
    BUILTIN_SEED,
    BUILTIN_SIZE,
    DEFAULT_FALLOFF,
    DEFAULT_FLASH_POINT,
    DEFAULT_FLATNESS,
    DEFAULT_PHOTO_MAPS,
    DEFAULT_RADIAL,
    DEFAULT_RADIAL_MAPS,
    DEFAULT_REFINE_STEPS,
    DEFAULT_RELIGHT_STEPS,
    DEFAULT_RELIGHTER,
    DEFAULT_RELIT_HIGHLIGHT,
    DEFAULT_RELIT_MAPS,
    DEFAULT_RELIT_WEIGHT,
    DEFAULT_SHARED_STEP_MAPS,
    FALLOFFS,
    FLASH_POINTS,
    MAP_NAMES,
    MAX_SIDE,
    PROVENANCE_JSON,
    REFINE_LR,
    RENDER_LIGHTS,
    WORKING_SIZE,
    CaptureConfig,
)
from matcap.capture.flash import FlashPoint, locate_flash
from matcap.capture.output import _SHEET_TILE as _SHEET_TILE
from matcap.capture.output import CaptureOutput
from matcap.capture.output import _preview_sheet as _preview_sheet
from matcap.capture.output import _tiles as _tiles
from matcap.capture.photo import builtin_photo, photo_from_tensor
from matcap.capture.pipeline import CapturePipeline
from matcap.capture.pipeline import _Stages as _Stages
from matcap.capture.pipeline import _upsample as _upsample
from matcap.capture.provenance import _component_record as _component_record
from matcap.capture.provenance import _package_versions as _package_versions
from matcap.capture.provenance import _sha256 as _sha256
from matcap.capture.refine import _VIEW_CHANNELS as _VIEW_CHANNELS
from matcap.capture.refine import CHUNK_BYTES as CHUNK_BYTES
from matcap.capture.refine import CLIP_TOL as CLIP_TOL
from matcap.capture.refine import _from_parameters as _from_parameters
from matcap.capture.refine import _masked_log_l1 as _masked_log_l1
from matcap.capture.refine import _Target as _Target
from matcap.capture.refine import _to_parameters as _to_parameters
from matcap.capture.refine import _view_chunks as _view_chunks
from matcap.capture.refine import refine_full_resolution, refine_memory_bytes
from matcap.capture.relighting import native_resolution, relight_views
from matcap.capture.scene import CaptureScene, area_downsample, capture_scene, falloff_factor, flash_disc

__all__ = [
    "CapturePipeline",
    "CaptureConfig",
    "CaptureOutput",
    "CaptureScene",
    "refine_full_resolution",
    "falloff_factor",
    "flash_disc",
    "area_downsample",
    "refine_memory_bytes",
    "builtin_photo",
    "relight_views",
    "capture_scene",
    "native_resolution",
    "photo_from_tensor",
    "FALLOFFS",
    "DEFAULT_FALLOFF",
    "FLASH_POINTS",
    "DEFAULT_FLASH_POINT",
    "FlashPoint",
    "locate_flash",
    "DEFAULT_RELIGHTER",
    "DEFAULT_RELIGHT_STEPS",
    "DEFAULT_FLATNESS",
    "DEFAULT_RELIT_WEIGHT",
    "DEFAULT_RELIT_MAPS",
    "DEFAULT_RELIT_HIGHLIGHT",
    "DEFAULT_RADIAL",
    "DEFAULT_RADIAL_MAPS",
    "DEFAULT_PHOTO_MAPS",
    "DEFAULT_SHARED_STEP_MAPS",
    "MAP_NAMES",
    "DEFAULT_REFINE_STEPS",
    "REFINE_LR",
    "WORKING_SIZE",
    "MAX_SIDE",
    "RENDER_LIGHTS",
    "PROVENANCE_JSON",
    "BUILTIN_SEED",
    "BUILTIN_SIZE",
]
