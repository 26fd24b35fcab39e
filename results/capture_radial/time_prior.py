"""Cost of the flash-independence prior per refinement step (forward + backward).

    python results/capture_radial/time_prior.py --sizes 256,1024,2048 --threads 2

Times ``flash_independence`` on the default maps (``DEFAULT_RADIAL_MAPS``) of a random
``S x S`` material, the rings built once as the refinement does; median of ``--repeats``
after one warm-up. Prints one JSON line per size.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time

import torch

from matcap.capture import DEFAULT_RADIAL_MAPS
from matcap.capture.priors import FlashRings, flash_independence

CHANNELS = {"diffuse": 3, "normal": 2, "roughness": 1, "specular": 3}


def time_one(side: int, repeats: int) -> dict:
    gen = torch.Generator().manual_seed(0)
    maps = {
        n: (torch.rand(1, CHANNELS[n], side, side, generator=gen) * 0.8 + 0.1).requires_grad_()
        for n in DEFAULT_RADIAL_MAPS
    }
    build = time.perf_counter()
    rings = FlashRings(side, (side / 2 - 0.5, side / 2 - 0.5))
    build = time.perf_counter() - build
    times = []
    for _ in range(repeats + 1):
        t = time.perf_counter()
        flash_independence(rings, maps).backward()
        times.append(time.perf_counter() - t)
    return {
        "side": side,
        "maps": list(DEFAULT_RADIAL_MAPS),
        "build_s": build,
        "step_ms": 1e3 * statistics.median(times[1:]),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", default="256,1024,2048")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--repeats", type=int, default=10)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    for side in (int(s) for s in args.sizes.split(",")):
        print(json.dumps({**time_one(side, args.repeats), "threads": args.threads}))


if __name__ == "__main__":
    main()
