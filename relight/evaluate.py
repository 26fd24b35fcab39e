"""Table-1-style relighting evaluation (SPEC section 7) on held-out procedural materials.

Protocol:

1. Materials: the first ``count`` held-out seeds (``materials.dataset.EVAL_SEEDS``, never
   trained on), each cropped and resized to ``size`` exactly as the training groups are
   (``RenderedGroups(...).material(i)`` with crop seed ``EVAL_CROP_SEED``), so the
   evaluation measures generalisation to new materials, not to a new image statistic.
2. Lights (``materials.lights``): camera ``EVAL_CAMERA`` = (0, 0, 4); input = the flash
   photo (light at the camera); targets = the 7 ``EVAL_LIGHTS``; ground truth rendered
   by ``kernels.render`` (preset ``dgrsise``).
3. Every method relights the same photos through ``relight.interface.Relighter``, in
   chunks of ``chunk`` materials; seconds per image = the wall time of the ``relight``
   calls / (materials x 7) (model loading excluded).
4. Metrics (``materials.metrics``) on tone-mapped images (clamp, x^(1/2.2)), averaged over
   all materials x lights: MSE, RMSE, PSNR, SSIM, FLIP; LPIPS is "n/a" unless its
   weights are present locally.
5. Stochastic relighters (``stochastic = True``, e.g. diffusion) are run ``samples``
   times with seeded generators: one row for the first sample, and with ``samples > 1``
   one row for the per-pixel mean of the samples (averaging reduces variance).

With ``domain="capture"`` (issue 16) step 2 is the capture pipeline's relighting domain
instead (``materials.capture_domain.CaptureDomain.relighting()`` through
``DomainGroups``): each material gets its own random camera (height, offset, crop of the
plane) and paper-sampled target lights, and the input photo is what a phone gives
(exposure, white balance, noise, clipped highlight, 8-bit, JPEG); the targets are the
unclipped renders of views 1..7 (tone-mapped for the metrics like every target). ``first``
selects the held-out seeds ``EVAL_SEEDS[first:first + count]`` (16: the validation
materials snapshots are chosen on, apart from Table 1's); ``p_crop`` is the share of
photos that show a window of the plane (0: whole planes, as the diffusion relighter's
default ``large="global"`` mode sees every photo).

``evaluate`` returns the result dict; ``write_report`` writes ``relight_eval.md``,
``relight_eval.json`` and ``relight_eval.png`` (rows: material x light; columns: input,
ground truth, each method).
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path

import torch

import kernels
from materials import metrics
from materials.capture_domain import CaptureDomain
from materials.dataset import EVAL_SEEDS, GroupConfig, RenderedGroups
from materials.domain_groups import DomainGroups
from materials.lights import EVAL_CAMERA, EVAL_LIGHTS, eval_lights
from relight.interface import Relighter

__all__ = [
    "EvalConfig",
    "EvalData",
    "load_eval_data",
    "evaluate",
    "write_report",
    "format_table",
    "format_per_material",
    "EVAL_CROP_SEED",
    "step_count",
    "EVAL_DOMAINS",
]

#: ``EvalConfig.domain``'s values.
EVAL_DOMAINS = ("paper", "capture")

#: Seed of the evaluation crops (``GroupConfig.seed``); the materials come from EVAL_SEEDS.
EVAL_CROP_SEED = 0


def step_count(n: int, what: str = "step") -> str:
    """``"1 step"``, ``"10 steps"``: how row labels and reports name a sampling step count."""
    return f"{n} {what}{'s' if n != 1 else ''}"


@dataclass(frozen=True)
class EvalConfig:
    """Evaluation settings (module docstring)."""

    count: int = 16
    size: int = 64
    chunk: int = 4
    samples: int = 1
    seed: int = 0  # generator seed of stochastic relighters
    domain: str = "paper"
    first: int = 0
    p_crop: float = CaptureDomain.p_crop

    def __post_init__(self) -> None:
        if self.domain not in EVAL_DOMAINS:
            raise ValueError(f"domain must be one of {EVAL_DOMAINS}, got {self.domain!r}")
        if not 0 <= self.first < len(EVAL_SEEDS):
            raise ValueError(f"first must be in 0..{len(EVAL_SEEDS) - 1}, got {self.first}")
        if not 1 <= self.count <= len(EVAL_SEEDS) - self.first:
            raise ValueError(
                f"count must be in 1..{len(EVAL_SEEDS) - self.first} (held-out materials from {self.first}), "
                f"got {self.count}"
            )
        CaptureDomain.relighting(self.p_crop)  # checks p_crop where the domain's probabilities are checked
        if self.size < 8:
            raise ValueError(f"size must be at least 8, got {self.size}")
        if self.chunk < 1 or self.samples < 1:
            raise ValueError(f"chunk and samples must be at least 1, got {self.chunk}, {self.samples}")


@dataclass
class EvalData:
    """Held-out photos and ground truth: ``photo [N, 3, H, W]``, ``target [N, 7, 3, H, W]``
    (linear radiance), ``light_pos [N, 7, 3]`` (the targets' lights), ``camera_pos [N, 3]``
    (camera and flash), material ``seeds``."""

    photo: torch.Tensor
    target: torch.Tensor
    light_pos: torch.Tensor
    camera_pos: torch.Tensor
    seeds: list[int] = field(default_factory=list)


def load_eval_data(cfg: EvalConfig) -> EvalData:
    """Render the held-out materials: under the input flash and the 7 evaluation lights
    (``paper``), or as capture-domain groups (``capture``; module docstring)."""
    seeds = EVAL_SEEDS[cfg.first : cfg.first + cfg.count]
    # The materials are generated at GroupConfig's default source size (256 px) and
    # cropped, as in training; a larger evaluation generates them at its own size, so the
    # 64 and 256 px tables keep their materials and 512 px does not upsample a 256 px map.
    source_size = max(GroupConfig.source_size, cfg.size)
    config = GroupConfig(size=cfg.size, source_size=source_size, seed=EVAL_CROP_SEED)
    if cfg.domain == "capture":
        return _capture_domain_data(DomainGroups(seeds, config, CaptureDomain.relighting(cfg.p_crop)))
    groups = RenderedGroups(seeds, config)
    light_pos, camera_pos = eval_lights(include_input=True)  # [8, 3]: flash, then EVAL_LIGHTS
    images = []
    for i in range(cfg.count):
        m = groups.material(i)
        images.append(kernels.render(*(t[None] for t in m.map_tensors()), light_pos, camera_pos)[0])
    images = torch.stack(images)
    n = cfg.count
    return EvalData(
        photo=images[:, 0],
        target=images[:, 1:],
        light_pos=light_pos[1:].expand(n, -1, -1).clone(),
        camera_pos=torch.tensor(EVAL_CAMERA).expand(n, 3).clone(),
        seeds=[int(s) for s in seeds],
    )


def _capture_domain_data(groups: DomainGroups) -> EvalData:
    """Each group's degraded flash photo (view 0) and unclipped views 1.. as targets; the
    relighting domain keeps one camera per group (``CaptureDomain.relighting``)."""
    items = [groups[i] for i in range(len(groups))]
    return EvalData(
        photo=torch.stack([it["images"][0] for it in items]),
        target=torch.stack([it["clean"][1:] for it in items]),
        light_pos=torch.stack([it["light_pos"][1:] for it in items]),
        camera_pos=torch.stack([it["camera_pos"][0] for it in items]),
        seeds=[int(it["seed"]) for it in items],
    )


def _run(relighter: Relighter, data: EvalData, cfg: EvalConfig, sample: int) -> tuple[torch.Tensor, float]:
    outs, seconds = [], 0.0
    for start in range(0, len(data.photo), cfg.chunk):
        sl = slice(start, start + cfg.chunk)
        gen = torch.Generator().manual_seed(cfg.seed * 1000 + sample * 100 + start)
        t0 = time.perf_counter()
        out = relighter.relight(data.photo[sl], data.light_pos[sl], data.camera_pos[sl], generator=gen)
        seconds += time.perf_counter() - t0
        outs.append(out)
    return torch.cat(outs), seconds


def _score(pred: torch.Tensor, target: torch.Tensor) -> dict[str, list[float]]:
    p, t = kernels.tonemap(pred), kernels.tonemap(target)
    return {name: fn(p, t).tolist() for name, (fn, _) in metrics.METRICS.items()}


def evaluate(relighters: dict[str, Relighter], cfg: EvalConfig = EvalConfig(), data: EvalData | None = None) -> dict:
    """Run every relighter on the held-out set; return the result dict.

    Returns:
        ``{"config", "seeds", "lights", "camera", "lpips", "rows": [...], "images"}``;
        each row has ``method``, the mean of each metric, ``seconds_per_image`` and
        ``per_image`` (each metric per material x light, material-major). ``images``
        maps row names to ``[N, 7, 3, H, W]`` predictions (not JSON; for the picture).
    """
    data = load_eval_data(cfg) if data is None else data
    n, k = data.target.shape[:2]
    rows, images, spread = [], {}, {}
    for name, relighter in relighters.items():
        runs = cfg.samples if getattr(relighter, "stochastic", False) else 1
        preds, seconds = [], 0.0
        for s in range(runs):
            pred, sec = _run(relighter, data, cfg, s)
            preds.append(pred)
            seconds += sec
        variants = [(name, preds[0])]
        if runs > 1:
            mean_name = f"{name} (mean of {runs})"
            variants.append((mean_name, torch.stack(preds).mean(0)))
            spread[mean_name] = sample_spread(preds)
        for row_name, pred in variants:
            per_image = _score(pred, data.target)
            row = {"method": row_name}
            row.update({m: sum(v) / len(v) for m, v in per_image.items()})
            # Table 1 averages PSNR per image; PSNR of the mean MSE (never higher, by
            # Jensen) is what a single pooled error gives, reported beside it.
            row["PSNR_of_mean_MSE"] = float(metrics.psnr_from_mse(row["MSE"]))
            row["LPIPS"] = None
            row["seconds_per_image"] = seconds / (runs * n * k)
            row["per_image"] = per_image
            if hasattr(relighter, "steps"):
                row["sampling_steps"] = relighter.steps
            if hasattr(relighter, "large"):  # how it treats a photo above its native size
                row["large"] = relighter.large
            if row_name in spread:
                row["std_error_corr"] = std_error_correlation(spread[row_name], pred, data.target)
            rows.append(row)
            images[row_name] = pred
    return {
        "config": cfg.__dict__.copy(),
        "seeds": data.seeds,
        # paper: the 7 lights and the camera every material shares; capture: per material.
        "lights": [list(p) for p in EVAL_LIGHTS] if cfg.domain == "paper" else data.light_pos.tolist(),
        "camera": list(EVAL_CAMERA) if cfg.domain == "paper" else data.camera_pos.tolist(),
        "lpips": "n/a (no LPIPS weights present locally)" if not metrics.lpips_available() else "not computed",
        "rows": rows,
        "images": images,
        "spread": spread,
        "data": data,
    }


def sample_spread(preds: list[torch.Tensor]) -> torch.Tensor:
    """Per-pixel standard deviation across samples: a confidence map.

    Args:
        preds: S >= 2 predictions ``[N, K, 3, H, W]`` (linear) of one stochastic method.
    Returns:
        ``[N, K, H, W]``: std over samples of the tone-mapped images, averaged over RGB.
    """
    tm = kernels.tonemap(torch.stack(preds))
    return tm.std(dim=0).mean(dim=2)


def std_error_correlation(std: torch.Tensor, pred: torch.Tensor, target: torch.Tensor) -> float:
    """Pearson correlation, over all pixels, between the sample std ``[N, K, H, W]`` and
    the absolute tone-mapped error of ``pred`` (``[N, K, 3, H, W]``, RGB-averaged): how
    far the spread can stand in for the (unknown) error."""
    err = (kernels.tonemap(pred) - kernels.tonemap(target)).abs().mean(dim=2)
    x, y = std.flatten().double(), err.flatten().double()
    x, y = x - x.mean(), y - y.mean()
    denom = float(x.norm() * y.norm())
    return float((x * y).sum()) / denom if denom > 0 else 0.0


def format_table(result: dict) -> str:
    """Markdown table: one row per method."""
    lines = [
        "| method | MSE | RMSE | PSNR (dB) | PSNR of mean MSE | SSIM | FLIP | LPIPS | s / image |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in result["rows"]:
        lpips = "n/a" if r["LPIPS"] is None else f"{r['LPIPS']:.3f}"
        lines.append(
            f"| {r['method']} | {r['MSE']:.4f} | {r['RMSE']:.4f} | {r['PSNR']:.2f} | {r['PSNR_of_mean_MSE']:.2f} | "
            f"{r['SSIM']:.3f} | "
            f"{r['FLIP']:.3f} | {lpips} | {r['seconds_per_image']:.4f} |"
        )
    return "\n".join(lines)


def format_per_material(result: dict) -> str:
    """Markdown table of PSNR per material (mean over its lights), one column per method.

    Reads each row's ``per_image["PSNR"]`` (``N * K`` values, material-major: material
    ``m`` holds ``[m * K, (m + 1) * K)``); the first column is the material's seed.

    The Table-1 PSNR is a mean over images, so a few near-perfect images (a diffuse
    material that the Lambertian re-shading relights exactly) weigh as much as the hard
    ones; this table shows where each method gains or loses its dB.
    """
    rows = result["rows"]
    n_mat = len(result["seeds"])
    k = len(rows[0]["per_image"]["PSNR"]) // n_mat
    head = "| seed | " + " | ".join(r["method"] for r in rows) + " |"
    lines = [head, "|---" * (len(rows) + 1) + "|"]
    for m in range(n_mat):
        cells = [sum(r["per_image"]["PSNR"][m * k : (m + 1) * k]) / k for r in rows]
        lines.append(f"| {result['seeds'][m]} | " + " | ".join(f"{c:.1f}" for c in cells) + " |")
    return "\n".join(lines)


def _picture(result: dict, path: Path, materials: int = 4, lights: tuple[int, ...] = (0, 4)) -> None:
    """Rows: the ``materials`` held-out materials that change most under relighting
    (largest tone-mapped MSE between the photo and its targets), each under ``lights``;
    columns: input, ground truth, each method."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    data: EvalData = result["data"]
    names = list(result["images"])
    change = ((kernels.tonemap(data.photo[:, None]) - kernels.tonemap(data.target)) ** 2).mean(dim=(1, 2, 3, 4))
    chosen = sorted(change.argsort(descending=True)[: min(materials, len(change))].tolist())
    rows = [(m, l) for m in chosen for l in lights if l < data.target.shape[1]]
    cols = ["input (flash)", "ground truth"] + names
    fig, axes = plt.subplots(len(rows), len(cols), figsize=(1.6 * len(cols), 1.6 * len(rows)), dpi=100, squeeze=False)
    for r, (m, l) in enumerate(rows):
        cells = [data.photo[m], data.target[m, l]] + [result["images"][nm][m, l] for nm in names]
        for c, img in enumerate(cells):
            ax = axes[r, c]
            ax.imshow(kernels.tonemap(img).permute(1, 2, 0).clamp(0, 1).numpy(), interpolation="nearest")
            ax.set_xticks([])
            ax.set_yticks([])
            if r == 0:
                ax.set_title(cols[c], fontsize=8)
            if c == 0:
                ax.set_ylabel(f"seed {data.seeds[m]}\nlight {l + 1}", fontsize=7)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def _confidence_picture(result: dict, name: str, path: Path, materials: int = 4, light: int = 0) -> None:
    """Rows: held-out materials (the first ``materials``); columns: photo, ground truth,
    mean of the samples, |error| of the mean, per-pixel std across samples (same scale)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    data: EvalData = result["data"]
    mean, std = result["images"][name], result["spread"][name]
    err = (kernels.tonemap(mean) - kernels.tonemap(data.target)).abs().mean(dim=2)
    m_count = min(materials, mean.shape[0])
    vmax = float(torch.quantile(torch.cat([err[:m_count, light].flatten(), std[:m_count, light].flatten()]), 0.99))
    cols = ["input (flash)", "ground truth", name, "|error| of the mean", "std across samples"]
    fig, axes = plt.subplots(m_count, len(cols), figsize=(1.8 * len(cols), 1.8 * m_count), dpi=100, squeeze=False)
    for r in range(m_count):
        cells = [data.photo[r], data.target[r, light], mean[r, light]]
        for c in range(len(cols)):
            ax = axes[r, c]
            if c < 3:
                ax.imshow(kernels.tonemap(cells[c]).permute(1, 2, 0).clamp(0, 1).numpy(), interpolation="nearest")
            else:
                ax.imshow(
                    (err if c == 3 else std)[r, light].numpy(),
                    cmap="magma",
                    vmin=0,
                    vmax=max(vmax, 1e-6),
                    interpolation="nearest",
                )
            ax.set_xticks([])
            ax.set_yticks([])
            if r == 0:
                ax.set_title(cols[c], fontsize=7)
            if c == 0:
                ax.set_ylabel(f"seed {data.seeds[r]}\nlight {light + 1}", fontsize=7)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def write_report(result: dict, folder: Path, command: str | None = None) -> list[Path]:
    """Write ``relight_eval.md`` (table), ``relight_eval.json`` (rows with per-image
    values, config, seeds, lights) and ``relight_eval.png`` into an existing ``folder``."""
    folder = Path(folder)
    cfg = result["config"]
    md = [
        "# Relighting evaluation (Table 1 style)",
        "",
        f"{cfg['count']} held-out procedural materials (seeds {result['seeds'][0]}..{result['seeds'][-1]}) at "
        f"{cfg['size']}x{cfg['size']}, 7 evaluation lights, camera {tuple(result['camera'])}, input = flash photo. "
        "Metrics on tone-mapped images (clamp, x^(1/2.2)), mean over materials x lights. "
        f"LPIPS: {result['lpips']}.",
        "",
    ]
    if command:
        md += [f"Command: `{command}`", ""]
    md += [format_table(result), ""]
    for r in result["rows"]:
        if "sampling_steps" in r:
            md.append(f"{r['method']}: {step_count(r['sampling_steps'], 'sampling step')} per sample.")
        if "std_error_corr" in r:
            md.append(
                f"{r['method']}: Pearson correlation between the per-pixel std across samples and the "
                f"absolute error of the mean: {r['std_error_corr']:.3f}."
            )
    md += ["", "## PSNR per material (dB, mean over the lights)", "", format_per_material(result), ""]
    paths = [folder / "relight_eval.md", folder / "relight_eval.json", folder / "relight_eval.png"]
    paths[0].write_text("\n".join(md))
    for name in result.get("spread", {}):
        slug = "".join(ch if ch.isalnum() else "_" for ch in name).strip("_")
        paths.append(folder / f"confidence_{slug}.png")
        _confidence_picture(result, name, paths[-1])
    blob = {k: v for k, v in result.items() if k not in ("images", "data", "spread")}
    if command:
        blob["command"] = command
    paths[1].write_text(json.dumps(blob, indent=1))
    _picture(result, paths[2])
    return paths
