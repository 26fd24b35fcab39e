"""End-to-end capture benchmark: flash photo file -> maps, exports and re-renders.

For each size (default 256 and 1024 px) a fresh subprocess writes the built-in flash photo
(``matcap.capture.builtin_photo``) as a PNG, loads the shipped models, runs
``CapturePipeline`` with its defaults (7 relit views, diffusion at one step, full-resolution
refinement) and saves the output folder; it reports the wall time of each step, the
loading and the saving, and its peak resident memory (``resource.getrusage`` maxrss: the
whole process, torch's allocations included, which ``tracemalloc`` does not see). One
process per size, so one size's peak does not hide the next one's.

Targets (issue 15): 256 px under 30 s, 1024 px under 120 s on the project's 2-core CPU.

    python benchmarks/bench_capture.py [--sizes 256,1024] [--threads 2] [--out benchmarks/results/capture.json]

Writes the JSON (with the CPU model and the load average before and after: the machine is
shared) and prints a table.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from machine import machine_meta

DEFAULT_OUT = Path(__file__).resolve().parent / "results" / "capture.json"
#: Issue 15's targets, seconds, photo -> maps end to end.
TARGETS_S = {256: 30.0, 1024: 120.0}


def child(size: int, threads: int) -> dict:
    """One run in this process; returns its record."""
    import torch

    torch.set_num_threads(threads)
    from matcap.capture import CapturePipeline, builtin_photo, refine_memory_bytes
    from materials.io import read_photo, write_png
    from materials.io.encoding import chw_to_hwc

    with tempfile.TemporaryDirectory() as tmp:
        import kernels

        path = Path(tmp) / "photo.png"
        write_png(path, chw_to_hwc(kernels.tonemap(builtin_photo(size=size).image)))
        total = time.perf_counter()
        start = time.perf_counter()
        pipeline = CapturePipeline.from_pretrained()
        load_s = time.perf_counter() - start
        start = time.perf_counter()
        photo = read_photo(path)
        read_s = time.perf_counter() - start
        output = pipeline(photo)
        start = time.perf_counter()
        output.save(Path(tmp) / "out")
        save_s = time.perf_counter() - start
        total_s = time.perf_counter() - total
    stages = {"load models": load_s, "read photo": read_s, **output.provenance["timings_s"], "9 save": save_s}
    return {
        "size": size,
        "total_s": round(total_s, 2),
        "stages_s": {k: round(v, 3) for k, v in stages.items()},
        "share": {k: round(v / total_s, 3) for k, v in stages.items()},
        "refine_steps_run": output.provenance["refinement"]["steps_run"],
        "peak_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1),
        "refine_estimate_mb": round(refine_memory_bytes(output.frame.size[0], 1 + len(output.relit)) / 2**20, 1),
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sizes", default="256,1024", help="photo sides, comma-separated")
    parser.add_argument("--threads", type=int, default=2, help="torch threads (the CPU's 2 cores)")
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT)
    parser.add_argument("--child", type=int, default=None, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child is not None:
        print(json.dumps(child(args.child, args.threads)))
        return 0

    sizes = [int(s) for s in args.sizes.split(",")]
    meta = machine_meta(args.threads)
    runs = []
    for size in sizes:
        cmd = [sys.executable, __file__, "--child", str(size), "--threads", str(args.threads)]
        result = subprocess.run(cmd, capture_output=True, text=True, check=False)
        if result.returncode:
            print(result.stderr[-4000:], file=sys.stderr)
            return result.returncode
        record = json.loads(result.stdout.strip().splitlines()[-1])
        record["target_s"] = TARGETS_S.get(size)
        runs.append(record)
    meta["loadavg_after"] = os.getloadavg()
    import torch

    meta["torch"] = torch.__version__
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"meta": meta, "runs": runs}, indent=2) + "\n")
    print(table(meta, runs))
    return 0


def table(meta: dict, runs: list[dict]) -> str:
    stages = list(runs[0]["stages_s"])
    lines = [
        f"CPU: {meta['cpu']} ({meta['cores']} cores, {meta['threads']} threads); "
        f"load average before {meta['loadavg_before'][0]:.2f}, after {meta['loadavg_after'][0]:.2f}",
        "",
        "| size | total (s) | target (s) | peak RSS (MB) | refine estimate (MB) | " + " | ".join(stages) + " |",
        "|" + "---|" * (5 + len(stages)),
    ]
    for r in runs:
        shares = [f"{r['stages_s'][s]:.2f} s ({100 * r['share'][s]:.0f}%)" for s in stages]
        lines.append(
            f"| {r['size']} | {r['total_s']:.1f} | {r['target_s'] or '-'} | {r['peak_rss_mb']:.0f} | "
            f"{r['refine_estimate_mb']:.0f} | " + " | ".join(shares) + " |"
        )
    return "\n".join(lines)


if __name__ == "__main__":
    sys.exit(main())
