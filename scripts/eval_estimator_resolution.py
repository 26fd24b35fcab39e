"""Estimation at 64, 256 and 512 px on the same held-out materials, three ways of running
the estimator at a resolution above its 64 px training crops (issue 16, item 1).

    .venv/bin/python scripts/eval_estimator_resolution.py --out results/estimator_resolution --num-threads 1

Data: the held-out procedural materials ``EVAL_SEEDS[:count]`` made once at the largest
size (crop seed ``EVAL_CROP_SEED``, source twice that size, as ``estimator.evaluate``
does) and area-averaged to each smaller size, so every size shows the same surfaces (the
normals renormalised). Each is rendered in the paper's evaluation setup at that size:
camera and flash at (0, 0, 4), views 1..7 under the ``EVAL_LIGHTS``, no falloff, linear.

Modes (no refinement):

- ``downsample``: the views area-averaged to 64 px, the estimator there, its maps
  bilinearly upsampled (what ``relight capture`` hands its refinement);
- ``whole``: the estimator on the whole image at full size (fully convolutional);
- ``tiled``: ``estimator.tiling.tiled_estimate``, 64 px windows overlapping by 16.

Scores: re-render PSNR of the predicted vs the true maps under the 16 ``HELDOUT_LIGHTS``
at that size (``estimator.evaluate.rerender_metrics``), map MSEs, and the seconds of the
estimation. Writes ``estimator_resolution.md`` and ``.json``.
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import time
from pathlib import Path

import torch
import torch.nn.functional as F

import kernels
from estimator.evaluate import EVAL_CROP_SEED, MAP_NAMES, rerender_metrics
from estimator.tiling import tiled_estimate
from matcap.capture import area_downsample
from matcap.estimate import load_estimator
from materials.dataset import EVAL_SEEDS, GroupConfig, RenderedGroups
from materials.lights import eval_lights
from materials.types import Material

MODES = ("downsample", "whole", "tiled")
#: The estimator's training resolution, where ``downsample`` runs it.
NATIVE = 64


def at_size(material: Material, size: int) -> Material:
    """The batched material ``[1, C, S, S]`` area-averaged to ``size``."""
    maps = {k: area_downsample(v, size) for k, v in material.maps().items()}
    maps["normal"] = F.normalize(maps["normal"], dim=1)
    return Material(**maps)


def estimate(model, mode: str, images, light, camera) -> Material:
    size = images.shape[-1]
    with torch.no_grad():
        if mode == "whole" or (mode == "downsample" and size == NATIVE):
            return model(images, light, camera)
        if mode == "downsample":
            small = model(area_downsample(images, NATIVE), light, camera)
            maps = {
                k: F.interpolate(v, size=(size, size), mode="bilinear", align_corners=False)
                for k, v in small.maps().items()
            }
            maps["normal"] = F.normalize(maps["normal"], dim=1)
            return Material(**maps)
        if mode == "tiled":
            return tiled_estimate(model, images, light, camera)
    raise ValueError(f"unknown mode {mode!r}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--count", type=int, default=8)
    parser.add_argument("--sizes", default="64,256,512")
    parser.add_argument("--modes", default=",".join(MODES))
    parser.add_argument("--estimator", type=Path, default=None)
    parser.add_argument("--num-threads", type=int, default=None)
    args = parser.parse_args()
    if args.num_threads:
        torch.set_num_threads(args.num_threads)
    sizes = sorted(int(s) for s in args.sizes.split(","))
    modes = [m for m in args.modes.split(",") if m]
    if unknown := set(modes) - set(MODES):
        parser.error(f"unknown modes {sorted(unknown)}; known: {', '.join(MODES)}")
    model = load_estimator(args.estimator)
    largest = sizes[-1]
    groups = RenderedGroups(
        EVAL_SEEDS[: args.count], GroupConfig(size=largest, source_size=2 * largest, seed=EVAL_CROP_SEED)
    )
    light8, camera = eval_lights(include_input=True)
    camera8 = camera.expand(len(light8), 3)
    per: dict[str, list[dict]] = {}
    start = time.perf_counter()
    for i in range(args.count):
        full = Material(*(t[None] for t in groups.material(i).map_tensors()))
        for size in sizes:
            true = at_size(full, size)
            images = kernels.render(*true.map_tensors(), light8, camera8)  # [1, 8, 3, S, S]
            for n in (1, 8):
                for mode in modes:
                    if size == NATIVE and mode != modes[0]:
                        continue  # at 64 px every mode is the whole-image forward
                    tick = time.perf_counter()
                    pred = estimate(model, mode, images[:, :n], light8[None, :n], camera8[None, :n])
                    seconds = time.perf_counter() - tick
                    psnr, ssim = rerender_metrics(pred, true)
                    row = {"psnr": float(psnr[0]), "ssim": float(ssim[0]), "seconds": seconds}
                    for name, p, t in zip(MAP_NAMES, pred.map_tensors(), true.map_tensors()):
                        row[name] = float(((p - t) ** 2).mean())
                    key = f"{size}|{n}|{'any' if size == NATIVE else mode}"
                    per.setdefault(key, []).append(row)
        print(f"material {i + 1}/{args.count} done ({time.perf_counter() - start:.0f} s)", flush=True)
    summary = []
    for key, rows in per.items():
        size, n, mode = key.split("|")
        mean = {k: sum(r[k] for r in rows) / len(rows) for k in rows[0]}
        summary.append({"size": int(size), "inputs": int(n), "mode": mode, "count": len(rows), **mean})
    summary.sort(key=lambda s: (s["inputs"], s["size"], s["mode"]))
    lines = [
        "| inputs | size | mode | re-render PSNR (dB) | SSIM | MSE D | MSE N | MSE R | MSE S | seconds |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for s in summary:
        cells = [str(s["inputs"]), str(s["size"]), s["mode"], f"{s['psnr']:.2f}", f"{s['ssim']:.3f}"]
        cells += [f"{s[k]:.4f}" for k in MAP_NAMES] + [f"{s['seconds']:.2f}"]
        lines.append("| " + " | ".join(cells) + " |")
    table = "\n".join(lines)
    total = time.perf_counter() - start
    meta = {
        "count": args.count,
        "sizes": sizes,
        "modes": modes,
        "estimator": str(args.estimator or "weights/estimator"),
        "threads": torch.get_num_threads(),
        "machine": platform.processor() or platform.machine(),
        "seconds": round(total, 1),
    }
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "estimator_resolution.json").write_text(
        json.dumps({"meta": meta, "summary": summary, "per_material": per}, indent=2) + "\n"
    )
    head = f"# Estimation at {', '.join(map(str, sizes))} px ({args.count} materials, no refinement, {total:.0f} s)\n\n"
    (args.out / "estimator_resolution.md").write_text(head + table + "\n")
    print(table)
    assert all(math.isfinite(s["psnr"]) for s in summary)


if __name__ == "__main__":
    main()
