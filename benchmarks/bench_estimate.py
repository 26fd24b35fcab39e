"""Benchmark: estimate one material from V views with test-time refinement (issue 5's
target: 8 views at 256x256 with 200 refinement steps under 60 s on this CPU).

    python benchmarks/bench_estimate.py [--size 256] [--views 8] [--steps 200] [--threads 2]

Times the network forward and the refinement separately, with the Warp rendering loss
and (``--reference``) the pure-torch one, and writes JSON to benchmarks/results/.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path

import torch


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--size", type=int, default=256)
    p.add_argument("--views", type=int, default=8)
    p.add_argument("--steps", type=int, default=200)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--reference", action="store_true", help="also time refinement with the torch reference loss")
    p.add_argument("--out", type=Path, default=Path("benchmarks/results/estimate.json"))
    args = p.parse_args()
    os.environ["DGRSISE_KERNEL_THREADS"] = str(args.threads)
    torch.set_num_threads(args.threads)

    import kernels
    import kernels.reference
    from estimator.refine import refine
    from matcap.estimate import load_estimator
    from materials.lights import eval_lights
    from materials.procedural import generate

    model = load_estimator()
    material = generate(10_000_003, size=args.size)
    light_pos, camera_pos = eval_lights()
    light_pos, camera_pos = light_pos[: args.views], camera_pos[: args.views]
    images = kernels.render(*(t[None] for t in material.map_tensors()), light_pos, camera_pos)
    images, light_pos, camera_pos = images, light_pos[None], camera_pos[None]

    with torch.no_grad():
        model(images, light_pos, camera_pos)  # warm-up (kernel load, allocator)
        tick = time.perf_counter()
        model(images, light_pos, camera_pos)
        forward_s = time.perf_counter() - tick
    rows = {"forward_s": forward_s}
    losses = {"warp": kernels.rendering_loss}
    if args.reference:
        losses["torch_reference"] = kernels.reference.rendering_loss
    for name, fn in losses.items():
        tick = time.perf_counter()
        # tol=-1 disables the early stop (it would need the loss to double), so every
        # run takes exactly `steps` steps: the worst case.
        result = refine(
            model, images, light_pos, camera_pos, steps=args.steps, tol=-1.0, render_loss_fn=fn, progress=False
        )
        rows[f"refine_{name}_s"] = time.perf_counter() - tick
        rows[f"refine_{name}_steps"] = len(result.history)
    total = forward_s + rows["refine_warp_s"]
    report = {
        "size": args.size,
        "views": args.views,
        "steps": args.steps,
        "threads": args.threads,
        "cpu": platform.processor() or platform.machine(),
        "load_avg": os.getloadavg(),
        **rows,
        "total_warp_s": total,
        "target_s": 60.0,
        "meets_target": total < 60.0,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(report, indent=2))
    print("| step | seconds |\n|---|---|")
    print(f"| network forward ({args.views} views, {args.size}x{args.size}) | {forward_s:.2f} |")
    for name in losses:
        print(f"| refinement, {rows[f'refine_{name}_steps']} steps, {name} loss | {rows[f'refine_{name}_s']:.2f} |")
    print(f"| total (warp) | {total:.2f} (target < 60: {'met' if total < 60 else 'not met'}) |")


if __name__ == "__main__":
    main()
