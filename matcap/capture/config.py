"""Settings of a capture: the module constants (defaults, sizes, file names) and the typed
``CaptureConfig`` that checks them.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

from materials.lights import EVAL_LIGHTS
from materials.types import MAP_CHANNELS

#: How the flash's light falls off over the plane (package docstring).
FALLOFFS = ("none", "inverse-square")
#: Default falloff model of a photo: a phone flash is a point light next to the lens, so
#: a photo has the 1/d^2 falloff. Measured on the 5 real-texture materials rendered under
#: the flash (README "Capture a material", table "falloff"; maps re-rendered in the
#: photo's true lighting under 16 held-out lights): for photos with the falloff,
#: correcting it gives 30.21 dB against 29.04 without (diffuse MSE 0.0024 against
#: 0.0038); applied to photos without falloff it costs 1.8 dB (27.14 against 28.90).
DEFAULT_FALLOFF = "inverse-square"
#: The relighter used by default and its sampling steps: one DDIM step of the diffusion
#: model is its best-scoring setting (README "Relighting": 28.12 dB against 25.89 at 10).
DEFAULT_RELIGHTER = "diffusion"
DEFAULT_RELIGHT_STEPS = 1
#: Working resolution of the networks, pixels: the diffusion relighter's only size and
#: the size the shipped estimator was trained at.
WORKING_SIZE = 64
#: Largest photo side refined at full resolution. At 2048 x 2048 with 8 views the
#: refinement's buffers are estimated at 1.7 GB (``refine_memory_bytes``); the whole
#: process peaked at 3.3 GB RSS and took 485 s on the project's 2-core CPU
#: (``benchmarks/bench_capture.py --sizes 2048``, ``benchmarks/results/capture_2048.json``).
#: A larger photo must be downscaled first (``CaptureConfig.max_side`` does it).
MAX_SIDE = 2048
#: Refinement steps: 50 / 100 / 200 gave 20.24 / 20.39 / 20.24 dB on 4 glossy procedural
#: materials (README "Capture a material", table "steps"); 100 keeps 1024 px under the
#: 120 s target.
DEFAULT_REFINE_STEPS = 100
#: The estimator's input side: the whole image at 256 px re-renders 1.6-1.9 dB better
#: than at 64 px upsampled (8 held-out materials at 256 px, 1 and 8 views, no refinement;
#: ``results/estimator_resolution``), in 1 s for 8 views; 512 px adds nothing (-0.2 dB)
#: at 8x the time and ~2 GB.
DEFAULT_ESTIMATE_SIZE = 256
#: The relit views' side: the diffusion model relights the whole plane at 64 px and the
#: photo's detail is carried to 256 px (``relight.detail``); against 64 px relit views
#: the 13 held-out materials re-render +0.40 / +0.53 / +0.06 dB better (procedural /
#: INRIA / textures, ``results/relight_detail/``) at the same relighting cost.
DEFAULT_RELIT_SIZE = 256
#: Weight of the refinement's flat-sample prior (``matcap.capture.priors.tilt_energy``):
#: the low-frequency tilt of the normal map, which the refinement otherwise uses to
#: explain a flash falloff that does not match the model's (four tilted quadrants around
#: the flash on real photos). Measured (``results/capture_flatness/``; 4 procedural, 4
#: INRIA-format, 5 real-texture materials at 256 px): 0 -> 3 moves the default capture's
#: re-render PSNR by -0.13 / +0.12 / +0.01 dB and the photo alone's by +1.20 / +0.91 /
#: +0.35 dB; on the 10 real photos the normal maps' low-frequency tilt falls from 4.5 to
#: 1.6 degrees (7 relit views). 30 left creases where the quadrants met.
DEFAULT_FLATNESS = 3.0
#: Weight of the refinement's flash-independence prior
#: (``matcap.capture.priors.flash_independence``): the radial profile of the maps around
#: the point under the flash. Measured (``results/capture_radial/``): on 9 real photos at
#: 256 px, 0 -> 1 cuts the roughness map's flash-centred profile (log-RMS over rings)
#: from 0.071 to 0.018 and the specular's from 0.081 to 0.006 (7 relit views), the
#: normals' low-frequency tilt from 1.85 to 1.50 degrees; on 4 procedural, 4 INRIA-format
#: and 4 real-texture materials the re-render PSNR moves by at most +0.3 dB (photo alone)
#: and -0.03 dB (7 relit views). 3 flattens the profiles further (0.008 / 0.004, tilt
#: 1.20 degrees) and moves the held-out PSNR by -0.09 to +0.53 dB; 1 already removes
#: most of the profiles.
DEFAULT_RADIAL = 1.0
#: The maps the flash-independence prior looks at. Not the diffuse: a real texture has its
#: own radial profile around any point (cobblestones, lgd/042), and pushing the diffuse's
#: flat made the roughness compensate with a ring (r ~ 40 px) and specular speckles.
DEFAULT_RADIAL_MAPS = ("normal", "roughness", "specular")
#: Which views the refinement's fitted radial gain multiplies (``matcap.capture.vignetting``):
#: ``VIGNETTING_VIEWS``; off until measured.
VIGNETTING_VIEWS = ("off", "photo", "all")
DEFAULT_VIGNETTING = "off"
#: The maps' names, in ``Material.map_tensors`` order.
MAP_NAMES = tuple(MAP_CHANNELS)
#: How the relit views are used (``results/capture_views``: 13 held-out materials, 4
#: procedural, 4 INRIA-format, 5 real-texture, at 256 px; re-render PSNR under 128 novel
#: lights, mean over materials; the photo alone 30.60 dB). Until 2026-12-04 the relit
#: views went to the estimator with the photo for every map and into the refinement at
#: weight 0.1: 29.94 dB, below the photo alone. The relit views are 64 px upsampled to
#: the estimate size, so the estimator's diffuse and normal maps from them are blurrier
#: than from the photo: taking those two from the photo alone (``DEFAULT_PHOTO_MAPS``) gave
#: 30.78; with the relit views' refinement weight lowered to 0.03 (``DEFAULT_RELIT_WEIGHT``)
#: 31.06, and at 0 (the relit views inform the estimator's roughness and specular only)
#: 31.02. On 21 materials (``results/capture_tables``) 0.03 against 0 gave +0.04 / +0.21
#: / +0.03 dB with 8 inputs and -0.14 / +0.12 / +0.02 with 4 (noise-level either way);
#: 0.03 was kept because on real photos the relit views' small weight held back the
#: refinement's creases in the normal map along the axes through the flash point (their
#: cause, per-pixel Adam steps, has since been removed: ``DEFAULT_SHARED_STEP_MAPS``,
#: 31.06 -> 31.44 dB on the 13 materials, ``results/capture_steps``). Routing the relit views'
#: refinement loss to roughness and specular only (``relit_maps``, an option)
#: gave 30.64 with the photo's diffuse and normal, 29.47 without.
DEFAULT_PHOTO_MAPS: tuple[str, ...] = ("diffuse", "normal")
DEFAULT_RELIT_WEIGHT = 0.03
#: Since 2026-12-07 the relit views' refinement loss leaves the normals alone
#: (``results/capture_relit_maps/``): on the real photos it had tilted them into four
#: quadrants around the flash (an X on lgd/028), and without it the normals' low-frequency
#: tilt falls from 1.36 to 1.16 degrees (8 of 10 photos lower) and the crease through the
#: flash from 0.38 to 0.31; on the 13 held-out materials the re-render PSNR moves by
#: -0.31 / +0.45 / -0.09 dB (procedural / INRIA / textures; mean +0.01) and the normal MSE
#: rises on the procedural set and the textures (0.0109 -> 0.0117, 0.0719 -> 0.0736).
DEFAULT_RELIT_MAPS: tuple[str, ...] = ("diffuse", "roughness", "specular")
#: Half-angle, degrees, of the cone under the flash whose disc on the plane (and the
#: photo's clipped pixels) the relit views' refinement loss leaves out
#: (``matcap.capture.scene.flash_disc``): where the photo had its flash highlight, the
#: relighters leave a darker disc (README "Relighting"), which pulled the refined diffuse
#: dark there. Measured (``results/capture_relit_highlight/``; the 13 held-out materials
#: at 256 px, 7 relit views, against no mask): a disc of 5.9 degrees (0.5 plane units at
#: the default camera, the evaluation's highlight region) with the clipped pixels cut the
#: diffuse MSE inside the highlight from 0.00162 / 0.0202 / 0.00212 to 0.00133 / 0.0192 /
#: 0.00211 (procedural / INRIA / textures; the photo alone: 0.00187 / 0.0194 / 0.00223)
#: and moved the re-render PSNR by +0.02 / 0.00 / 0.00 dB; 11.7 degrees did about the
#: same (0.00134 / 0.0192 / 0.00212, -0.00 / -0.01 / -0.01 dB); the disc without the
#: clipped pixels left the procedural set's at 0.00164. 6 degrees reproduced 5.9.
#: Off by default all the same: on the real photos (``results/capture_real_photos/``) the
#: relit views had kept the diffuse under the flash bright, and without them there the
#: diffuse maps of lgd/057 and IMG_6970 got a dark disc with the mask's sharp edge (the
#: diffuse disc/ring ratio 0.92 -> 0.71 and 0.97 -> 0.81; mean |ratio - 1| over the 10
#: photos 0.103 -> 0.124), and ground-truth views lose 0.1-0.7 dB (their correct pixels
#: under the flash are dropped too). 6 is the setting measured for held-out photos.
DEFAULT_RELIT_HIGHLIGHT = 0.0
#: Adam rate of the per-pixel logits and normal slopes (``estimator.refine.refine_maps``'s):
#: every pixel's step for the maps with per-pixel steps, the root-mean-square step over
#: the pixels for the maps in ``shared_step_maps``.
REFINE_LR = 1e-2
#: Maps whose refinement step size is shared by all their pixels
#: (``estimator.optim.MapAdam``): each pixel steps in proportion to its gradient. With
#: per-pixel Adam every pixel steps by about the rate in the sign of its gradient, which
#: turned the smooth radial pull of a flash highlight the model cannot reproduce into
#: sharp creases in the normal map along the axes through the flash point (real photos).
DEFAULT_SHARED_STEP_MAPS: tuple[str, ...] = ("normal",)
#: Where the camera and flash are assumed over the photo: above its ``"centre"`` (the
#: field's convention), or above the flash highlight found in it (``"auto"``,
#: ``matcap.capture.flash.locate_flash``; the centre when there is no clear one).
#: Measured (``results/capture_flash_point/``; the 21 held-out materials at 256 px, photo
#: alone / + 7 relit): on photos taken 0.72 plane units off-centre, auto against centre
#: 29.58 / 29.91 dB against 27.96 / 28.25 (procedural), 21.20 / 21.87 against 20.55 /
#: 20.57 (INRIA-format), 29.99 / 30.03 against 29.96 / 29.99 (textures); on centred
#: photos within 0.03 dB on every row of Tables 2 and 4 that was rerun (alone, + 3, + 7
#: relit, + 7 ground truth), the textures unchanged (no point found).
FLASH_POINTS = ("centre", "auto")
DEFAULT_FLASH_POINT = "auto"
#: Lights of the re-renders (after the flash): the 7 evaluation lights.
RENDER_LIGHTS = EVAL_LIGHTS
#: The file that marks a folder written by ``CaptureOutput.save`` (safe to --overwrite).
PROVENANCE_JSON = "provenance.json"
#: The built-in photo: procedural seed (``relight render``'s default material) and size.
BUILTIN_SEED = 3
BUILTIN_SIZE = 256


@dataclass(frozen=True)
class CaptureConfig:
    """Settings of one capture (``CapturePipeline.__call__``).

    Attributes:
        relit: number K of relit views, 0 to 7 (the first K of ``EVAL_LIGHTS``); 0 runs
            the same steps with the photo alone (the baseline).
        steps: sampling steps of a sampling relighter (diffusion); None keeps its own.
        samples: samples per relit view; >= 2 gives the confidence map (their std) and
            averages them.
        refine_steps: refinement steps at full resolution (0: the estimator's maps,
            upsampled).
        refine_lr: Adam rate of the refinement.
        photo_weight, relit_weight: weight of the photo's and of each relit view's loss.
        relit_robust: None (log-L1 for every view), or the scale of a robust loss for the
            relit views (``matcap.capture.refine._Target``: pixels a generated view gets
            badly wrong stop pulling the maps).
        relit_highlight: half-angle, degrees, of the cone under the flash whose disc the
            relit views' refinement loss leaves out, with the photo's clipped pixels (0:
            every pixel counts; ``DEFAULT_RELIT_HIGHLIGHT``).
        relit_maps: the maps the relit views' refinement loss may change (names of
            ``MAP_NAMES``); the others follow the photo alone.
        photo_maps: the maps taken from the estimator run on the photo alone rather
            than on the photo and the relit views (a second, cheap forward pass).
        shared_step_maps: the maps whose refinement step size is shared by all their
            pixels (``DEFAULT_SHARED_STEP_MAPS``); the others get per-pixel Adam.
        flatness: weight of the flat-sample prior on the refined normals (0: none;
            ``DEFAULT_FLATNESS``): a photographed sample is flat, so its normal map
            should not tilt at low frequency however bumpy its surface.
        radial: weight of the flash-independence prior on the refined maps (0: none;
            ``DEFAULT_RADIAL``): the material does not know where the flash was, so a
            map's mean over a ring around the point under the flash should not depend on
            the ring's radius (no disc or ring centred on the flash).
        radial_maps: the maps that prior looks at (names of ``MAP_NAMES``).
        vignetting: fit a smooth darkening radial gain of the photo with the maps
            (``matcap.capture.vignetting``: the flash's beam and the lens's vignetting,
            which the renderer does not model): ``"off"``, on the render of the
            ``"photo"`` only, or on ``"all"`` views (the relit views are made from the
            photo and carry its darkening).
        falloff: ``"none"`` or ``"inverse-square"`` (package docstring).
        fov: field of view across the photo's long side, degrees (None: EXIF or 45).
        camera: camera (and flash) position ``(x, y, z)``, scene units; overrides ``fov``
            and ``flash_point``.
        flash_point: ``FLASH_POINTS`` entry: the camera above the photo's centre, or
            above its located flash highlight (``DEFAULT_FLASH_POINT``).
        working_size: the networks' resolution, pixels.
        relit_size: side of the relit views, pixels: None keeps the working size; larger
            (a multiple of it) relights the photo at that size (the diffusion model:
            the whole plane at its own size, the photo's detail carried at full size,
            ``relight.detail``), and the refinement compares the relit views there; the
            estimator sees them resampled to ``estimate_size``. The size used is the largest multiple of the working size that is at
            most ``relit_size`` and divides the padded photo's side.
        estimate_size: side the estimator sees the photo and the relit views at, pixels
            (the whole image at once: it is convolutional): None keeps the working size;
            larger (a multiple of it) is chosen as ``relit_size`` is. Relit views of
            another size are area-averaged or bilinearly upsampled to it.
        max_side: downscale a photo whose long side exceeds it (None: refuse photos
            above ``MAX_SIDE``); at most ``MAX_SIDE``.
        seed: seed of the relighter's sampling.
        clip_aware: in the refinement, a pixel clipped at the top of the photo's range
            (8-bit PNG / JPEG: 1) or of the relighter's (1, times the falloff factor)
            counts as "at least this bright" (``refine_full_resolution``); EXR photos
            are taken as unclipped.
    """

    relit: int = len(EVAL_LIGHTS)
    steps: int | None = DEFAULT_RELIGHT_STEPS
    samples: int = 1
    refine_steps: int = DEFAULT_REFINE_STEPS
    refine_lr: float = REFINE_LR
    photo_weight: float = 1.0
    relit_weight: float = DEFAULT_RELIT_WEIGHT
    relit_robust: float | None = None
    relit_highlight: float = DEFAULT_RELIT_HIGHLIGHT
    relit_maps: tuple[str, ...] = DEFAULT_RELIT_MAPS
    photo_maps: tuple[str, ...] = DEFAULT_PHOTO_MAPS
    shared_step_maps: tuple[str, ...] = DEFAULT_SHARED_STEP_MAPS
    flatness: float = DEFAULT_FLATNESS
    radial: float = DEFAULT_RADIAL
    radial_maps: tuple[str, ...] = DEFAULT_RADIAL_MAPS
    vignetting: str = DEFAULT_VIGNETTING
    falloff: str = DEFAULT_FALLOFF
    fov: float | None = None
    camera: tuple[float, float, float] | None = None
    flash_point: str = DEFAULT_FLASH_POINT
    working_size: int = WORKING_SIZE
    relit_size: int | None = DEFAULT_RELIT_SIZE
    estimate_size: int | None = DEFAULT_ESTIMATE_SIZE
    max_side: int | None = None
    seed: int = 0
    clip_aware: bool = True

    def __post_init__(self) -> None:
        def need(ok: bool, message: str) -> None:
            if not ok:
                raise ValueError(message)

        need(0 <= self.relit <= len(EVAL_LIGHTS), f"relit must be 0..{len(EVAL_LIGHTS)}, got {self.relit}")
        need(self.steps is None or self.steps >= 1, f"steps must be at least 1, got {self.steps}")
        need(self.samples >= 1, f"samples must be at least 1, got {self.samples}")
        need(self.refine_steps >= 0, f"refine steps must be >= 0, got {self.refine_steps}")
        need(self.refine_lr > 0, f"refine_lr must be positive, got {self.refine_lr}")
        for name in ("photo_weight", "relit_weight"):
            value = getattr(self, name)
            need(math.isfinite(value) and value >= 0, f"{name} must be a finite number >= 0, got {value}")
        need(self.photo_weight > 0 or self.relit_weight > 0, "photo_weight and relit_weight cannot both be 0")
        need(
            self.relit_robust is None or (math.isfinite(self.relit_robust) and self.relit_robust > 0),
            f"relit_robust must be a positive number, got {self.relit_robust}",
        )
        need(
            math.isfinite(self.relit_highlight) and 0 <= self.relit_highlight < 90,
            f"relit_highlight must lie in [0, 90) degrees, got {self.relit_highlight}",
        )
        for name in ("flatness", "radial"):
            value = getattr(self, name)
            need(math.isfinite(value) and value >= 0, f"{name} must be a finite number >= 0, got {value}")
        for name in ("relit_maps", "photo_maps", "shared_step_maps", "radial_maps"):
            value = getattr(self, name)
            need(
                isinstance(value, tuple) and len(set(value)) == len(value) and set(value) <= set(MAP_NAMES),
                f"{name} must be distinct names of {', '.join(MAP_NAMES)}, got {value!r}",
            )
        need(bool(self.relit_maps), "relit_maps cannot be empty (use relit_weight=0 to ignore the relit views)")
        need(
            self.vignetting in VIGNETTING_VIEWS,
            f"vignetting must be one of {', '.join(VIGNETTING_VIEWS)}, got {self.vignetting!r}",
        )
        need(self.falloff in FALLOFFS, f"falloff must be one of {', '.join(FALLOFFS)}, got {self.falloff!r}")
        need(self.fov is None or 0 < self.fov < 180, f"field of view must lie in (0, 180) degrees, got {self.fov}")
        if self.camera is not None:
            need(
                len(self.camera) == 3 and all(math.isfinite(v) for v in self.camera) and self.camera[2] > 0,
                f"camera must be three finite numbers with z > 0, got {self.camera}",
            )
        need(
            self.flash_point in FLASH_POINTS,
            f"flash_point must be one of {', '.join(FLASH_POINTS)}, got {self.flash_point!r}",
        )
        need(self.working_size >= 16, f"working_size must be at least 16, got {self.working_size}")
        if self.relit_size is not None:
            need(
                self.relit_size >= self.working_size and self.relit_size % self.working_size == 0,
                f"relit size must be a multiple of the working size {self.working_size}, got {self.relit_size}",
            )
        if self.estimate_size is not None:
            need(
                self.estimate_size >= self.working_size and self.estimate_size % self.working_size == 0,
                f"estimate size must be a multiple of the working size {self.working_size}, got {self.estimate_size}",
            )
        if self.max_side is not None:
            need(
                self.working_size <= self.max_side <= MAX_SIDE,
                f"max side must lie in [{self.working_size}, {MAX_SIDE}], got {self.max_side}",
            )

    def to_dict(self) -> dict:
        return {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(self).items()}

    def relit_side(self, side: int) -> int:
        """The relit views' side for a padded photo of ``side`` pixels (a multiple of the
        working size): the largest multiple of the working size that is at most
        ``relit_size`` (None: the working size) and divides ``side``.

        >>> CaptureConfig().relit_side(512), CaptureConfig().relit_side(320), CaptureConfig(relit_size=None).relit_side(512)
        (256, 64, 64)
        """
        return self._side(self.relit_size, side)

    def estimate_side(self, side: int) -> int:
        """The estimator's input side for a padded photo of ``side`` pixels: as
        ``relit_side``, for ``estimate_size``.

        >>> CaptureConfig().estimate_side(1024), CaptureConfig().estimate_side(192), CaptureConfig().estimate_side(320)
        (256, 192, 64)
        """
        return self._side(self.estimate_size, side)

    def _side(self, size: int | None, side: int) -> int:
        ws = self.working_size
        largest = min(size or ws, side)
        return next(s for s in range(largest - largest % ws, ws - 1, -ws) if side % s == 0)
