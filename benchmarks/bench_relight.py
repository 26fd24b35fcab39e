"""Benchmark: relight one flash photo to the 7 evaluation lights (issue 4's target: under
20 s on this CPU with the tiny diffusion preset), every registered relighter side by side.

    python benchmarks/bench_relight.py [--threads 2] [--repeats 3] [--samples 1] [--steps 20] [--size 256]

Times ``Relighter.relight`` on one held-out procedural material's flash photo at the
model's resolution (the shipped checkpoints), or at ``--size`` pixels (the diffusion model
then relights 64 px tiles, ``relight.tiling``; issue 16's target: 7 images from a 256 px
photo under 20 s), after one warm-up call; reports the median and the spread, CPU model
and load, writes JSON to benchmarks/results/relight.json and prints a table.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time
from pathlib import Path

import torch
from machine import cpu_model

#: Issue 4: 7 relit images from one photo in under 20 s with the tiny preset.
TARGET_S = 20.0


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--samples", type=int, default=1, help="diffusion samples averaged per target")
    p.add_argument("--steps", type=int, default=None, help="diffusion sampling steps (default: the pipeline's 20)")
    p.add_argument("--methods", default="input,lambertian,bieron,diffusion")
    p.add_argument("--size", type=int, default=None, help="photo side (default: each model's own, 64)")
    p.add_argument("--out", type=Path, default=Path("benchmarks/results/relight.json"))
    args = p.parse_args()
    os.environ["DGRSISE_KERNEL_THREADS"] = str(args.threads)
    torch.set_num_threads(args.threads)

    from matcap.args import set_sampling
    from relight.evaluate import EvalConfig, load_eval_data
    from relight.interface import get_relighter

    rows = {}
    for name in args.methods.split(","):
        relighter = get_relighter(name)
        if getattr(relighter, "stochastic", False):
            set_sampling(relighter, name, args.steps, args.samples)
        model = getattr(getattr(relighter, "pipeline", None), "model", None)
        size = args.size or (model.config.resolution if model is not None else 64)
        data = load_eval_data(EvalConfig(count=1, size=size))
        photo, light_pos, camera_pos = data.photo[:1], data.light_pos[:1], data.camera_pos[:1]  # 7 target lights

        def call(relighter=relighter, photo=photo, light_pos=light_pos, camera_pos=camera_pos):
            return relighter.relight(photo, light_pos, camera_pos, generator=torch.Generator().manual_seed(0))

        call()  # warm-up: kernel load, allocator
        times = []
        for _ in range(args.repeats):
            tick = time.perf_counter()
            out = call()
            times.append(time.perf_counter() - tick)
        rows[name] = {
            "size": size,
            "images": int(out.shape[1]),
            "steps": getattr(relighter, "steps", None),
            "median_s": statistics.median(times),
            "min_s": min(times),
            "max_s": max(times),
        }
    report = {
        "threads": args.threads,
        "repeats": args.repeats,
        "samples": args.samples,
        "cpu": cpu_model(),
        "load_avg": os.getloadavg(),
        "target_s": TARGET_S,
        "rows": rows,
    }
    if "diffusion" in rows:
        report["meets_target"] = rows["diffusion"]["median_s"] < TARGET_S
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(report, indent=2))
    print("| method | size | images | median s [min-max] |\n|---|---|---|---|")
    for name, r in rows.items():
        print(
            f"| {name} | {r['size']}x{r['size']} | {r['images']} | {r['median_s']:.2f} [{r['min_s']:.2f}-{r['max_s']:.2f}] |"
        )
    if "diffusion" in rows:
        met = "met" if report["meets_target"] else "not met"
        print(f"\ndiffusion: 7 images in {rows['diffusion']['median_s']:.2f} s (target < {TARGET_S:.0f} s: {met})")


if __name__ == "__main__":
    main()
