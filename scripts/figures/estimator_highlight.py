"""README picture: diffuse maps from 1 vs 8 inputs on strongly specular held-out materials.

    .venv/bin/python scripts/figures/estimator_highlight.py [--out PNG] [--model DIR] [--num-threads N]

Rows: three held-out procedural materials from the most specular third of the Table-2
set (``results/estimator_eval``, "Strong highlights"), generated at 64 x 64. Columns:
flash photo (tone-mapped), ground-truth diffuse, diffuse from the flash photo alone, from
flash + 7 renders (the 7 evaluation lights); sRGB-encoded, no refinement. Each pixel is
shown as a 3 x 3 block. Default output: ``results/estimator_figures/highlight_diffuse.png``
under the repository root.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path

import torch

import kernels
from estimator.model import SVBRDFEstimator
from matcap.estimate import load_estimator
from matcap.outputs import contact_sheet
from materials.io import write_png
from materials.io.encoding import chw_to_hwc
from materials.lights import eval_lights
from materials.procedural import generate

REPO_ROOT = Path(__file__).resolve().parents[2]
DEFAULT_OUT = REPO_ROOT / "results" / "estimator_figures" / "highlight_diffuse.png"
#: The three most specular of the 16 Table-2 materials (its "Strong highlights" list).
SEEDS = (10000004, 10000015, 10000013)
#: Material side in pixels (the Table-2 size).
SIZE = 64
#: Nearest-neighbour magnification of the sheet, so 64-pixel maps are visible in the README.
UPSCALE = 3


def make_sheet(model: SVBRDFEstimator, seeds: Sequence[int] = SEEDS, size: int = SIZE) -> torch.Tensor:
    """Contact sheet ``[3, len(seeds) * size * UPSCALE, 4 * size * UPSCALE]``, float32 display values in [0, 1]."""
    light_pos, camera_pos = eval_lights()
    rows = []
    for seed in seeds:
        m = generate(seed, size=size)
        imgs = kernels.render(*[t[None] for t in m.map_tensors()], light_pos, camera_pos)  # [1, 8, 3, H, W]
        with torch.no_grad():
            one = model(imgs[:, :1], light_pos[None, :1], camera_pos[None, :1])
            eight = model(imgs, light_pos[None], camera_pos[None])
        rows += [
            kernels.tonemap(imgs[0, 0]),
            kernels.srgb_encode(m.diffuse),
            kernels.srgb_encode(one.diffuse[0]),
            kernels.srgb_encode(eight.diffuse[0]),
        ]
    sheet = contact_sheet(torch.stack(rows), columns=4)
    return torch.nn.functional.interpolate(sheet[None], scale_factor=UPSCALE, mode="nearest")[0]


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT, help="PNG to write (default: %(default)s)")
    parser.add_argument("--model", type=Path, default=None, help="estimator folder (default: the shipped weights)")
    parser.add_argument(
        "--num-threads", type=int, default=1, help="torch threads (default %(default)s, as the README picture)"
    )
    args = parser.parse_args(argv)
    torch.set_num_threads(args.num_threads)
    sheet = make_sheet(load_estimator(args.model))
    args.out.parent.mkdir(parents=True, exist_ok=True)
    write_png(args.out, chw_to_hwc(sheet))
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
