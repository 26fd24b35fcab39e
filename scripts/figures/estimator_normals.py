"""README picture: normal maps from 1 vs 8 inputs on held-out materials with relief.

    .venv/bin/python scripts/figures/estimator_normals.py [--out PNG] [--model DIR] [--num-threads N]

Rows: the three Table-2 materials (the crops ``relight eval estimation --num 16 --size 64``
scores) with the most relief, i.e. the largest ground-truth normal MSE to a flat map.
Columns: flash photo (tone-mapped), ground-truth normals, normals from the flash photo
alone, from flash + 7 renders; no refinement. Normals are shown as 0.5 + 2.5 (x, y, z - 1)
around flat grey-blue, so that relief of a few degrees is visible (plain 0.5 + 0.5 n would
show all three as nearly the same flat colour). Each pixel is shown as a 3 x 3 block.
Prints each row's normal MSE (1 input, 8 inputs, flat). Default output:
``results/estimator_figures/normals_1_vs_8.png`` under the repository root.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path

import torch

import kernels
from estimator.evaluate import EVAL_CROP_SEED
from estimator.model import SVBRDFEstimator
from matcap.estimate import load_estimator
from matcap.outputs import contact_sheet
from materials.dataset import EVAL_SEEDS, GroupConfig, RenderedGroups
from materials.io import write_png
from materials.io.encoding import chw_to_hwc
from materials.lights import eval_lights

REPO_ROOT = Path(__file__).resolve().parents[2]
DEFAULT_OUT = REPO_ROOT / "results" / "estimator_figures" / "normals_1_vs_8.png"
#: Exaggeration of the normal display (module docstring).
GAIN = 2.5
#: Table-2 materials and their size (``relight eval estimation --num 16 --size 64``).
NUM_MATERIALS = 16
SIZE = 64
#: Rows of the picture: the materials with the most relief.
ROWS = 3
#: Nearest-neighbour magnification of the sheet, so 64-pixel maps are visible in the README.
UPSCALE = 3


def show(normal: torch.Tensor) -> torch.Tensor:
    """Display values ``[3, H, W]`` in [0, 1] of unit normals ``[3, H, W]`` (module docstring)."""
    flat = torch.tensor([0.0, 0.0, 1.0])[:, None, None]
    return (0.5 + GAIN * (normal - flat)).clamp(0, 1)


def normal_mse(a: torch.Tensor, b: torch.Tensor) -> float:
    return float(((a - b) ** 2).mean())


def make_sheet(model: SVBRDFEstimator) -> torch.Tensor:
    """Contact sheet ``[3, ROWS * SIZE * UPSCALE, 4 * SIZE * UPSCALE]``, float32 display values in [0, 1]."""
    light_pos, camera_pos = eval_lights()
    table2 = RenderedGroups(
        EVAL_SEEDS[:NUM_MATERIALS], GroupConfig(size=SIZE, source_size=2 * SIZE, seed=EVAL_CROP_SEED)
    )
    candidates = [table2.material(i) for i in range(NUM_MATERIALS)]
    relief = torch.stack([(m.normal[:2] ** 2).mean() for m in candidates])
    flat = torch.tensor([0.0, 0.0, 1.0])[:, None, None]
    rows = []
    for i in relief.argsort(descending=True)[:ROWS].tolist():
        m = candidates[i]
        imgs = kernels.render(*[t[None] for t in m.map_tensors()], light_pos, camera_pos)  # [1, 8, 3, H, W]
        with torch.no_grad():
            one = model(imgs[:, :1], light_pos[None, :1], camera_pos[None, :1])
            eight = model(imgs, light_pos[None], camera_pos[None])
        rows += [kernels.tonemap(imgs[0, 0]), show(m.normal), show(one.normal[0]), show(eight.normal[0])]
        print(
            f"seed {int(EVAL_SEEDS[i])}: normal MSE 1 input {normal_mse(one.normal[0], m.normal):.5f}, "
            f"8 inputs {normal_mse(eight.normal[0], m.normal):.5f}, flat {normal_mse(flat, m.normal):.5f}"
        )
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
