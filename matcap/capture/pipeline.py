"""``CapturePipeline``: the numbered steps of a capture (package docstring), timed as one
progress bar (``_Stages``), and its provenance record.
"""

from __future__ import annotations

import os
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import replace

import torch
import torch.nn.functional as F
from tqdm.auto import tqdm

import kernels
from estimator.model import SVBRDFEstimator
from matcap.capture.config import DEFAULT_RELIGHTER, MAX_SIDE, RENDER_LIGHTS, CaptureConfig
from matcap.capture.flash import locate_flash
from matcap.capture.output import CaptureOutput, _preview_sheet
from matcap.capture.photo import photo_from_tensor
from matcap.capture.provenance import _component_record, _package_versions
from matcap.capture.refine import refine_full_resolution, refine_memory_bytes
from matcap.capture.relighting import native_resolution, relight_views
from matcap.capture.scene import CaptureScene, area_downsample, capture_scene, falloff_factor, flash_disc
from materials.frame import Frame, prepare_photo
from materials.highlight import saturated
from materials.io.photo import MIN_PHOTO_SIDE, Photo
from materials.lights import EVAL_LIGHTS
from materials.types import Capture, Material


class _Stages:
    """Times the numbered steps and shows them as one progress bar."""

    def __init__(self, total: int, progress: bool):
        self.timings: dict[str, float] = {}
        self.bar = tqdm(total=total, desc="capture", unit="step", disable=not progress)

    @contextmanager
    def __call__(self, name: str) -> Iterator[None]:
        self.bar.set_postfix_str(name)
        start = time.perf_counter()
        yield
        self.timings[name] = round(time.perf_counter() - start, 4)
        self.bar.update(1)

    def close(self) -> None:
        self.bar.close()


def _resample(images: torch.Tensor, side: int) -> torch.Tensor:
    """``[N, 3, S, S]`` linear images to ``side``: area-averaged down (an integer
    factor), bilinear up (relit views smaller than the estimate size)."""
    if images.shape[-1] == side:
        return images
    if images.shape[-1] > side:
        return area_downsample(images, side)
    return F.interpolate(images, size=(side, side), mode="bilinear", align_corners=False)


def _highlight_region(image, photo: Photo, camera, size: int, plane_size: float, half_angle_deg: float):
    """``[size, size]`` bool, the relit views' pixels over the photo's flash highlight: the
    disc of ``half_angle_deg`` under the flash, and every relit pixel that covers a
    clipped photo pixel (8-bit formats; an EXR is taken as unclipped)."""
    region = flash_disc(camera, size, plane_size, half_angle_deg)
    if photo.format != "exr":
        clipped = saturated(image[None])[0].float()
        region = region | (area_downsample(clipped, size)[0] > 0)
    return region


def _upsample(material: Material, side: int) -> Material:
    """Bilinear upsampling of batched maps to ``side x side``; normals renormalised."""
    if material.shape == (side, side):
        return material
    maps = {
        k: F.interpolate(v, size=(side, side), mode="bilinear", align_corners=False) for k, v in material.maps().items()
    }
    maps["normal"] = F.normalize(maps["normal"], dim=1)
    return Material(**maps)


class CapturePipeline:
    """Flash photo -> relit views -> SVBRDF maps (package docstring).

    Args:
        relighter: a ``relight.interface.Relighter`` (None allowed when ``config.relit``
            is 0: the photo alone).
        estimator: an ``SVBRDFEstimator`` (e.g. ``matcap.estimate.load_estimator()``).
        config: default settings of ``__call__``.
        names: registry names of the components, for the provenance record.
    """

    def __init__(
        self,
        relighter=None,
        estimator: SVBRDFEstimator | None = None,
        *,
        config: CaptureConfig | None = None,
        names: dict[str, str] | None = None,
    ):
        self.relighter = relighter
        self.estimator = estimator.eval() if estimator is not None else None
        self.config = config or CaptureConfig()
        self.names = dict(names or {})

    @property
    def components(self) -> dict:
        return {"relighter": self.relighter, "estimator": self.estimator}

    @classmethod
    def from_pretrained(
        cls,
        relighter: str | None = DEFAULT_RELIGHTER,
        *,
        relighter_checkpoint: str | os.PathLike | None = None,
        estimator: str | os.PathLike | None = None,
        config: CaptureConfig | None = None,
    ) -> CapturePipeline:
        """The shipped components (or the given folders); ``relighter=None`` loads none
        (for ``relit=0``)."""
        from matcap.estimate import load_estimator
        from matcap.estimator_relighter import register
        from relight.interface import get_relighter

        register()
        model = get_relighter(relighter, relighter_checkpoint) if relighter else None
        return cls(model, load_estimator(estimator), config=config, names={"relighter": relighter})

    # ------------------------------------------------------------------ steps
    def check_inputs(self, photo, config: CaptureConfig) -> Photo:
        """Step 1: the photo as a ``Photo``, or a ``ValueError`` saying what is wrong."""
        if not isinstance(photo, Photo):
            photo = photo_from_tensor(photo)
        image = photo.image
        if image.dim() != 3 or image.shape[0] != 3:
            raise ValueError(f"photo must be [3, H, W] linear radiance, got {tuple(image.shape)}")
        if not bool(torch.isfinite(image).all()) or bool((image < 0).any()):
            raise ValueError("photo must hold finite linear radiance >= 0")
        height, width = photo.size
        if min(height, width) < MIN_PHOTO_SIDE:
            raise ValueError(f"photo is {width}x{height} (W x H); each side must be at least {MIN_PHOTO_SIDE} pixels")
        if max(height, width) > MAX_SIDE and config.max_side is None:
            gb = refine_memory_bytes(MAX_SIDE, 1 + config.relit) / 1e9
            raise ValueError(
                f"photo is {width}x{height} (W x H); the capture refines at full resolution up to {MAX_SIDE} pixels "
                f"on the long side (about {gb:.1f} GB there): downscale it, or pass --max-side {MAX_SIDE} to let "
                "the pipeline do it"
            )
        if self.estimator is None:
            raise ValueError("the pipeline has no estimator")
        if config.working_size % self.estimator.downsample_factor:
            raise ValueError(
                f"working size {config.working_size} is not a multiple of the estimator's "
                f"{self.estimator.downsample_factor}"
            )
        if config.relit > 0:
            if self.relighter is None:
                raise ValueError(f"relit = {config.relit} needs a relighter; the pipeline has none")
            native = native_resolution(self.relighter)
            size = config.relit_size or config.working_size
            if native is not None and native > size:
                raise ValueError(f"the relighter needs at least {native} px, the relit size is {size}")
            if config.samples >= 2 and not getattr(self.relighter, "stochastic", False):
                raise ValueError(f"samples = {config.samples}: the relighter is deterministic, its samples would agree")
        return photo

    def scene(self, photo: Photo, frame: Frame, config: CaptureConfig) -> CaptureScene:
        """Camera, flash and lights of a prepared photo (``capture_scene``)."""
        lights = torch.tensor(EVAL_LIGHTS[: config.relit], dtype=torch.float32).reshape(-1, 3)
        located = locate_flash(photo.image) if config.flash_point == "auto" and config.camera is None else None
        return capture_scene(
            photo, frame, lights, falloff=config.falloff, fov=config.fov, camera=config.camera, flash_point=located
        )

    # ------------------------------------------------------------------ call
    def __call__(self, photo: Photo | torch.Tensor, *, config: CaptureConfig | None = None, progress: bool = False):
        """Run the capture on one photo.

        Args:
            photo: a ``Photo`` (``materials.io.read_photo``) or ``[3, H, W]`` linear radiance.
            config: settings (default: the pipeline's).
            progress: show a bar per step (and inner bars for relighting and refinement).

        Returns:
            ``CaptureOutput``; maps, re-renders and confidence on the photo's pixel grid.

        Raises:
            ValueError: a bad photo or setting (one sentence, nothing computed).
        """
        cfg = config or self.config
        stages = _Stages(8, progress)
        try:
            return self._run(photo, cfg, stages, progress)
        finally:
            stages.close()

    def _run(self, photo, cfg: CaptureConfig, stage: _Stages, progress: bool) -> CaptureOutput:
        ws, k = cfg.working_size, cfg.relit
        # 1. Check the inputs.
        with stage("1 check inputs"):
            photo = self.check_inputs(photo, cfg)

        # 2. Prepare the photo: a square of side a multiple of the working size, its scene,
        #    the no-falloff version for the networks, and the working-resolution image.
        with stage("2 prepare photo"):
            image, frame = prepare_photo(photo, multiple=ws, max_side=cfg.max_side, fit="pad")
            side = frame.size[0]
            scene = self.scene(photo, frame, cfg)
            camera, height = scene.camera_pos, float(scene.camera_pos[2])
            photo_mask = frame.valid_mask()
            rs = cfg.relit_side(side)
            relit_mask = area_downsample(photo_mask.float()[None], rs)[0] >= 1.0  # relit pixels all real
            if k and cfg.relit_highlight > 0:
                relit_mask = relit_mask & ~_highlight_region(
                    image, photo, camera, rs, frame.plane_size, cfg.relit_highlight
                )
            if cfg.falloff == "inverse-square":
                model_image = image / falloff_factor(camera[None], height, side, frame.plane_size)[0]
            else:
                model_image = image
            es = cfg.estimate_side(side)
            estimate_input = area_downsample(model_image, es)
            relit_input = estimate_input if rs == es else area_downsample(model_image, rs)

        # 3. Relight the photo at the relit size to the K lights (mean and std over samples).
        with stage("3 relight"):
            relit, std = torch.zeros(0, 3, rs, rs), None
            if k:
                for attr, value in (("steps", cfg.steps), ("num_samples", 1)):
                    if value is not None and hasattr(self.relighter, attr):
                        setattr(self.relighter, attr, value)
                generator = torch.Generator().manual_seed(cfg.seed)
                relit, std = relight_views(
                    self.relighter, relit_input, scene.relit_light_pos, camera, samples=cfg.samples,
                    generator=generator, progress=progress,
                )  # fmt: skip
            confidence = frame.to_photo(std.mean(dim=(0, 1))[None]) if std is not None else None

        # 4. One capture: the photo as view 0, the relit views after it.
        with stage("4 capture"):
            capture = Capture(
                images=torch.cat([estimate_input[None], _resample(relit, es)]),
                light_pos=torch.cat([camera[None], scene.relit_light_pos]),
                camera_pos=camera.expand(1 + k, 3).clone(),
                preset="dgrsise",
                plane_size=frame.plane_size,
                meta={
                    "made_by": "relight capture",
                    "photo": photo.path,
                    "views": "0: the photo, 1..K: relit views, all resampled to the estimate size "
                    "(area-averaged down, bilinear up)",
                    "falloff": "photo divided by the flash's 1/d^2 factor (no-falloff convention)"
                    if cfg.falloff == "inverse-square"
                    else "none assumed",
                    "frame": frame.to_dict(),
                },
            )

        # 5. The estimator on the 1 + K views at the estimate size (whole images: it is
        #    convolutional, and windows are worse, see estimator.tiling). Views 1.. are
        #    marked generated (an estimator built with ``generated_flag`` weighs them as
        #    a relighter's, not as photos; others ignore the mark).
        with stage("5 estimate"):
            scale = self.estimator.config.plane_size / frame.plane_size
            generated = torch.arange(1 + k) > 0
            with torch.no_grad():
                estimate = self.estimator(
                    capture.images[None],
                    capture.light_pos[None] * scale,
                    capture.camera_pos[None] * scale,
                    generated=generated,
                )
                # These maps from the photo alone (a second pass): the relit views are
                # upsampled from the relit size and blur the detail maps (results/capture_views).
                if k and cfg.photo_maps:
                    alone = self.estimator(
                        capture.images[None, :1],
                        capture.light_pos[None, :1] * scale,
                        capture.camera_pos[None, :1] * scale,
                        generated=generated[:1],
                    )
                    estimate = replace(estimate, **{name: getattr(alone, name) for name in cfg.photo_maps})

        # 6. Refinement at the photo's full resolution against the photo and, weighted far
        #    below it, the relit views (compared at their resolution), padded pixels
        #    masked out.
        with stage("6 refine"):
            init = _upsample(estimate, side)
            # The relighters' outputs are capped at 1 (the tone map's range): their
            # ceiling moves with the falloff conversion.
            targets, ceiling = relit, torch.ones(k, 1, 1, 1)
            if cfg.falloff == "inverse-square" and k:
                ceiling = falloff_factor(scene.relit_light_pos, height, rs, frame.plane_size)
                targets = relit * ceiling
            photo_ceiling = 1.0 if photo.format != "exr" else None
            history: list[float] = []
            vignetting: tuple[float, ...] = ()
            refined = init
            if cfg.refine_steps:
                result = refine_full_resolution(
                    init, image, photo_mask, targets, relit_mask, capture.light_pos, camera,
                    photo_weight=cfg.photo_weight, relit_weight=cfg.relit_weight, steps=cfg.refine_steps,
                    photo_ceiling=photo_ceiling if cfg.clip_aware else None,
                    relit_ceiling=ceiling if cfg.clip_aware else None, relit_robust=cfg.relit_robust,
                    relit_maps=cfg.relit_maps, shared_step_maps=cfg.shared_step_maps,
                    flatness=cfg.flatness, radial=cfg.radial, radial_maps=cfg.radial_maps, vignetting=cfg.vignetting,
                    lr=cfg.refine_lr,
                    render_kwargs=scene.render_kwargs, progress=progress,
                )  # fmt: skip
                refined, history, vignetting = result.material, result.history, result.vignetting

        # 7. The maps on the photo's pixel grid.
        with stage("7 maps to photo"):
            material = frame.material_to_photo(refined[0])

        # 8. Re-renders under the flash and the evaluation lights; the preview sheet.
        with stage("8 re-render"):
            render_lights = torch.cat([camera[None], torch.tensor(RENDER_LIGHTS, dtype=torch.float32)])
            with torch.no_grad():
                square = torch.stack(
                    [
                        kernels.render(*refined.map_tensors(), p[None, None], camera, **scene.render_kwargs)[0, 0]
                        for p in render_lights
                    ]
                )
            renders = torch.stack([frame.to_photo(r) for r in square])
            preview = self._preview(image, relit, refined, estimate, std, square)

        provenance = self._provenance(photo, frame, scene, cfg, stage.timings, history, vignetting)
        return CaptureOutput(
            material=material,
            estimate=estimate[0],
            relit=relit,
            confidence=confidence,
            renders=renders,
            capture=capture,
            photo=photo,
            frame=frame,
            scene=scene,
            preview=preview,
            refine_history=history,
            provenance=provenance,
        )

    # ------------------------------------------------------------------ records
    #: The preview sheet of step 8 (``matcap.capture.output._preview_sheet``).
    _preview = staticmethod(_preview_sheet)

    def _provenance(self, photo, frame, scene, cfg, timings, history, vignetting=()) -> dict:
        return {
            "made_by": "relight capture (matcap.capture.CapturePipeline)",
            "versions": _package_versions(),
            "weights": {
                "relighter": _component_record(self.relighter if cfg.relit else None, self.names.get("relighter")),
                "estimator": _component_record(self.estimator, self.names.get("estimator", "estimator")),
            },
            "seed": cfg.seed,
            "settings": cfg.to_dict(),
            "scene": scene.to_dict(),
            "photo": photo.metadata(),
            "frame": frame.to_dict(),
            "working_size": cfg.working_size,
            "refinement": {
                "steps_run": len(history),
                "loss_first": history[0] if history else None,
                "loss_last": history[-1] if history else None,
                # The photo's fitted radial gain exp(sum_k a_k rho^2k) (matcap.capture.vignetting).
                "vignetting": list(vignetting) if vignetting else None,
            },
            "timings_s": timings,
            "files": {
                "material/": "maps: EXR linear, PNG (diffuse/specular/basecolor sRGB, others linear), material.glb",
                "renders/view_KK": "re-renders on the photo's grid: 00 the flash, 01.. the evaluation lights",
                "relit/relit_KK": "relit views at the relit size (CaptureConfig.relit_side), the relighter's output (no falloff)",
                "confidence": "std across relighting samples, mean over views and channels (high = uncertain)",
                "capture/": "the estimator's input in our capture format (relight estimate reruns it)",
                "preview.png": "rows: photo + relit views; maps (diffuse, normal, roughness, specular, "
                "estimator diffuse, confidence); re-renders",
            },
        }
