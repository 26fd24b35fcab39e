"""``relight eval capture``: the paper's Tables 2 and 4 for the whole capture pipeline.

Each held-out material becomes an 8-bit flash photo, rendered by our renderer at the
default phone camera (``materials.camera.camera_from_fov()``: (0, 0, 4.83), 45 degrees
over the square photo) with the flash's 1/d^2 falloff at auto-exposure intensity
``pi h^2`` (``CaptureScene.render_kwargs``: what ``relight capture`` assumes), tone-mapped,
rounded to 8 bits and decoded back to linear radiance, as a phone's PNG would be. Then
``CapturePipeline`` runs once per row of ``RUNS`` on the same photo:

=================  ========================================================  ======
run                what the estimator and the refinement see                  inputs
=================  ========================================================  ======
``alone``          the photo (``--relit 0``)                                  1
``diffusion3``     the photo + 3 views relit by the diffusion model           4
``diffusion``      the photo + 7 views relit by the diffusion model           8
``bieron``         the photo + 7 views relit by the Bieron-style network      8
``gt``             the photo + 7 ground-truth renders (8-bit, like a relit)   8
=================  ========================================================  ======

Table 2 is ``alone / diffusion / bieron / gt``, Table 4 ``alone / diffusion3 / diffusion``
(1, 4 and 8 inputs; the paper's 1 / 4 / 8). All runs use the pipeline's defaults
(refinement steps, relit-view weight, one DDIM step), seed 0.

Scores, per material and run (``score``):

- map MSE of diffuse, normal, roughness, specular (maps in [0, 1] / unit normals, at the
  photo's resolution), and the diffuse MSE inside the flash highlight
  (``materials.highlight.highlight_mask``: the region the paper is about);
- re-render PSNR / SSIM / FLIP: predicted and true maps rendered under ``NOVEL_LIGHTS``
  (128 lights drawn once from the paper's training distribution, x, y ~ U[-4, 4],
  z ~ U[4, 8], seed ``NOVEL_LIGHT_SEED``; none is a relighting light) from the capture
  camera, tone-mapped; PSNR of the MSE pooled over lights and pixels, SSIM the mean over
  lights, FLIP (``materials.metrics.flip``, slow: ~0.1 s an image) the mean over every
  ``flip_every``-th light;
- ``relit_psnr``: the relit views against the true maps rendered under their lights
  (what the relighter contributed), for runs with relit views.

Data sets (``SETS``):

- ``procedural``: ``materials.dataset.EVAL_SEEDS[:count]`` at ``size`` px (never trained on).
- ``inria``: INRIA five-panel PNGs (``materials.io.read_inria``; 8-bit maps). With
  ``inria`` a folder, its ``*.png`` files (e.g. ``relight synth --format inria`` output, or
  real INRIA data a user has); none: ``EVAL_SEEDS[count:2 count]`` written with
  ``write_inria`` to a temporary folder and read back, the same files ``relight synth
  --format inria`` writes.
- ``textures``: every material folder under ``textures`` (``load_texture_folder``:
  diffuse, normal, roughness, specular PNGs), e.g. ``../shared/data/real-dev/materials``;
  the textures' own resolution, cropped to ``size`` at the centre when larger.

With ``photo_vignetting`` the photo (not the ground-truth views) is multiplied by the
darkening gain ``matcap.capture.vignetting.vignetting_gain`` of those coefficients about
its centre before the 8-bit step: a phone flash's beam and lens vignetting, which real
photos have and the renderer does not; the maps are still scored against the true ones.
"""

from __future__ import annotations

import json
import math
import tempfile
import time
from collections.abc import Callable, Iterator, Mapping
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import torch
from tqdm import tqdm

import kernels
from estimator.model import SVBRDFEstimator
from matcap.capture import CaptureConfig, CaptureOutput, CapturePipeline, area_downsample, photo_from_tensor
from matcap.capture.provenance import component_settings
from matcap.capture.vignetting import vignetting_basis, vignetting_gain
from materials import metrics
from materials.camera import camera_from_fov
from materials.highlight import highlight_mask
from materials.io.photo import MIN_PHOTO_SIDE
from materials.types import Material
from relight.interface import Relighter

__all__ = [
    "RUNS",
    "TABLE2",
    "TABLE4",
    "SETS",
    "NOVEL_LIGHT_COUNT",
    "NOVEL_LIGHT_SEED",
    "EVAL_MARKER",
    "CaptureEvalConfig",
    "EvalMaterial",
    "GroundTruthRelighter",
    "novel_lights",
    "flash_photo",
    "photo_render_kwargs",
    "as_8bit",
    "load_materials",
    "score",
    "evaluate",
    "format_tables",
    "write_report",
]

#: Run name -> (relighter: registry name, "gt" or None; number of relit views).
RUNS: dict[str, tuple[str | None, int]] = {
    "alone": (None, 0),
    "diffusion3": ("diffusion", 3),
    "diffusion": ("diffusion", 7),
    "bieron": ("bieron", 7),
    "gt": ("gt", 7),
}
#: The paper's Table 2 rows (photo alone, + relit by two relighters, + ground truth).
TABLE2 = ("alone", "diffusion", "bieron", "gt")
#: The paper's Table 4 rows: 1, 4 and 8 inputs.
TABLE4 = ("alone", "diffusion3", "diffusion")
SETS = ("procedural", "inria", "textures")
#: Novel lights of the re-render scores (the paper uses 128 for its Table 2).
NOVEL_LIGHT_COUNT = 128
NOVEL_LIGHT_SEED = 20251215
#: File that marks a folder written by ``relight eval capture`` (safe to --overwrite).
EVAL_MARKER = "capture_eval.json"
#: Columns of the tables: (row key, header, higher is better).
COLUMNS = (
    ("psnr", "PSNR", True),
    ("ssim", "SSIM", True),
    ("flip", "FLIP", False),
    ("mse_diffuse", "MSE D", False),
    ("mse_normal", "MSE N", False),
    ("mse_roughness", "MSE R", False),
    ("mse_specular", "MSE S", False),
    ("mse_diffuse_highlight", "MSE D highlight", False),
    ("relit_psnr", "relit PSNR", True),
)


@dataclass(frozen=True)
class CaptureEvalConfig:
    """Settings of ``evaluate`` (module docstring).

    Attributes:
        sets: data sets, of ``SETS``.
        count: materials of the ``procedural`` set and of the synthesised ``inria`` set.
        size: map side of the procedural and synthesised INRIA materials, pixels; the
            largest side of a texture material (centre crop).
        runs: rows, of ``RUNS``.
        textures: folder of texture material folders (needed by the ``textures`` set).
        inria: folder of INRIA PNGs (None: synthesised from held-out seeds).
        capture: the pipeline's settings (``relit`` is set per run).
        flip_every: FLIP on every this-many-th novel light (FLIP is the slow metric).
        photo_vignetting: coefficients of the radial gain applied to the photo (module
            docstring; each <= 0); empty: none.
        photo_offset: ``(x, y)`` scene units: the photo's camera and flash sit this far
            from above the centre (a photo taken off-centre), and the novel-light scores
            are rendered from there. The pipeline is told the centred camera, unless its
            ``capture.flash_point`` is ``"auto"`` (then it locates the flash itself).
    """

    sets: tuple[str, ...] = ("procedural", "inria")
    count: int = 8
    size: int = 256
    runs: tuple[str, ...] = tuple(RUNS)
    textures: str | None = None
    inria: str | None = None
    capture: CaptureConfig = field(default_factory=CaptureConfig)
    flip_every: int = 8
    photo_vignetting: tuple[float, ...] = ()
    photo_offset: tuple[float, float] = (0.0, 0.0)

    def __post_init__(self) -> None:
        if len(self.photo_offset) != 2 or not all(math.isfinite(v) for v in self.photo_offset):
            raise ValueError(f"photo_offset must be two finite numbers, got {self.photo_offset}")
        if not all(math.isfinite(a) and a <= 0 for a in self.photo_vignetting):
            raise ValueError(f"photo_vignetting must be finite numbers <= 0, got {self.photo_vignetting}")
        unknown = [s for s in self.sets if s not in SETS] + [r for r in self.runs if r not in RUNS]
        if unknown:
            raise ValueError(f"unknown sets or runs {unknown}; sets: {', '.join(SETS)}; runs: {', '.join(RUNS)}")
        if not self.sets or not self.runs:
            raise ValueError("need at least one set and one run")
        if self.count < 1 or self.size < MIN_PHOTO_SIDE or self.flip_every < 1:
            raise ValueError(
                f"need count >= 1, size >= {MIN_PHOTO_SIDE} (the smallest photo) and flip_every >= 1, "
                f"got {self.count}, {self.size}, {self.flip_every}"
            )
        if "textures" in self.sets and self.textures is None:
            raise ValueError("the textures set needs a folder of texture materials (--textures)")

    def to_dict(self) -> dict:
        out = asdict(self)
        out["capture"] = self.capture.to_dict()
        return out


@dataclass
class EvalMaterial:
    """One held-out material: its set, a name and the true maps (unbatched, ``[C, S, S]``)."""

    set: str
    name: str
    material: Material


def novel_lights(count: int = NOVEL_LIGHT_COUNT, seed: int = NOVEL_LIGHT_SEED) -> torch.Tensor:
    """``[count, 3]`` float32 light positions, x, y ~ U[-4, 4], z ~ U[4, 8] (the paper's
    training distribution, SPEC section 3), drawn from a fixed seed.

    Example:
        >>> lights = novel_lights(4)
        >>> tuple(lights.shape), bool((lights[:, 2] >= 4).all())
        ((4, 3), True)
    """
    g = torch.Generator().manual_seed(seed)
    u = torch.rand(count, 3, generator=g, dtype=torch.float64)
    lo = torch.tensor([-4.0, -4.0, 4.0], dtype=torch.float64)
    hi = torch.tensor([4.0, 4.0, 8.0], dtype=torch.float64)
    return (lo + (hi - lo) * u).float()


def photo_render_kwargs(camera: torch.Tensor, falloff: bool = True) -> dict:
    """``kernels.render`` keywords of the photo's lighting: 1/d^2 falloff at auto-exposure
    intensity pi h^2 (``CaptureScene.render_kwargs``), or none."""
    if not falloff:
        return {"preset": "dgrsise"}
    h = float(camera[2])
    return {"preset": "dgrsise", "inverse_square": True, "intensity": math.pi * h * h}


def as_8bit(linear: torch.Tensor) -> torch.Tensor:
    """Linear radiance through the tone map, rounded to 8 bits, decoded back (a PNG)."""
    return kernels.inverse_tonemap(torch.round(kernels.tonemap(linear) * 255) / 255)


def flash_photo(material: Material, camera: torch.Tensor, falloff: bool = True) -> torch.Tensor:
    """``[3, S, S]`` linear radiance of ``material`` (unbatched) lit by a flash at
    ``camera`` ``[3]``, with 1/d^2 falloff or without, before the 8-bit step (``as_8bit``)."""
    maps = [t[None] for t in material.map_tensors()]
    return kernels.render(*maps, camera[None, None], camera, **photo_render_kwargs(camera, falloff))[0, 0]


class GroundTruthRelighter(Relighter):
    """The true maps rendered under the target lights at full resolution (no falloff, the
    relighters' convention), area-downsampled to the photo given, then 8-bit like a photo:
    the "1 + 7 ground-truth renders" row of Table 2, through the same pipeline."""

    name = "ground truth"

    def __init__(self, material: Material):
        self.maps = [t[None] for t in material.map_tensors()]

    def _relight(self, photo, light_pos, camera_pos, *, generator=None):
        full = kernels.render(*self.maps, light_pos, camera_pos[:, None])
        return as_8bit(area_downsample(full, photo.shape[-1])).to(photo.dtype)


def _center_crop(material: Material, size: int) -> Material:
    h, w = material.shape
    side = min(h, w, size)
    return material.crop((h - side) // 2, (w - side) // 2, side, side)


def load_materials(cfg: CaptureEvalConfig) -> Iterator[EvalMaterial]:
    """The held-out materials of ``cfg.sets`` (module docstring), one at a time."""
    from materials.dataset import EVAL_SEEDS
    from materials.procedural import family_of, generate

    if "procedural" in cfg.sets:
        for seed in EVAL_SEEDS[: cfg.count]:
            yield EvalMaterial("procedural", f"{seed}_{family_of(seed)}", generate(seed, size=cfg.size))
    if "inria" in cfg.sets:
        yield from _inria_materials(cfg)
    if "textures" in cfg.sets:
        from materials.domain_groups import load_texture_folder

        folder = Path(str(cfg.textures))
        if not folder.is_dir():
            raise FileNotFoundError(f"textures: {folder} is not a folder")
        subfolders = sorted(p for p in folder.iterdir() if p.is_dir())
        if not subfolders:
            raise FileNotFoundError(f"textures: {folder} holds no material folders")
        for sub in subfolders:
            yield EvalMaterial("textures", sub.name, _center_crop(load_texture_folder(sub), cfg.size))


def _inria_materials(cfg: CaptureEvalConfig) -> Iterator[EvalMaterial]:
    from materials.io.inria import read_inria, write_inria

    def read_all(files: list[Path]) -> Iterator[EvalMaterial]:
        for path in files:
            material, _ = read_inria(path)
            yield EvalMaterial("inria", path.stem, material)

    if cfg.inria is not None:
        files = sorted(Path(cfg.inria).glob("*.png"))
        if not files:
            raise FileNotFoundError(f"inria: {cfg.inria} holds no .png files")
        yield from read_all(files[: cfg.count])
        return
    from materials.dataset import EVAL_SEEDS
    from materials.lights import EVAL_CAMERA
    from materials.procedural import family_of, generate

    flash = torch.tensor([EVAL_CAMERA])
    with tempfile.TemporaryDirectory(prefix="capture-eval-inria-") as tmp:
        files = []
        for seed in EVAL_SEEDS[cfg.count : 2 * cfg.count]:
            material = generate(seed, size=cfg.size)
            render = kernels.render(*(t[None] for t in material.map_tensors()), flash, flash[0])[0, 0]
            files.append(write_inria(Path(tmp) / f"{seed}_{family_of(seed)}.png", material, render))
        yield from read_all(files)


def score(
    out: CaptureOutput,
    true: Material,
    flash: torch.Tensor,
    camera: torch.Tensor,
    lights: torch.Tensor,
    flip_every: int,
) -> dict[str, float]:
    """Scores of one capture against the true maps (module docstring).

    Args:
        out: the pipeline's output (maps on the photo's grid, ``[C, S, S]``).
        true: the true maps, unbatched ``[C, S, S]``.
        flash: ``[3, S, S]`` the photo's linear render before 8 bits (highlight mask).
        camera: ``[3]`` the capture camera; lights: ``[L, 3]`` novel lights.
        flip_every: FLIP on every this-many-th light.
    """
    pred = out.material
    camera_pos = camera[None].expand(lights.shape[0], 3)
    with torch.no_grad():
        a = kernels.tonemap(
            kernels.render(
                *(t[None] for t in pred.map_tensors()), lights[None], camera_pos[None], **out.scene.render_kwargs
            )[0]
        )
        b = kernels.tonemap(
            kernels.render(
                *(t[None] for t in true.map_tensors()), lights[None], camera_pos[None], **photo_render_kwargs(camera)
            )[0]
        )
    mask = highlight_mask(flash[None], camera.tolist())[0, 0]
    diffuse_se = ((pred.diffuse - true.diffuse) ** 2).mean(0)
    row = {
        "psnr": float(metrics.psnr_from_mse(metrics.mse(a, b).mean())),
        "ssim": float(metrics.ssim(a, b).mean()),
        "flip": float(metrics.flip(a[::flip_every], b[::flip_every]).mean()),
        "mse_diffuse": float(diffuse_se.mean()),
        "mse_normal": float(((pred.normal - true.normal) ** 2).mean()),
        "mse_roughness": float(((pred.roughness - true.roughness) ** 2).mean()),
        "mse_specular": float(((pred.specular - true.specular) ** 2).mean()),
        "mse_diffuse_highlight": float(diffuse_se[mask].mean()) if bool(mask.any()) else float("nan"),
    }
    if out.relit.shape[0]:
        maps = [t[None] for t in true.map_tensors()]
        ref = area_downsample(kernels.render(*maps, out.scene.relit_light_pos[None], camera)[0], out.relit.shape[-1])
        row["relit_psnr"] = float(metrics.psnr(kernels.tonemap(out.relit), kernels.tonemap(ref)).mean())
    return row


def evaluate(
    cfg: CaptureEvalConfig,
    estimator: SVBRDFEstimator,
    relighters: Mapping[str, Relighter],
    *,
    progress: bool = True,
    on_row: Callable[[dict], None] | None = None,
) -> dict:
    """Run every ``cfg.runs`` row on every material of ``cfg.sets``.

    Args:
        cfg: the settings.
        estimator: the estimator of every run.
        relighters: registry name -> ``Relighter`` for the runs that need one
            (``diffusion``, ``bieron``); the ground truth is made here.
        progress: a bar over material x run.
        on_row: called with each row as it is made (e.g. to log it).

    Returns:
        ``{"config", "relighters", "rows", "summary", "seconds"}``: one row per (material, run) with the
        ``score`` keys, ``set``, ``material``, ``run``, ``inputs`` and ``seconds``; the
        summary's means per (set, run).
    """
    missing = sorted({RUNS[r][0] for r in cfg.runs} - {None, "gt"} - set(relighters))
    if missing:
        raise ValueError(f"runs {list(cfg.runs)} need relighters {missing}")
    centred = camera_from_fov()
    camera = centred + torch.tensor([*cfg.photo_offset, 0.0])
    # What the pipeline is told: the centred camera, or nothing when it locates the flash.
    told = None if cfg.capture.flash_point == "auto" else tuple(centred.tolist())
    lights = novel_lights()
    rows: list[dict] = []
    start = time.perf_counter()
    bar = tqdm(desc="eval capture", unit="run", disable=not progress)
    for item in load_materials(cfg):
        flash = flash_photo(item.material, camera)
        seen = flash
        if cfg.photo_vignetting:
            side = flash.shape[-1]
            basis = vignetting_basis(side, ((side - 1) / 2, (side - 1) / 2), len(cfg.photo_vignetting))
            seen = flash * vignetting_gain(torch.tensor(cfg.photo_vignetting), basis)
        photo = photo_from_tensor(as_8bit(seen), f"{item.name} (rendered)", fmt="png")
        for run in cfg.runs:
            kind, k = RUNS[run]
            relighter = GroundTruthRelighter(item.material) if kind == "gt" else relighters.get(kind) if kind else None
            # Samples apply to a sampling relighter only (the others refuse them).
            samples = cfg.capture.samples if getattr(relighter, "stochastic", False) else 1
            config = replace(cfg.capture, relit=k, camera=told, samples=samples)
            pipe = CapturePipeline(relighter, estimator, config=config)
            t0 = time.perf_counter()
            out = pipe(photo)
            seconds = time.perf_counter() - t0
            row = {"set": item.set, "material": item.name, "run": run, "inputs": 1 + k}
            row.update(score(out, item.material, flash, camera, lights, cfg.flip_every))
            row["seconds"] = round(seconds, 2)
            rows.append(row)
            if on_row is not None:
                on_row(row)
            bar.update(1)
    bar.close()
    return {
        "config": cfg.to_dict(),
        # Settings that live on the relighters, not in ``cfg`` (sampling steps, the mode
        # for photos above their native size): two reports differ in them too.
        "relighters": {name: relighter_settings(r) for name, r in relighters.items()},
        "camera": camera.tolist(),
        "camera_told": None if told is None else list(told),
        "novel_lights": {"count": NOVEL_LIGHT_COUNT, "seed": NOVEL_LIGHT_SEED},
        "rows": rows,
        "summary": summarize(rows),
        "seconds": round(time.perf_counter() - start, 1),
    }


def relighter_settings(relighter: Relighter) -> dict:
    """A relighter's class and the settings it carries (``component_settings``: ``steps``,
    ``num_samples``, ``large``, where it has them)."""
    return {"class": type(relighter).__name__, **component_settings(relighter)}


def summarize(rows: list[dict]) -> list[dict]:
    """Means per (set, run) over materials (NaN entries, e.g. no highlight, skipped)."""
    out = []
    for key in dict.fromkeys((r["set"], r["run"]) for r in rows):
        sel = [r for r in rows if (r["set"], r["run"]) == key]
        mean = {"set": key[0], "run": key[1], "inputs": sel[0]["inputs"], "count": len(sel)}
        for name, _, _ in COLUMNS:
            values = [r[name] for r in sel if name in r and not math.isnan(r[name])]
            if values:
                mean[name] = sum(values) / len(values)
        out.append(mean)
    return out


def _cell(value: float | None, name: str) -> str:
    if value is None:
        return ""
    return f"{value:.2f}" if name in ("psnr", "relit_psnr") else f"{value:.4f}"


def format_tables(report: dict) -> str:
    """Markdown: per set, Table 2 (rows ``TABLE2``, PSNR gain over ``alone``) and Table 4
    (rows ``TABLE4``), of the runs present."""
    lines: list[str] = []
    summary = report["summary"]
    for set_name in dict.fromkeys(s["set"] for s in summary):
        by_run = {s["run"]: s for s in summary if s["set"] == set_name}
        count = next(iter(by_run.values()))["count"]
        base = by_run.get("alone", {}).get("psnr")
        for title, runs in (("Table 2", TABLE2), ("Table 4", TABLE4)):
            present = [r for r in runs if r in by_run]
            if len(present) < 2:
                continue
            lines += [f"### {set_name} ({count} materials): {title}", ""]
            header = ["run", "inputs", *(h for _, h, _ in COLUMNS), "PSNR vs alone"]
            lines += ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
            for run in present:
                s = by_run[run]
                gain = "" if base is None or run == "alone" else f"{s['psnr'] - base:+.2f}"
                cells = [run, str(s["inputs"]), *(_cell(s.get(k), k) for k, _, _ in COLUMNS), gain]
                lines.append("| " + " | ".join(cells) + " |")
            lines.append("")
    return "\n".join(lines)


def write_report(report: dict, folder: Path, command: str | None = None) -> list[Path]:
    """``capture_eval.json`` (config, every row, summary) and ``capture_eval.md`` (tables)."""
    folder.mkdir(parents=True, exist_ok=True)
    data = dict(report, command=command) if command else report
    json_path = folder / EVAL_MARKER
    json_path.write_text(json.dumps(data, indent=2) + "\n")
    md = folder / "capture_eval.md"
    head = [f"# Capture evaluation ({report['seconds']} s)", ""]
    if command:
        head += ["    " + command, ""]
    md.write_text("\n".join(head) + format_tables(report) + "\n")
    return [json_path, md]
