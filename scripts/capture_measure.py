"""Measure the capture pipeline's settings on real-texture materials rendered by our renderer.

Each material folder (``materials.domain_groups.load_texture_folder``: diffuse, normal,
roughness, specular PNGs) becomes a flash photo: rendered under the flash at the default
camera (45 degrees over the square photo: (0, 0, 4.83)), with or without the flash's 1/d^2
falloff (``--photo-falloff``), tone-mapped and quantised to 8 bits, decoded back. Then
``CapturePipeline`` runs with each setting of ``--runs`` and the result is scored against
the ground truth:

- re-render PSNR: tone-mapped renders of the refined and the true maps under the 16
  ``estimator.evaluate.HELDOUT_LIGHTS`` (none of them a relighting light), MSE pooled over
  lights and pixels per material, PSNR of it; the refined maps rendered in the lighting
  the pipeline assumed (``psnr``: what its re-renders show) and in the photo's true
  lighting (``psnr_photo_light``: the maps alone; the two differ only when ``--falloff``
  does not match the photo);
- diffuse MSE over the map, and inside the flash highlight (``materials.highlight.highlight_mask``);
- roughness MSE; relit-view PSNR (tone-mapped, 64 px, against the true maps rendered at
  full resolution and area-downsampled) when the run relights.

Runs (``--runs``, comma-separated): ``alone`` (relit 0), ``w0``, ``w0.05``, ``w0.1``,
``w0.25``, ``w0.5``, ``w1`` (7 diffusion-relit views at that refinement weight per view;
the photo weighs 1), ``gt_w...`` (the same with 7 ground-truth renders instead of relit
views), ``k3`` (3 relit views, the default weight), ``gt`` (ground truth, the default weight), ``falloff_none`` (the default run with ``falloff="none"``), ``steps50`` /
``steps200`` (the default run with that many refinement steps); ``..._noclip``: the same
without the clipping-aware loss (``CaptureConfig.clip_aware``).

    python scripts/capture_measure.py ../shared/data/real-dev/materials --out results/capture_eval/weights.json

Writes a JSON with every row and prints a Markdown table (mean over materials).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from dataclasses import replace
from pathlib import Path

import torch

DEFAULT_OUT = Path(__file__).resolve().parents[1] / "results" / "capture_eval" / "capture_eval.json"
#: Refinement weights of a relit view measured by the ``wW`` and ``gt_wW`` runs.
WEIGHTS = (0.0, 0.05, 0.1, 0.25, 0.5, 1.0)
RUNS = (
    "alone",
    *(f"w{w:g}" for w in WEIGHTS),
    *(f"gt_w{w:g}" for w in WEIGHTS),
    "alone_noclip",
    "w0.1_noclip",
    "gt_w0.5_noclip",
    "k3",
    "gt",
    "falloff_none",
    "steps50",
    "steps200",
)


def _run_configs(base):
    """Name -> (CaptureConfig, relighter kind: None / "diffusion" / "gt")."""
    return {
        "alone": (replace(base, relit=0), None),
        **{f"w{w:g}": (replace(base, relit_weight=w), "diffusion") for w in WEIGHTS},
        **{f"gt_w{w:g}": (replace(base, relit_weight=w), "gt") for w in WEIGHTS},
        "alone_noclip": (replace(base, relit=0, clip_aware=False), None),
        "w0.1_noclip": (replace(base, relit_weight=0.1, clip_aware=False), "diffusion"),
        "gt_w0.5_noclip": (replace(base, relit_weight=0.5, clip_aware=False), "gt"),
        "k3": (replace(base, relit=3), "diffusion"),
        "gt": (base, "gt"),
        "falloff_none": (replace(base, falloff="none"), "diffusion"),
        "steps50": (replace(base, refine_steps=50), "diffusion"),
        "steps200": (replace(base, refine_steps=200), "diffusion"),
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "materials",
        help="folder of texture material folders, or 'glossy:N': the first N glossy held-out "
        "procedural materials (materials.dataset.EVAL_SEEDS) at 256 px",
    )
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT, help="JSON of all rows")
    parser.add_argument("--runs", default="alone,w0,w0.25,w0.5,w1", help=f"comma-separated, of {', '.join(RUNS)}")
    parser.add_argument("--photo-falloff", choices=("inverse-square", "none"), default="inverse-square")
    parser.add_argument("--refine", type=int, default=None, help="refinement steps (default: the pipeline's)")
    parser.add_argument("--lr", type=float, default=None, help="refinement rate (default: the pipeline's)")
    parser.add_argument("--threads", type=int, default=2)
    args = parser.parse_args(argv)

    import kernels
    from estimator.evaluate import HELDOUT_LIGHTS
    from matcap.capture import CaptureConfig, CapturePipeline, area_downsample, photo_from_tensor
    from matcap.capture_eval import GroundTruthRelighter, as_8bit, flash_photo, photo_render_kwargs
    from matcap.estimate import load_estimator
    from materials import metrics
    from materials.camera import camera_from_fov
    from materials.domain_groups import load_texture_folder
    from materials.highlight import highlight_mask
    from relight.interface import get_relighter

    torch.set_num_threads(args.threads)
    runs = [r for r in args.runs.split(",") if r]
    unknown = set(runs) - set(RUNS)
    if unknown:
        parser.error(f"unknown runs {sorted(unknown)}; known: {', '.join(RUNS)}")
    base = CaptureConfig()
    if args.refine is not None:
        base = replace(base, refine_steps=args.refine)
    if args.lr is not None:
        base = replace(base, refine_lr=args.lr)
    configs = _run_configs(base)
    estimator = load_estimator()
    diffusion = get_relighter("diffusion") if any(configs[r][1] == "diffusion" for r in runs) else None
    if args.materials.startswith("glossy:"):
        from materials.dataset import EVAL_SEEDS
        from materials.procedural import generate, glossy_of

        seeds = [s for s in EVAL_SEEDS if glossy_of(s)][: int(args.materials.split(":")[1])]
        sources = [(f"seed {s}", lambda s=s: generate(s, size=256)) for s in seeds]
    else:
        folders = sorted(p for p in Path(args.materials).iterdir() if p.is_dir())
        sources = [(f.name, lambda f=f: load_texture_folder(f)) for f in folders]
    camera = camera_from_fov()  # (0, 0, 4.83): the default camera over a square photo
    photo_kw = photo_render_kwargs(camera, falloff=args.photo_falloff != "none")
    heldout = torch.tensor(HELDOUT_LIGHTS, dtype=torch.float32)
    rows = []
    for name, load in sources:
        true = load()
        maps = [t[None] for t in true.map_tensors()]
        flash = flash_photo(true, camera, falloff=args.photo_falloff != "none")
        photo = photo_from_tensor(as_8bit(flash), f"{name} (rendered)")
        true_heldout = kernels.tonemap(kernels.render(*maps, heldout[None], camera, **photo_kw)[0])
        mask = highlight_mask(flash[None], camera.tolist())[0, 0]
        for run in runs:
            config, kind = configs[run]
            relighter = {"diffusion": diffusion, "gt": GroundTruthRelighter(true), None: None}[kind]
            pipe = CapturePipeline(relighter, estimator, config=config)
            start = time.perf_counter()
            out = pipe(photo)
            seconds = time.perf_counter() - start
            pred = [t[None] for t in out.material.map_tensors()]
            kw = out.scene.render_kwargs
            # The prediction is rendered in the pipeline's lighting; the truth in the photo's.
            pred_heldout = kernels.tonemap(kernels.render(*pred, heldout[None], camera, **kw)[0])
            mse = metrics.mse(pred_heldout, true_heldout).mean()
            # The maps alone, whatever lighting the pipeline assumed: rendered in the photo's.
            pred_true_light = kernels.tonemap(kernels.render(*pred, heldout[None], camera, **photo_kw)[0])
            mse_true_light = metrics.mse(pred_true_light, true_heldout).mean()
            row = {
                "material": name,
                "run": run,
                "relit": config.relit,
                "relit_weight": config.relit_weight,
                "falloff": config.falloff,
                "photo_falloff": args.photo_falloff,
                "refine_steps": config.refine_steps,
                "refine_lr": config.refine_lr,
                "clip_aware": config.clip_aware,
                "psnr": float(metrics.psnr_from_mse(mse)),
                "psnr_photo_light": float(metrics.psnr_from_mse(mse_true_light)),
                "diffuse_mse": float(((out.material.diffuse - true.diffuse) ** 2).mean()),
                "diffuse_mse_highlight": float(((out.material.diffuse - true.diffuse) ** 2).mean(0)[mask].mean()),
                "roughness_mse": float(((out.material.roughness - true.roughness) ** 2).mean()),
                "normal_mse": float(((out.material.normal - true.normal) ** 2).mean()),
                "specular_mse": float(((out.material.specular - true.specular) ** 2).mean()),
                "seconds": round(seconds, 2),
                "refine_steps_run": len(out.refine_history),
            }
            if config.relit and kind == "diffusion":
                lights = out.scene.relit_light_pos
                ref = area_downsample(kernels.render(*maps, lights[None], camera)[0], out.relit.shape[-1])
                row["relit_psnr"] = float(metrics.psnr(kernels.tonemap(out.relit), kernels.tonemap(ref)).mean())
            rows.append(row)
            print(json.dumps(row), file=sys.stderr, flush=True)
    meta = {
        "command": "python scripts/capture_measure.py " + " ".join(argv if argv is not None else sys.argv[1:]),
        "date": time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime()),
        "loadavg": os.getloadavg(),
        "threads": args.threads,
        "camera": camera.tolist(),
        "photo_falloff": args.photo_falloff,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"meta": meta, "rows": rows}, indent=2) + "\n")
    print(table(rows))
    return 0


def table(rows: list[dict]) -> str:
    """Markdown: one line per run, means over materials."""
    keys = [
        "psnr",
        "psnr_photo_light",
        "diffuse_mse",
        "diffuse_mse_highlight",
        "roughness_mse",
        "normal_mse",
        "relit_psnr",
        "seconds",
    ]
    lines = [
        "| run | relit | weight | falloff | steps | " + " | ".join(keys) + " |",
        "|" + "---|" * (5 + len(keys)),
    ]
    for run in dict.fromkeys(r["run"] for r in rows):
        sel = [r for r in rows if r["run"] == run]
        first = sel[0]
        cells = []
        for k in keys:
            values = [r[k] for r in sel if k in r]
            cells.append(f"{sum(values) / len(values):.4g}" if values else "")
        lines.append(
            f"| {run} | {first['relit']} | {first['relit_weight']} | {first['falloff']} | {first['refine_steps']} | "
            + " | ".join(cells)
            + " |"
        )
    return "\n".join(lines)


if __name__ == "__main__":
    sys.exit(main())
