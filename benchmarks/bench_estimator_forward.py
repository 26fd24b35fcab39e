"""Benchmark: the estimator's forward pass at 256-1024 px, the three ways of running it
above its 64 px training size (issue 16's target: under 10 s at 1024 px).

- ``downsample``: the views area-averaged to 64 px, the network there, the maps
  bilinearly upsampled (what ``relight capture`` does before its refinement);
- ``whole``: the network on the whole image (fully convolutional);
- ``tiled``: ``estimator.tiling.tiled_estimate``, 64 px windows overlapping by 16;
- ``compile``: ``whole`` through ``torch.compile`` (inductor, its C++ backend on the CPU;
  the warm-up call pays the compilation);
- ``bf16``: ``whole`` under ``torch.autocast("cpu", torch.bfloat16)`` (fast only on CPUs
  with AVX512-BF16 or AMX; its largest map difference to ``whole`` is recorded).

Quality of each at 64-512 px: ``scripts/eval_estimator_resolution.py``. Each (size, mode)
runs in a fresh subprocess, so its peak resident memory (``getrusage`` maxrss) is its own:
the shipped estimator, 8 views of a procedural material rendered in the evaluation
setup, one warm-up call, then the median of ``--repeats`` timed calls.

    python benchmarks/bench_estimator_forward.py [--sizes 256,512,1024] [--modes downsample,whole,tiled] [--threads 2]

Writes ``benchmarks/results/estimator_forward.json`` (with the CPU model and the load
average before and after: the machine may be shared) and prints a table.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

from machine import machine_meta

DEFAULT_OUT = Path(__file__).resolve().parent / "results" / "estimator_forward.json"
MODES = ("downsample", "whole", "tiled", "compile", "bf16")
#: Issue 16's target, seconds, at 1024 px.
TARGET_S = {1024: 10.0}
VIEWS = 8


def child(size: int, mode: str, threads: int, repeats: int) -> dict:
    """One (size, mode) in this process; returns its record."""
    import torch
    import torch.nn.functional as F

    torch.set_num_threads(threads)
    import kernels
    from estimator.tiling import tiled_estimate
    from matcap.capture import area_downsample
    from matcap.estimate import load_estimator
    from materials.lights import eval_lights
    from materials.procedural import generate

    model = load_estimator()
    light, camera = eval_lights(include_input=True)
    light, camera = light[None, :VIEWS], camera.expand(VIEWS, 3)[None]
    material = generate(10_000_003, size=size)
    images = kernels.render(*(t[None] for t in material.map_tensors()), light[0], camera[0])

    net = torch.compile(model) if mode == "compile" else model

    def forward():
        if mode in ("whole", "compile"):
            return net(images, light, camera)
        if mode == "bf16":
            with torch.autocast("cpu", dtype=torch.bfloat16):
                out = model(images, light, camera)
            return {k: v.float() for k, v in out.maps().items()}
        if mode == "tiled":
            return tiled_estimate(model, images, light, camera)
        small = model(area_downsample(images, 64), light, camera)
        return {k: F.interpolate(v, size=(size, size), mode="bilinear") for k, v in small.maps().items()}

    seconds = []
    with torch.no_grad():
        forward()  # warm-up: kernel loads, first-touch allocations
        for _ in range(repeats):
            tick = time.perf_counter()
            forward()
            seconds.append(time.perf_counter() - tick)
        deviation = None
        if mode == "bf16":
            exact = model(images, light, camera).maps()
            deviation = max(float((forward()[k] - v).abs().max()) for k, v in exact.items())
    return {
        "size": size,
        "mode": mode,
        "views": VIEWS,
        "seconds": [round(s, 3) for s in seconds],
        "median_s": round(statistics.median(seconds), 3),
        "peak_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1),
        "target_s": TARGET_S.get(size),
        "max_map_difference_to_whole": deviation,
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sizes", default="256,512,1024")
    parser.add_argument("--modes", default=",".join(MODES))
    parser.add_argument("--threads", type=int, default=2, help="torch threads (the CPU's 2 cores)")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT)
    parser.add_argument("--child", nargs=2, metavar=("SIZE", "MODE"), help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        print(json.dumps(child(int(args.child[0]), args.child[1], args.threads, args.repeats)))
        return 0
    modes = [m for m in args.modes.split(",") if m]
    if unknown := set(modes) - set(MODES):
        parser.error(f"unknown modes {sorted(unknown)}; known: {', '.join(MODES)}")
    before = os.getloadavg()
    runs = []
    for size in (int(s) for s in args.sizes.split(",")):
        for mode in modes:
            cmd = [sys.executable, __file__, "--child", str(size), mode, "--threads", str(args.threads)]
            out = subprocess.run([*cmd, "--repeats", str(args.repeats)], capture_output=True, text=True, check=True)
            runs.append(json.loads(out.stdout.strip().splitlines()[-1]))
            print(f"{size} px {mode}: {runs[-1]['median_s']:.2f} s, {runs[-1]['peak_rss_mb']:.0f} MB", flush=True)
    meta = {**machine_meta(args.threads), "loadavg_before": before, "loadavg_after": os.getloadavg()}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"meta": meta, "runs": runs}, indent=2) + "\n")
    print(f"\n{meta['cpu']}, {args.threads} threads, load {before[0]:.1f} -> {meta['loadavg_after'][0]:.1f}")
    print("| size | mode | median s | peak RSS | target |\n|---|---|---|---|---|")
    for r in runs:
        target = f"< {r['target_s']:.0f} s" if r["target_s"] else "-"
        print(f"| {r['size']} | {r['mode']} | {r['median_s']:.2f} | {r['peak_rss_mb']:.0f} MB | {target} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
