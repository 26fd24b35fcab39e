"""Evaluate the estimator on held-out procedural materials (SPEC sections 5 and 7).

For each held-out material (a prefix of ``materials.dataset.EVAL_SEEDS``), the inputs are
rendered under the fixed evaluation set (``materials.lights.eval_lights``: camera
(0, 0, 4), view 0 the flash at the camera, then the 7 ``EVAL_LIGHTS``). The estimator
sees 1 input (the flash photo) or 8 (flash + 7), each without and with test-time
refinement (``estimator.refine.refine``). Reported per configuration, averaged over the
materials:

- map MSE of diffuse, normal, roughness, specular against the ground truth;
- re-rendered PSNR and SSIM (``materials.metrics``): predicted and true maps rendered
  under ``HELDOUT_LIGHTS`` (16 positions, none of them an input light), tone-mapped
  (``kernels.tonemap``), PSNR from the MSE over all lights and pixels per material, SSIM
  (11 x 11 Gaussian window) averaged over lights and pixels.

The strong-highlight check: on the most specular third of the materials (score
``mean(specular) * (1 - mean(roughness))``), the diffuse-map MSE inside the flash
highlight (pixels whose tone-mapped flash image is near saturation, or within
``materials.highlight.HIGHLIGHT_RADIUS`` of the mirror point under the camera), 1 vs 8 inputs. This is where a
single flash photo bakes the highlight into the albedo (SPEC section 1).

``python -m estimator evaluate --model PATH --num 16 --size 64 --refine-steps 100``
(``estimator/__main__.py``) writes ``estimator_eval.md`` and ``estimator_eval.json`` to ``--out``.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import torch
from tqdm.auto import tqdm

import kernels
from estimator.model import SVBRDFEstimator
from estimator.refine import refine
from materials import metrics
from materials.dataset import EVAL_SEEDS, GroupConfig, RenderedGroups
from materials.highlight import highlight_mask
from materials.io.atomic import atomic_file
from materials.lights import EVAL_CAMERA, EVAL_LIGHTS, eval_lights
from materials.types import Material

__all__ = [
    "evaluate",
    "write_report",
    "HELDOUT_LIGHTS",
    "specular_score",
    "EvalRow",
    "rerender_metrics",
]

#: 16 held-out lights for the re-rendered metrics (camera at ``EVAL_CAMERA``): an outer
#: ring of 8 at radius 3.2, height 4.5 (angles 22.5 + 45k degrees; mirror highlights at
#: radius 1.35, near the plane's edge), and an inner ring of 8 at radius 1.5, height 6.5
#: (angles 45k degrees; highlights at radius 0.57). None is an input light: the input
#: set is the camera position plus ``EVAL_LIGHTS`` (checked in the tests).
HELDOUT_LIGHTS: tuple[tuple[float, float, float], ...] = (
    (2.956, 1.225, 4.5),
    (1.225, 2.956, 4.5),
    (-1.225, 2.956, 4.5),
    (-2.956, 1.225, 4.5),
    (-2.956, -1.225, 4.5),
    (-1.225, -2.956, 4.5),
    (1.225, -2.956, 4.5),
    (2.956, -1.225, 4.5),
    (1.5, 0.0, 6.5),
    (1.061, 1.061, 6.5),
    (0.0, 1.5, 6.5),
    (-1.061, 1.061, 6.5),
    (-1.5, 0.0, 6.5),
    (-1.061, -1.061, 6.5),
    (0.0, -1.5, 6.5),
    (1.061, -1.061, 6.5),
)
#: Crop seed of the evaluation materials (``GroupConfig.seed``); the materials are
#: ``EVAL_SEEDS``, disjoint from the training seeds.
EVAL_CROP_SEED = 0

MAP_NAMES = ("diffuse", "normal", "roughness", "specular")


@dataclass
class EvalRow:
    """Mean metrics of one configuration (inputs, refined) over ``count`` materials."""

    inputs: int
    refined: bool
    count: int
    mse_diffuse: float
    mse_normal: float
    mse_roughness: float
    mse_specular: float
    psnr: float
    ssim: float
    seconds: float


def heldout_lights() -> tuple[torch.Tensor, torch.Tensor]:
    """(light_pos ``[16, 3]``, camera_pos ``[16, 3]``) float32: ``HELDOUT_LIGHTS`` seen from ``EVAL_CAMERA``."""
    light_pos = torch.tensor(HELDOUT_LIGHTS, dtype=torch.float32)
    return light_pos, torch.tensor(EVAL_CAMERA, dtype=torch.float32).expand_as(light_pos).clone()


def specular_score(material: Material) -> torch.Tensor:
    """Per-material specularity ``mean(specular) * (1 - mean(roughness))``: high for
    bright, sharp highlights. ``[B]`` for a batched material."""
    return material.specular.mean((-3, -2, -1)) * (1 - material.roughness.mean((-3, -2, -1)))


def rerender_metrics(pred: Material, true: Material) -> tuple[torch.Tensor, torch.Tensor]:
    """Per-material PSNR and SSIM ``[B]`` (float64) of tone-mapped renders under
    ``HELDOUT_LIGHTS``: PSNR of the MSE pooled over the lights, SSIM averaged over them."""
    light_pos, camera_pos = (t.to(pred.device) for t in heldout_lights())
    with torch.no_grad():
        a = kernels.tonemap(kernels.render(*pred.map_tensors(), light_pos, camera_pos))
        b = kernels.tonemap(kernels.render(*true.map_tensors(), light_pos, camera_pos))
    per_material = a.shape[:2]  # [B, K]: every image has H x W pixels, so the mean of
    # the per-image MSEs is the MSE over all lights and pixels.
    mse = metrics.mse(a, b).view(per_material).mean(1)
    ssim = metrics.ssim(a, b).view(per_material).mean(1)
    return metrics.psnr_from_mse(mse), ssim


def evaluate(
    model: SVBRDFEstimator,
    seeds: Sequence[int] = EVAL_SEEDS[:16],
    size: int = 64,
    *,
    refine_steps: int = 0,
    source_size: int | None = None,
    batch_size: int = 8,
    render_loss_fn: Callable[..., torch.Tensor] = kernels.rendering_loss,
    progress: bool = True,
    out_dir: str | Path | None = None,
) -> dict:
    """Evaluate ``model`` (module docstring) and optionally write the report.

    Args:
        model: the estimator (evaluated in float32, ``eval()`` mode, not modified).
        seeds: held-out material seeds (default: the first 16 ``EVAL_SEEDS``).
        size: image side in pixels; ``source_size`` (None: ``2 * size``, as in training)
            is the resolution the materials are generated at before the crop.
        refine_steps: > 0 adds refined rows (``refine`` per material, this many steps).
        batch_size: materials per forward pass (refinement always runs per material,
            since the adapter heads it fine-tunes are shared by a batch).
        render_loss_fn: the renderer used by refinement.
        out_dir: when given, write ``estimator_eval.md`` and ``estimator_eval.json`` there.
    Returns:
        ``{"rows": [EvalRow as dict, ...], "highlight": [...], "meta": {...}}``.
    """
    seeds = list(seeds)
    if not seeds:
        raise ValueError("seeds must not be empty")
    data = RenderedGroups(seeds, GroupConfig(size=size, source_size=source_size or 2 * size, seed=EVAL_CROP_SEED))
    was_training = model.training
    model.eval()
    device = next(model.parameters()).device
    light_pos8, camera_pos8 = (t.to(device) for t in eval_lights(include_input=True))
    configs = [(n, r) for n in (1, 8) for r in ((False, True) if refine_steps > 0 else (False,))]
    per = {c: {k: [] for k in (*MAP_NAMES, "psnr", "ssim", "hl_diffuse")} for c in configs}
    seconds = dict.fromkeys(configs, 0.0)
    scores, has_mask = [], []

    bar = tqdm(total=len(seeds), desc="evaluate", disable=not progress)
    for start in range(0, len(seeds), batch_size):
        true = Material.stack([data.material(i) for i in range(start, min(start + batch_size, len(seeds)))]).to(device)
        b = true.diffuse.shape[0]
        with torch.no_grad():
            images = kernels.render(*true.map_tensors(), light_pos8, camera_pos8)  # [b, 8, 3, H, W]
        mask = highlight_mask(images[:, 0], EVAL_CAMERA)
        scores.append(specular_score(true))
        has_mask.append(mask.flatten(1).any(1))
        for n, refined in configs:
            views = slice(0, n)
            inp = images[:, views]
            light_pos, camera_pos = light_pos8[views].expand(b, n, 3), camera_pos8[views].expand(b, n, 3)
            tick = time.perf_counter()
            if refined:
                preds = [
                    refine(
                        model,
                        inp[i : i + 1],
                        light_pos[i : i + 1],
                        camera_pos[i : i + 1],
                        steps=refine_steps,
                        render_loss_fn=render_loss_fn,
                        progress=False,
                    ).material
                    for i in range(b)
                ]
                pred = Material(**{k: torch.cat([getattr(p, k) for p in preds]) for k in MAP_NAMES})
            else:
                with torch.no_grad():
                    pred = model(inp, light_pos, camera_pos)
            seconds[(n, refined)] += time.perf_counter() - tick
            for name, p, t in zip(MAP_NAMES, pred.map_tensors(), true.map_tensors()):
                per[(n, refined)][name].append(((p - t) ** 2).mean((1, 2, 3)))
            psnr, ssim = rerender_metrics(pred, true)
            per[(n, refined)]["psnr"].append(psnr)
            per[(n, refined)]["ssim"].append(ssim)
            err = ((pred.diffuse - true.diffuse) ** 2).mean(1, keepdim=True)
            inside = (err * mask).flatten(1).sum(1) / mask.flatten(1).sum(1).clamp_min(1)
            per[(n, refined)]["hl_diffuse"].append(inside)
        bar.update(b)
    bar.close()
    model.train(was_training)

    scores_t, has_mask_t = torch.cat(scores), torch.cat(has_mask)
    k = max(1, math.ceil(len(seeds) / 3))
    top = torch.argsort(scores_t, descending=True)[:k]
    top = top[has_mask_t[top]]
    rows, highlight = [], []
    for c in configs:
        cat = {name: torch.cat(v) for name, v in per[c].items()}
        rows.append(
            EvalRow(
                inputs=c[0],
                refined=c[1],
                count=len(seeds),
                **{f"mse_{m}": float(cat[m].mean()) for m in MAP_NAMES},
                psnr=float(cat["psnr"].mean()),
                ssim=float(cat["ssim"].mean()),
                seconds=seconds[c],
            ).__dict__
        )
        highlight.append(
            {
                "inputs": c[0],
                "refined": c[1],
                "count": int(top.numel()),
                "mse_diffuse_highlight": float(cat["hl_diffuse"][top].mean()) if top.numel() else float("nan"),
                "mse_diffuse_all": float(cat["diffuse"][top].mean()) if top.numel() else float("nan"),
            }
        )
    report = {
        "rows": rows,
        "highlight": highlight,
        "meta": {
            "seeds": [seeds[0], seeds[-1]] if len(seeds) > 1 else seeds,
            "num_materials": len(seeds),
            "size": size,
            "source_size": source_size or 2 * size,
            "refine_steps": refine_steps,
            "input_lights": [list(EVAL_CAMERA), *map(list, EVAL_LIGHTS)],
            "heldout_lights": [list(p) for p in HELDOUT_LIGHTS],
            "specular_third_seeds": [seeds[i] for i in top.tolist()],
            "params": sum(p.numel() for p in model.parameters()),
        },
    }
    if out_dir is not None:
        write_report(report, out_dir)
    return report


def _fmt(x: float, digits: int = 4) -> str:
    return "nan" if math.isnan(x) else f"{x:.{digits}f}"


def write_report(report: dict, out_dir: str | Path, name: str = "estimator_eval") -> tuple[Path, Path]:
    """Write ``report`` (from ``evaluate``) as ``<name>.md`` (tables) and ``<name>.json``."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    meta = report["meta"]
    lines = [
        "# SVBRDF estimator evaluation",
        "",
        f"{meta['num_materials']} held-out procedural materials (EVAL_SEEDS {meta['seeds']}), "
        f"{meta['size']} x {meta['size']}; inputs: flash (1) or flash + 7 EVAL_LIGHTS (8); "
        f"re-rendered under 16 held-out lights, tone-mapped; refinement {meta['refine_steps']} steps.",
        "",
        "| inputs | refined | MSE D | MSE N | MSE R | MSE S | PSNR (dB) | SSIM | time (s) |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in report["rows"]:
        lines.append(
            f"| {r['inputs']} | {'yes' if r['refined'] else 'no'} | {_fmt(r['mse_diffuse'])} | {_fmt(r['mse_normal'])} "
            f"| {_fmt(r['mse_roughness'])} | {_fmt(r['mse_specular'])} | {_fmt(r['psnr'], 2)} | {_fmt(r['ssim'], 3)} "
            f"| {_fmt(r['seconds'], 1)} |"
        )
    lines += [
        "",
        "## Strong highlights",
        "",
        f"Most specular third ({report['highlight'][0]['count']} materials, seeds {meta['specular_third_seeds']}): "
        "diffuse MSE inside the flash highlight (saturated or within the mirror disc) and over the whole map.",
        "",
        "| inputs | refined | diffuse MSE in highlight | diffuse MSE (all pixels) |",
        "|---|---|---|---|",
    ]
    for h in report["highlight"]:
        lines.append(
            f"| {h['inputs']} | {'yes' if h['refined'] else 'no'} | {_fmt(h['mse_diffuse_highlight'])} "
            f"| {_fmt(h['mse_diffuse_all'])} |"
        )
    md, js = out_dir / f"{name}.md", out_dir / f"{name}.json"
    with atomic_file(md) as tmp:
        tmp.write_text("\n".join(lines) + "\n")
    with atomic_file(js) as tmp:
        tmp.write_text(json.dumps(report, indent=2))
    return md, js


def cli(argv: list[str] | None = None) -> dict:
    """``python -m estimator evaluate ...``: load a model folder, evaluate, write the report."""
    parser = argparse.ArgumentParser(prog="python -m estimator evaluate", description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--model",
        required=True,
        help="folder written by save_pretrained (config.json + safetensors), or a training "
        "checkpoint folder holding one in model/",
    )
    parser.add_argument("--num", type=int, default=16, help="how many EVAL_SEEDS (a prefix)")
    parser.add_argument("--size", type=int, default=64)
    parser.add_argument("--refine-steps", type=int, default=0)
    parser.add_argument("--out", default="runs/estimator_eval")
    parser.add_argument("--num-threads", type=int, default=None)
    args = parser.parse_args(argv)
    if args.num_threads is not None:
        torch.set_num_threads(args.num_threads)
    folder = Path(args.model)
    model = SVBRDFEstimator.from_pretrained(
        folder / "model" if (folder / "model" / "config.json").is_file() else folder
    )
    report = evaluate(model, EVAL_SEEDS[: args.num], args.size, refine_steps=args.refine_steps, out_dir=args.out)
    print((Path(args.out) / "estimator_eval.md").read_text())
    return report
