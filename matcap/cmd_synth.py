"""``relight synth``: write procedural materials (our folders, or INRIA PNGs)."""

from __future__ import annotations

import argparse
from pathlib import Path

import torch
from tqdm import tqdm

import kernels
from matcap.outputs import check_output_folder
from materials.io import save_material
from materials.io.atomic import atomic_folder
from materials.lights import EVAL_CAMERA
from materials.procedural import family_of, generate

__all__ = ["add_parser", "run", "SYNTH_MARKER"]

#: File that marks a folder written by ``relight synth`` (safe to --overwrite).
SYNTH_MARKER = "synth.txt"


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "synth",
        help="write procedural SVBRDF materials",
        description="Write COUNT procedural materials, seeds SEED..SEED+COUNT-1: one folder each "
        "(ours: EXR + PNG maps) or one INRIA five-panel PNG each (render lit by a collocated flash).",
    )
    p.add_argument("--count", type=int, default=8, help="number of materials (default %(default)s)")
    p.add_argument("--size", type=int, default=256, help="map size in pixels (default %(default)s)")
    p.add_argument("--seed", type=int, default=0, help="first seed (default %(default)s)")
    p.add_argument("--out", type=Path, required=True, help="output folder (created)")
    p.add_argument("--format", choices=["ours", "inria"], default="ours", help="file format (default %(default)s)")
    p.add_argument("--overwrite", action="store_true", help="replace an output folder written by this command")
    p.set_defaults(run=run)


def run(args) -> int:
    if args.count < 1:
        raise ValueError(f"--count must be at least 1, got {args.count}")
    if args.seed < 0:
        raise ValueError(f"--seed must be non-negative, got {args.seed}")
    check_output_folder(args.out, overwrite=args.overwrite, marker=SYNTH_MARKER)
    flash = torch.tensor([EVAL_CAMERA])
    with atomic_folder(args.out, overwrite=args.overwrite, marker=SYNTH_MARKER) as tmp:
        names = []
        for seed in tqdm(range(args.seed, args.seed + args.count), desc="synth", unit="material"):
            material = generate(seed, size=args.size)
            name = f"{seed:07d}_{family_of(seed)}"
            provenance = {"generator": "materials.procedural", "seed": seed, "size": args.size}
            if args.format == "ours":
                save_material(tmp / name, material, provenance=provenance)
            else:
                # INRIA renders are scaled to the Deschaintre plane: flash over the centre.
                render = kernels.render(*(t[None] for t in material.map_tensors()), flash, flash[0], preset="dgrsise")[
                    0, 0
                ]
                name += ".png"
                save_material(tmp / name, material, fmt="inria", render=render)
            names.append(name)
        (tmp / SYNTH_MARKER).write_text("\n".join(names) + "\n")
    print(f"wrote {args.count} materials to {args.out}")
    return 0
