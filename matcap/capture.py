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
5. the estimator on the 1 + K views at the working resolution;
6. refinement at the photo's full resolution (``refine_full_resolution``): per-pixel maps,
   initialised from the estimator's maps upsampled, fitted through the Warp renderer to
   the full-resolution photo and to the relit views compared at *their* resolution
   (render at full resolution, area-downsample, then the loss), a weight per view, the
   padded pixels masked out;
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
(0, 0, 4.83). The relit views' lights are positions in the same units.

Falloff. A real flash's light falls off with 1 / d^2 across the photo; the relighter and
the estimator were trained without falloff (SPEC section 2, preset ``dgrsise``).
``falloff="inverse-square"`` converts at the boundary: the photo is divided by the flash's
falloff factor ``h^2 / |p_flash - x|^2`` (1 under the camera, h its height) before
relighting and estimation (the no-falloff convention); the relit views are multiplied by
their target light's factor ``h^2 / |p_k - x|^2``; and the refinement renders with 1 / d^2
at intensity ``pi h^2``, which equals the no-falloff convention's radiance under the
camera. ``falloff="none"`` takes the photo as it is (the models' convention).
``DEFAULT_FALLOFF`` says which one is the default and the measurement behind it.

Example:
    >>> pipe = CapturePipeline(relighter=get_relighter("diffusion"), estimator=load_estimator())  # doctest: +SKIP
    >>> out = pipe(read_photo("wood.jpg"))  # doctest: +SKIP
    >>> out.material.diffuse.shape  # the photo's (H, W)  # doctest: +SKIP
    >>> out.save("out/wood")  # doctest: +SKIP
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import asdict, dataclass
from pathlib import Path

import torch
import torch.nn.functional as F
from tqdm.auto import tqdm

import kernels
from estimator.model import NORMAL_MIN_Z, SVBRDFEstimator
from estimator.refine import DEFAULT_TOL, DEFAULT_WINDOW, LOGIT_EPS, RefineResult, converged
from kernels.tonemap import srgb_encode, tonemap
from materials.camera import DEFAULT_FOV_DEG, camera_height, fov_from_exif
from materials.frame import Frame, prepare_photo
from materials.io.encoding import encode_normal
from materials.io.photo import MIN_PHOTO_SIDE, Photo
from materials.lights import EVAL_LIGHTS
from materials.types import Capture, Material

__all__ = [
    "CapturePipeline",
    "CaptureConfig",
    "CaptureOutput",
    "CaptureScene",
    "refine_full_resolution",
    "falloff_factor",
    "area_downsample",
    "refine_memory_bytes",
    "builtin_photo",
    "relight_views",
    "capture_scene",
    "native_resolution",
    "photo_from_tensor",
    "FALLOFFS",
    "DEFAULT_FALLOFF",
    "DEFAULT_RELIGHTER",
    "DEFAULT_RELIGHT_STEPS",
    "DEFAULT_RELIT_WEIGHT",
    "DEFAULT_REFINE_STEPS",
    "REFINE_LR",
    "WORKING_SIZE",
    "MAX_SIDE",
    "RENDER_LIGHTS",
    "PROVENANCE_JSON",
    "BUILTIN_SEED",
    "BUILTIN_SIZE",
]

#: How the flash's light falls off over the plane (module docstring).
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
#: Refinement defaults (README "Capture a material", tables "relit view weight" and
#: "steps"). Weight of each relit view (the photo weighs 1): over 5 real-texture and 4
#: glossy procedural materials, re-render PSNR by weight 0 / 0.1 / 0.25 / 0.5 / 1 was
#: 30.32 / 30.21 / 30.03 / 29.83 / 29.46 dB (real; photo alone 30.33) and 19.92 / 20.39 /
#: 20.31 / 20.15 / 20.05 dB (glossy; alone 20.31): 0.1 is the best on the glossy set and
#: within 0.12 dB of the photo alone on the real one, and roughness MSE on the glossy
#: set falls from 0.130 (alone) to 0.057. Steps: 50 / 100 / 200 gave 20.24 / 20.39 / 20.24
#: dB on the glossy set; 100 keeps 1024 px under the 120 s target (96 s measured).
DEFAULT_REFINE_STEPS = 100
DEFAULT_RELIT_WEIGHT = 0.1
#: Adam rate of the per-pixel logits and normal slopes (``estimator.refine.refine_maps``'s).
REFINE_LR = 1e-2
#: Lights of the re-renders (after the flash): the 7 evaluation lights.
RENDER_LIGHTS = EVAL_LIGHTS
#: The file that marks a folder written by ``CaptureOutput.save`` (safe to --overwrite).
PROVENANCE_JSON = "provenance.json"
#: The built-in photo: procedural seed (``relight render``'s default material) and size.
BUILTIN_SEED = 3
BUILTIN_SIZE = 256
# Side of one tile of the preview sheet, pixels.
_SHEET_TILE = 128


# ---------------------------------------------------------------------- settings
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
        falloff: ``"none"`` or ``"inverse-square"`` (module docstring).
        fov: field of view across the photo's long side, degrees (None: EXIF or 45).
        camera: camera (and flash) position ``(x, y, z)``, scene units; overrides ``fov``.
        working_size: the networks' resolution, pixels.
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
    falloff: str = DEFAULT_FALLOFF
    fov: float | None = None
    camera: tuple[float, float, float] | None = None
    working_size: int = WORKING_SIZE
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
        need(self.falloff in FALLOFFS, f"falloff must be one of {', '.join(FALLOFFS)}, got {self.falloff!r}")
        need(self.fov is None or 0 < self.fov < 180, f"field of view must lie in (0, 180) degrees, got {self.fov}")
        if self.camera is not None:
            need(
                len(self.camera) == 3 and all(math.isfinite(v) for v in self.camera) and self.camera[2] > 0,
                f"camera must be three finite numbers with z > 0, got {self.camera}",
            )
        need(self.working_size >= 16, f"working_size must be at least 16, got {self.working_size}")
        if self.max_side is not None:
            need(
                self.working_size <= self.max_side <= MAX_SIDE,
                f"max side must lie in [{self.working_size}, {MAX_SIDE}], got {self.max_side}",
            )

    def to_dict(self) -> dict:
        return {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(self).items()}


@dataclass(frozen=True)
class CaptureScene:
    """Where the camera and the lights are, and how the refinement renders (scene units
    of the ``dgrsise`` plane, side ``plane_size``).

    Attributes:
        camera_pos: ``[3]`` camera and flash position.
        camera_source: ``"camera"`` (given), ``"fov"`` (given), ``"exif"`` or ``"default"``.
        fov_deg: field of view across the photo's long side (None when ``camera`` was given).
        relit_light_pos: ``[K, 3]`` lights of the relit views.
        falloff: ``FALLOFFS`` entry.
        plane_size: side of the plane the prepared square spans.
    """

    camera_pos: torch.Tensor
    camera_source: str
    fov_deg: float | None
    relit_light_pos: torch.Tensor
    falloff: str
    plane_size: float

    @property
    def render_kwargs(self) -> dict:
        """``kernels.render`` keywords of the refinement and the re-renders: ``dgrsise``,
        with 1/d^2 at intensity pi h^2 under ``"inverse-square"`` (module docstring)."""
        if self.falloff == "none":
            return {"preset": "dgrsise"}
        height = float(self.camera_pos[2])
        return {"preset": "dgrsise", "inverse_square": True, "intensity": math.pi * height * height}

    def to_dict(self) -> dict:
        return {
            "camera_pos": self.camera_pos.tolist(),
            "camera_source": self.camera_source,
            "fov_deg": self.fov_deg,
            "relit_light_pos": self.relit_light_pos.tolist(),
            "render_light_pos": [self.camera_pos.tolist(), *[list(p) for p in RENDER_LIGHTS]],
            "falloff": self.falloff,
            "plane_size": self.plane_size,
            "render": dict(self.render_kwargs),
        }


@dataclass
class CaptureOutput:
    """What one capture produced (tensors on the CPU, float32, linear unless stated).

    Attributes:
        material: ``Material`` ``[C, H, W]`` on the photo's pixel grid (refined).
        estimate: the estimator's maps ``[C, w, w]`` at the working resolution.
        relit: ``[K, 3, w, w]`` relit views, the relighter's output (no falloff).
        confidence: ``[1, H, W]`` std across relighting samples on the photo's grid
            (high = uncertain), or None (fewer than 2 samples, or K = 0).
        renders: ``[1 + 7, 3, H, W]`` the refined maps re-rendered under the flash and the
            ``RENDER_LIGHTS``, on the photo's grid (in ``scene.render_kwargs``).
        capture: the step-4 ``Capture`` (working resolution, no-falloff convention): what
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

    def save(self, folder: str | os.PathLike, *, overwrite: bool = False) -> Path:
        """Write the capture's folder, atomically (nothing appears unless all of it does)::

        provenance.json     the record (marker of this folder)
        preview.png         photo + relit views / maps / re-renders (tone-mapped, sRGB maps)
        material/           ``export_material``: EXR + PNG maps, metallic-roughness, material.glb
        renders/view_KK.exr/.png   re-renders on the photo's grid: 00 the flash, 01.. RENDER_LIGHTS
        relit/relit_KK.exr/.png    relit views at the working resolution (no falloff)
        confidence.exr/.png        std across relighting samples (only with samples >= 2)
        capture/            our capture format (capture.json + 0.png ... K.png): the
                            estimator's input, so ``relight estimate capture/`` reruns it
        """
        from matcap.outputs import write_image_pair
        from materials.io import export_material, write_capture, write_exr, write_png
        from materials.io.atomic import atomic_folder
        from materials.io.encoding import chw_to_hwc

        folder = Path(folder)
        with atomic_folder(folder, overwrite=overwrite, marker=PROVENANCE_JSON) as tmp:
            export_material(tmp / "material", self.material, provenance={"made_by": "relight capture"})
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


# ---------------------------------------------------------------------- helpers
def photo_from_tensor(image: torch.Tensor, name: str = "<tensor>", *, fmt: str = "tensor") -> Photo:
    """Wrap ``[3, H, W]`` linear radiance as a ``Photo`` (for callers without a file)."""
    if not isinstance(image, torch.Tensor) or image.dim() != 3 or image.shape[0] != 3:
        raise ValueError(f"photo must be a Photo or a [3, H, W] tensor, got {getattr(image, 'shape', type(image))}")
    size = tuple(image.shape[-2:])
    return Photo(image=image.float(), path=name, format=fmt, bit_depth=None, file_size=size, channels=3)


def builtin_photo(name: str = "", *, size: int = BUILTIN_SIZE, falloff: str = DEFAULT_FALLOFF) -> Photo:
    """A flash photo the project makes itself: a procedural material rendered under the
    flash at the default camera (45 degrees over a square photo), tone-mapped and
    quantised to 8 bits like a PNG, decoded back to linear radiance.

    Args:
        name: ``""`` (seed ``BUILTIN_SEED``), a seed number, or a procedural family
            (``materials.procedural.FAMILIES``; its glossy finish).
        size: side of the square photo, pixels.
        falloff: whether the flash falls off with 1/d^2 (a real flash) or not.

    Returns:
        A ``Photo`` with ``format="builtin"`` and ``path="builtin:<name>"``.
    """
    from materials.camera import camera_from_fov
    from materials.procedural import FAMILIES, generate

    if falloff not in FALLOFFS:
        raise ValueError(f"falloff must be one of {', '.join(FALLOFFS)}, got {falloff!r}")
    if name == "":
        material, label = generate(BUILTIN_SEED, size=size), str(BUILTIN_SEED)
    elif name.isdigit():
        material, label = generate(int(name), size=size), name
    elif name in FAMILIES:
        material, label = generate(BUILTIN_SEED, size=size, family=name, glossy=True), name
    else:
        raise ValueError(f"builtin photo {name!r}: give a seed number or a family ({', '.join(FAMILIES)})")
    camera = camera_from_fov(DEFAULT_FOV_DEG)
    scene = CaptureScene(camera, "default", DEFAULT_FOV_DEG, torch.zeros(0, 3), falloff, 4.0)
    radiance = kernels.render(*(t[None] for t in material.map_tensors()), camera[None], camera, **scene.render_kwargs)
    codes = torch.round(tonemap(radiance[0, 0]) * 255.0) / 255.0
    return photo_from_tensor(kernels.inverse_tonemap(codes), f"builtin:{label}", fmt="builtin")


def native_resolution(relighter) -> int | None:
    """The only image size a relighter accepts (the diffusion model's), or None."""
    model = getattr(getattr(relighter, "pipeline", None), "model", None)
    resolution = getattr(getattr(model, "config", None), "resolution", None)
    return int(resolution) if resolution is not None else None


def area_downsample(x: torch.Tensor, size: int) -> torch.Tensor:
    """Mean over ``f x f`` blocks: ``[..., C, S, S]`` -> ``[..., C, size, size]``, S = f * size
    (the radiance a pixel ``f`` times larger collects; differentiable)."""
    s = x.shape[-1]
    if x.shape[-2] != s or s % size:
        raise ValueError(f"area_downsample needs a square side that is a multiple of {size}, got {tuple(x.shape)}")
    if s == size:
        return x
    f = s // size
    # A reshape and a mean: its backward is a broadcast (avg_pool2d's CPU backward cost
    # 20 ms per 256 px view here, more than the render's).
    return x.reshape(*x.shape[:-2], size, f, size, f).mean(dim=(-3, -1))


def _plane_grid(size: int, plane_size: float, dtype=torch.float32) -> tuple[torch.Tensor, torch.Tensor]:
    """``(x, y)`` ``[size, size]`` plane coordinates of the pixel centres (SPEC section 2)."""
    c = ((torch.arange(size, dtype=torch.float64) + 0.5) / size - 0.5) * plane_size
    return c[None, :].expand(size, size).to(dtype), (-c)[:, None].expand(size, size).to(dtype)


def falloff_factor(light_pos: torch.Tensor, reference_height: float, size: int, plane_size: float) -> torch.Tensor:
    """``h^2 / |p - x|^2`` per pixel of a square image spanning the plane.

    Args:
        light_pos: ``[K, 3]`` light positions (scene units).
        reference_height: ``h``, the flash's height (the factor is 1 under a flash at h).
        size: side of the image, pixels; plane_size: side of the plane, scene units.

    Returns:
        ``[K, 1, size, size]`` float32.
    """
    x, y = _plane_grid(size, plane_size, torch.float64)
    p = light_pos.to(torch.float64)[:, :, None, None]
    d2 = (p[:, 0] - x) ** 2 + (p[:, 1] - y) ** 2 + p[:, 2] ** 2
    return (reference_height**2 / d2)[:, None].float()


def refine_memory_bytes(side: int, views: int) -> int:
    """Estimated peak bytes of ``refine_full_resolution`` at ``side x side`` (float32).

    Per pixel: the 10 map channels as parameters, their gradient, Adam's two moments and
    the best copy (5 x 10), the maps made from them and a detached copy with its gradient
    (3 x 10), the photo target and mask (4); plus, per view rendered in one call
    (``CHUNK_BYTES``), about 12 channels (render, Fresnel weights, masked products, their
    gradients). Compared with the peak RSS in ``benchmarks/bench_capture.py``.
    """
    per_view = 4 * _VIEW_CHANNELS * side * side
    in_flight = min(views, max(1, CHUNK_BYTES // per_view))
    return int(4 * side * side * (5 * 10 + 3 * 10 + 4) + in_flight * per_view)


def _sha256(obj) -> str:
    return hashlib.sha256(json.dumps(obj, sort_keys=True, default=str).encode()).hexdigest()


def _component_record(component, name: str | None) -> dict:
    """Where a component's weights came from: its folder and a hash of its config."""
    if component is None:
        return {"name": name, "used": False}
    model = getattr(getattr(component, "pipeline", None), "model", None) or getattr(component, "model", component)
    config = getattr(model, "config", None)
    record: dict = {"name": name or type(component).__name__, "class": type(component).__name__}
    if config is not None:
        config = dict(config)
        record["folder"] = str(config.get("_name_or_path")) if config.get("_name_or_path") else None
        record["config_sha256"] = _sha256({k: v for k, v in config.items() if not k.startswith("_")})
    for attr in ("steps", "num_samples"):
        if hasattr(component, attr):
            record[attr] = getattr(component, attr)
    return record


def _package_versions() -> dict:
    from importlib import metadata

    versions = {"python": ".".join(map(str, __import__("sys").version_info[:3])), "torch": torch.__version__}
    for dist in ("dgrsise", "warp-lang", "diffusers"):
        try:
            versions[dist] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            versions[dist] = None
    return versions


def capture_scene(
    photo: Photo,
    frame: Frame,
    light_pos: torch.Tensor,
    *,
    falloff: str = DEFAULT_FALLOFF,
    fov: float | None = None,
    camera: tuple[float, float, float] | None = None,
) -> CaptureScene:
    """The scene convention of a phone photo (module docstring): the camera and flash
    above the photo's centre, at the height where the photo's long side on the plane
    spans the field of view: ``fov``, else the EXIF focal length, else 45 degrees;
    ``camera`` overrides all of it.

    Args:
        photo: the ``Photo`` (its EXIF focal length and size); frame: its ``Frame``.
        light_pos: ``[K, 3]`` lights of the relit views (scene units).
    """
    if camera is not None:
        camera_pos, source, fov_deg = torch.tensor(camera, dtype=torch.float32), "camera", None
    else:
        if fov is not None:
            fov_deg, source = float(fov), "fov"
        elif photo.focal_35mm is not None:
            h, w = photo.exif_size or photo.size
            fov_deg, source = fov_from_exif(photo.focal_35mm, aspect=max(h, w) / min(h, w)), "exif"
        else:
            fov_deg, source = DEFAULT_FOV_DEG, "default"
        height, width = frame.photo_size
        x, y = frame.pixel_to_plane(torch.tensor((height - 1) / 2), torch.tensor((width - 1) / 2))
        z = camera_height(fov_deg, frame.photo_long_side)
        camera_pos = torch.tensor([float(x), float(y), z], dtype=torch.float32)
    return CaptureScene(camera_pos, source, fov_deg, light_pos.float().reshape(-1, 3), falloff, frame.plane_size)


# ---------------------------------------------------------------------- relighting
def relight_views(
    relighter,
    photo: torch.Tensor,
    light_pos: torch.Tensor,
    camera_pos: torch.Tensor,
    *,
    samples: int = 1,
    generator: torch.Generator | None = None,
    progress: bool = False,
    desc: str = "relight",
) -> tuple[torch.Tensor, torch.Tensor | None]:
    """Relight one photo to K lights, one light (and sample) per call, so a slow model
    shows progress; the generator carries on from call to call.

    Args:
        photo: ``[3, h, w]`` linear radiance at the relighter's size.
        light_pos: ``[K, 3]``; camera_pos: ``[3]``.
        samples: samples per light (>= 2 only for stochastic relighters).

    Returns:
        ``(relit [K, 3, h, w], std [K, 3, h, w] or None)``: the mean over samples and the
        per-pixel standard deviation across them (None for one sample).
    """
    total = len(light_pos) * samples
    outs = []
    with tqdm(total=total, desc=desc, unit="image", leave=False, disable=not progress) as bar:
        for _ in range(samples):
            row = []
            for k in range(len(light_pos)):
                out = relighter.relight(
                    photo=photo[None],
                    light_pos=light_pos[None, k : k + 1],
                    camera_pos=camera_pos[None],
                    generator=generator,
                )
                row.append(out[0, 0].float())
                bar.update(1)
            outs.append(torch.stack(row))
    stack = torch.stack(outs)  # [samples, K, 3, h, w]
    return stack.mean(0), (stack.std(0, unbiased=False) if samples >= 2 else None)


# ---------------------------------------------------------------------- refinement
class _Target:
    """One view's target, prepared once for the loss of every step (``loss``): the mean
    ``kernels.log_l1_loss`` over the pixels where ``mask`` ([h, w] bool) is True.

    ``ceiling``: the level at which ``y`` was clipped (a scalar or a tensor broadcasting to
    ``y``), or None. A pixel of ``y`` at its ceiling only says "at least this bright" (the
    flash highlight of an 8-bit photo, a relighter's output capped at 1), so there the
    render is compared as ``min(x, ceiling)``: a brighter render costs nothing.
    """

    def __init__(self, y: torch.Tensor, mask: torch.Tensor, ceiling: torch.Tensor | float | None = None):
        self.mask = None if bool(mask.all()) else mask.to(y.dtype)
        self.scale = mask.numel() / int(mask.sum())  # mean over the masked pixels only
        self.y = y if self.mask is None else y * self.mask
        self.clipped, self.ceiling = None, None
        if ceiling is not None:
            ceiling = torch.as_tensor(ceiling, dtype=y.dtype)
            clipped = y >= ceiling - CLIP_TOL
            if bool(clipped.any()):
                self.clipped, self.ceiling = clipped, ceiling

    def loss(self, x: torch.Tensor) -> torch.Tensor:
        if self.clipped is not None:
            x = torch.where(self.clipped, torch.minimum(x, self.ceiling), x)
        if self.mask is not None:
            x = x * self.mask
        return kernels.log_l1_loss(x, self.y) * self.scale


def _masked_log_l1(
    x: torch.Tensor, y: torch.Tensor, mask: torch.Tensor, ceiling: torch.Tensor | float | None = None
) -> torch.Tensor:
    """``_Target(y, mask, ceiling).loss(x)``."""
    return _Target(y, mask, ceiling).loss(x)


#: A target within this of its ceiling counts as clipped. Decoded 8-bit photos and the
#: relighters' capped outputs sit exactly at it; the next 8-bit code is 0.009 below 1.
CLIP_TOL = 1e-6


def _to_parameters(material: Material) -> list[torch.Tensor]:
    """Unconstrained per-pixel parameters of ``[1, C, S, S]`` maps, as in
    ``estimator.refine.refine_maps``: logits of diffuse, roughness, specular (clamped to
    ``[LOGIT_EPS, 1 - LOGIT_EPS]`` first), normals as slopes ``(n_x, n_y) / n_z``."""
    n = F.normalize(material.normal.detach().float(), dim=1)
    nz = n[:, 2:3].clamp_min(NORMAL_MIN_Z)

    def logit(t):
        return torch.logit(t.detach().float().clamp(LOGIT_EPS, 1 - LOGIT_EPS))

    return [
        logit(material.diffuse).requires_grad_(True),
        (n[:, :2] / nz).requires_grad_(True),
        logit(material.roughness).requires_grad_(True),
        logit(material.specular).requires_grad_(True),
    ]


def _from_parameters(p: list[torch.Tensor]) -> Material:
    slope = p[1]
    normal = F.normalize(torch.cat([slope, torch.ones_like(slope[:, :1])], dim=1), dim=1)
    return Material(torch.sigmoid(p[0]), normal, torch.sigmoid(p[2]), torch.sigmoid(p[3]))


#: Views rendered in one call of the refinement: as many as fit in this many bytes of
#: per-view buffers (render, Fresnel weights, output gradient, loss temporaries: about
#: 12 float32 channels a pixel). One call for several views costs less than one per view
#: (256 px, 8 views: 0.13 s against 0.29 s forward + backward on this CPU); 2048 px gets
#: 2 views a call.
CHUNK_BYTES = 512 * 1024 * 1024
_VIEW_CHANNELS = 12


def _view_chunks(views: list[int], side: int) -> list[list[int]]:
    per_view = 4 * _VIEW_CHANNELS * side * side
    n = max(1, CHUNK_BYTES // per_view)
    return [views[i : i + n] for i in range(0, len(views), n)]


def refine_full_resolution(
    material: Material,
    photo: torch.Tensor,
    photo_mask: torch.Tensor,
    relit: torch.Tensor,
    relit_mask: torch.Tensor,
    light_pos: torch.Tensor,
    camera_pos: torch.Tensor,
    *,
    photo_weight: float = 1.0,
    relit_weight: float = DEFAULT_RELIT_WEIGHT,
    photo_ceiling: float | None = None,
    relit_ceiling: torch.Tensor | float | None = None,
    steps: int = DEFAULT_REFINE_STEPS,
    lr: float = REFINE_LR,
    tol: float = DEFAULT_TOL,
    window: int = DEFAULT_WINDOW,
    render_kwargs: dict | None = None,
    progress: bool = False,
) -> RefineResult:
    """Fit per-pixel maps at the photo's resolution to the photo and to lower-resolution
    relit views, through the Warp renderer.

    Loss: ``sum_v w_v L_v / sum_v w_v`` with ``L_v`` the mean log-L1
    (``kernels.log_l1_loss``, Deschaintre et al. 2018) over the masked pixels: view 0 the
    maps rendered under the flash against ``photo`` at full resolution; view k >= 1
    rendered at full resolution under light k, area-downsampled to the relit size, against
    ``relit[k - 1]``. ``w_0 = photo_weight``, ``w_k = relit_weight``. The views are
    rendered and back-propagated one at a time (the maps' gradient accumulates), so the
    memory does not grow with K (``refine_memory_bytes``). Adam on the parameters of
    ``estimator.refine.refine_maps``; early stop and best-of as in ``estimator.refine``.

    Args:
        material: initial maps ``[1, C, S, S]`` (e.g. the estimator's, upsampled).
        photo: ``[3, S, S]`` linear radiance; photo_mask: ``[S, S]`` bool (True: real pixel).
        relit: ``[K, 3, s, s]`` (K may be 0; S a multiple of s); relit_mask: ``[s, s]`` bool.
        light_pos: ``[1 + K, 3]`` (row 0 the flash); camera_pos: ``[3]``.
        photo_ceiling, relit_ceiling: where the photo / the relit views were clipped
            (``_masked_log_l1``): None (not clipped), a number, or for the relit views a
            tensor broadcasting to ``[K, 3, s, s]``.
        render_kwargs: ``kernels.render`` keywords (preset, falloff, intensity).

    Returns:
        ``RefineResult(material [1, C, S, S], history, 0)``.
    """
    render_kwargs = dict(render_kwargs or {"preset": "dgrsise"})
    k = relit.shape[0]
    side = photo.shape[-1]
    if material.diffuse.shape[0] != 1 or material.shape != (side, side) or photo.shape[-2] != side:
        raise ValueError(f"material {material.shape} and photo {tuple(photo.shape)} must be one [.., S, S] image")
    if light_pos.shape != (1 + k, 3):
        raise ValueError(f"light_pos must be [1 + K, 3] = [{1 + k}, 3], got {tuple(light_pos.shape)}")
    weights = [photo_weight] + [relit_weight] * k
    total = sum(weights)
    if not total > 0:
        raise ValueError("the view weights sum to 0")
    views = [v for v in range(1 + k) if weights[v] > 0]
    lights = light_pos.float()
    camera = camera_pos.float().reshape(1, 1, 3)
    relit_size = relit.shape[-1] if k else side

    # Per chunk of views rendered together: the photo's target (if view 0 is in it) and
    # one batched target for its relit views (they share one weight).
    plan = []
    for chunk in _view_chunks(views, side):
        rel = [v - 1 for v in chunk if v > 0]
        ceiling = relit_ceiling[rel] if isinstance(relit_ceiling, torch.Tensor) else relit_ceiling
        plan.append(
            (
                chunk,
                _Target(photo, photo_mask, photo_ceiling) if chunk[0] == 0 else None,
                _Target(relit[rel], relit_mask, ceiling) if rel else None,
                len(rel) * relit_weight / total,
            )
        )

    def chunk_loss(maps: tuple[torch.Tensor, ...], step: tuple) -> torch.Tensor:
        chunk, photo_target, relit_target, relit_share = step
        images = kernels.render(*maps, lights[chunk][None], camera, **render_kwargs)[0]  # [n, 3, S, S]
        loss = images.new_zeros(())
        if photo_target is not None:
            loss = loss + photo_target.loss(images[0]) * (photo_weight / total)
            images = images[1:]
        if relit_target is not None:
            loss = loss + relit_target.loss(area_downsample(images, relit_size)) * relit_share
        return loss

    params = _to_parameters(material)
    # fused: one kernel for the whole update (the per-tensor loop cost ~10% of a step).
    opt = torch.optim.Adam(params, lr=lr, fused=True)
    history: list[float] = []
    best, best_loss = [p.detach().clone() for p in params], float("inf")

    def loss_and_grad() -> float:
        maps = _from_parameters(params).map_tensors()
        leaves = tuple(t.detach().requires_grad_(True) for t in maps)
        value = 0.0
        for step in plan:
            loss = chunk_loss(leaves, step)
            loss.backward()  # one chunk's graph at a time; the leaves' .grad accumulates
            value += float(loss.detach())
        torch.autograd.backward(list(maps), [t.grad for t in leaves])
        return value

    with tqdm(total=steps, desc="refine (full resolution)", leave=False, disable=not progress) as bar:
        for _ in range(steps):
            opt.zero_grad(set_to_none=True)
            value = loss_and_grad()
            if value < best_loss:  # the loss belongs to the parameters before this step
                best_loss, best = value, [p.detach().clone() for p in params]
            opt.step()
            history.append(value)
            bar.update(1)
            bar.set_postfix(loss=f"{value:.5f}")
            if converged(history, window, tol):
                break
    with torch.no_grad():
        if steps:
            maps = _from_parameters(params).map_tensors()
            if sum(float(chunk_loss(maps, step)) for step in plan) >= best_loss:
                for p, b in zip(params, best):
                    p.copy_(b)
        return RefineResult(_from_parameters(params), history, 0)


# ---------------------------------------------------------------------- the pipeline
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


def _upsample(material: Material, side: int) -> Material:
    """Bilinear upsampling of batched maps to ``side x side``; normals renormalised."""
    if material.shape == (side, side):
        return material
    maps = {
        k: F.interpolate(v, size=(side, side), mode="bilinear", align_corners=False) for k, v in material.maps().items()
    }
    maps["normal"] = F.normalize(maps["normal"], dim=1)
    return Material(**maps)


def _tiles(images: torch.Tensor, side: int) -> torch.Tensor:
    """``[N, C, h, w]`` display values (C = 1 or 3) -> ``[N, 3, side, side]``."""
    images = images.float()
    if images.shape[1] == 1:
        images = images.expand(-1, 3, -1, -1)
    if images.shape[-1] != side:
        images = F.interpolate(images, size=(side, side), mode="bilinear", antialias=True, align_corners=False)
    return images.clamp(0, 1)


class CapturePipeline:
    """Flash photo -> relit views -> SVBRDF maps (module docstring).

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
            if native is not None and native != config.working_size:
                raise ValueError(f"the relighter works at {native} px only, the working size is {config.working_size}")
            if config.samples >= 2 and not getattr(self.relighter, "stochastic", False):
                raise ValueError(f"samples = {config.samples}: the relighter is deterministic, its samples would agree")
        return photo

    def scene(self, photo: Photo, frame: Frame, config: CaptureConfig) -> CaptureScene:
        """Camera, flash and lights of a prepared photo (``capture_scene``)."""
        lights = torch.tensor(EVAL_LIGHTS[: config.relit], dtype=torch.float32).reshape(-1, 3)
        return capture_scene(photo, frame, lights, falloff=config.falloff, fov=config.fov, camera=config.camera)

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
            relit_mask = area_downsample(photo_mask.float()[None], ws)[0] >= 1.0  # working pixels all real
            if cfg.falloff == "inverse-square":
                model_image = image / falloff_factor(camera[None], height, side, frame.plane_size)[0]
            else:
                model_image = image
            working = area_downsample(model_image, ws)

        # 3. Relight the working photo to the K lights (mean and std over samples).
        with stage("3 relight"):
            relit, std = torch.zeros(0, 3, ws, ws), None
            if k:
                for attr, value in (("steps", cfg.steps), ("num_samples", 1)):
                    if value is not None and hasattr(self.relighter, attr):
                        setattr(self.relighter, attr, value)
                generator = torch.Generator().manual_seed(cfg.seed)
                relit, std = relight_views(
                    self.relighter, working, scene.relit_light_pos, camera, samples=cfg.samples,
                    generator=generator, progress=progress,
                )  # fmt: skip
            confidence = frame.to_photo(std.mean(dim=(0, 1))[None]) if std is not None else None

        # 4. One capture: the photo as view 0, the relit views after it.
        with stage("4 capture"):
            capture = Capture(
                images=torch.cat([working[None], relit]),
                light_pos=torch.cat([camera[None], scene.relit_light_pos]),
                camera_pos=camera.expand(1 + k, 3).clone(),
                preset="dgrsise",
                plane_size=frame.plane_size,
                meta={
                    "made_by": "relight capture",
                    "photo": photo.path,
                    "views": "0: the photo (area-downsampled to the working size), 1..K: relit views",
                    "falloff": "photo divided by the flash's 1/d^2 factor (no-falloff convention)"
                    if cfg.falloff == "inverse-square"
                    else "none assumed",
                    "frame": frame.to_dict(),
                },
            )

        # 5. The estimator on the 1 + K views at the working resolution.
        with stage("5 estimate"):
            scale = self.estimator.config.plane_size / frame.plane_size
            with torch.no_grad():
                estimate = self.estimator(
                    capture.images[None], capture.light_pos[None] * scale, capture.camera_pos[None] * scale
                )

        # 6. Refinement at the photo's full resolution against the photo and the relit
        #    views (compared at their resolution), padded pixels masked out.
        with stage("6 refine"):
            init = _upsample(estimate, side)
            # The relighters' outputs are capped at 1 (the tone map's range): their
            # ceiling moves with the falloff conversion.
            targets, ceiling = relit, torch.ones(k, 1, 1, 1)
            if cfg.falloff == "inverse-square" and k:
                ceiling = falloff_factor(scene.relit_light_pos, height, ws, frame.plane_size)
                targets = relit * ceiling
            photo_ceiling = 1.0 if photo.format != "exr" else None
            history: list[float] = []
            refined = init
            if cfg.refine_steps:
                result = refine_full_resolution(
                    init, image, photo_mask, targets, relit_mask, capture.light_pos, camera,
                    photo_weight=cfg.photo_weight, relit_weight=cfg.relit_weight, steps=cfg.refine_steps,
                    photo_ceiling=photo_ceiling if cfg.clip_aware else None,
                    relit_ceiling=ceiling if cfg.clip_aware else None,
                    lr=cfg.refine_lr, render_kwargs=scene.render_kwargs, progress=progress,
                )  # fmt: skip
                refined, history = result.material, result.history

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

        provenance = self._provenance(photo, frame, scene, cfg, stage.timings, history)
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
    @staticmethod
    def _preview(image, relit, refined: Material, estimate: Material, std, renders) -> torch.Tensor:
        """Rows: photo + relit views; refined maps (diffuse and specular sRGB, normal
        (n + 1) / 2, roughness linear), the estimator's diffuse, the confidence; re-renders."""
        from matcap.outputs import contact_sheet

        t = _SHEET_TILE
        row1 = torch.cat([_tiles(tonemap(image[None]), t), *([_tiles(tonemap(relit), t)] if len(relit) else [])])
        maps = [
            srgb_encode(refined.diffuse),
            encode_normal(refined.normal),
            refined.roughness,
            srgb_encode(refined.specular),
            srgb_encode(estimate.diffuse),
        ]
        if std is not None:
            spread = std.mean(dim=(0, 1))[None, None]
            maps.append(spread / spread.max().clamp_min(1e-8))
        row2 = torch.cat([_tiles(m, t) for m in maps])
        row3 = _tiles(tonemap(renders), t)
        columns = max(len(row1), len(row2), len(row3))

        def pad(row):
            return torch.cat([row, row.new_zeros(columns - len(row), 3, t, t)])

        return contact_sheet(torch.cat([pad(row1), pad(row2), pad(row3)]), columns=columns)

    def _provenance(self, photo, frame, scene, cfg, timings, history) -> dict:
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
            },
            "timings_s": timings,
            "files": {
                "material/": "maps: EXR linear, PNG (diffuse/specular/basecolor sRGB, others linear), material.glb",
                "renders/view_KK": "re-renders on the photo's grid: 00 the flash, 01.. the evaluation lights",
                "relit/relit_KK": "relit views at the working resolution, the relighter's output (no falloff)",
                "confidence": "std across relighting samples, mean over views and channels (high = uncertain)",
                "capture/": "the estimator's input in our capture format (relight estimate reruns it)",
                "preview.png": "rows: photo + relit views; maps (diffuse, normal, roughness, specular, "
                "estimator diffuse, confidence); re-renders",
            },
        }
