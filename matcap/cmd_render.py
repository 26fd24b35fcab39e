"""``relight render``: render a material under point lights to EXR (linear) and PNG."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import torch

import kernels
from matcap.args import parse_position, positions_or_default
from matcap.outputs import check_output_folder, contact_sheet, write_image_pair
from materials.io import load_material
from materials.io.atomic import atomic_folder
from materials.lights import EVAL_CAMERA, eval_lights
from materials.procedural import generate
from materials.types import Material

__all__ = ["add_parser", "run", "RENDER_MARKER", "DEFAULT_SEED"]

#: File that marks a folder written by ``relight render`` (safe to --overwrite).
RENDER_MARKER = "renders.json"
#: The built-in material rendered when no MATERIAL is given: a procedural seed.
DEFAULT_SEED = 3


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "render",
        help="render a material under point lights to EXR + PNG",
        description="Render a material folder (ours, MatSynth, INRIA PNG) or a built-in "
        "procedural material under point lights. Writes render_KK.exr (linear radiance), "
        "render_KK.png (tone-mapped), sheet.png and renders.json.",
    )
    p.add_argument("material", nargs="?", help="material folder or INRIA PNG (default: built-in procedural)")
    p.add_argument("--out", required=True, type=Path, help="output folder (created)")
    p.add_argument(
        "--light",
        action="append",
        metavar="X,Y,Z",
        help="light position (repeat); default: the collocated flash plus the 7 evaluation lights",
    )
    p.add_argument(
        "--camera",
        default=",".join(str(v) for v in EVAL_CAMERA),
        metavar="X,Y,Z",
        help="camera position (default %(default)s)",
    )
    p.add_argument("--seed", type=int, default=DEFAULT_SEED, help="procedural seed when no material is given")
    p.add_argument("--size", type=int, default=256, help="procedural material size (default %(default)s)")
    p.add_argument("--preset", default="dgrsise", choices=sorted(kernels.PRESETS), help="scene conventions")
    p.add_argument("--overwrite", action="store_true", help="replace an output folder written by this command")
    p.set_defaults(run=run)


def _material(args) -> tuple[Material, dict]:
    if args.material is None:
        return generate(args.seed, size=args.size), {"source": "procedural", "seed": args.seed, "size": args.size}
    material, meta = load_material(args.material)
    return material, {"source": str(args.material), "format": meta.get("format")}


def run(args) -> int:
    check_output_folder(args.out, overwrite=args.overwrite, marker=RENDER_MARKER)
    material, provenance = _material(args)
    camera_pos = torch.tensor(parse_position(args.camera, "--camera"))
    light_pos = positions_or_default(args.light, eval_lights()[0], "--light")
    images = kernels.render(*(t[None] for t in material.map_tensors()), light_pos, camera_pos, preset=args.preset)[0]
    with atomic_folder(args.out, overwrite=args.overwrite, marker=RENDER_MARKER) as tmp:
        for k, image in enumerate(images):
            write_image_pair(tmp, f"render_{k:02d}", image)
        from materials.io import write_png
        from materials.io.encoding import chw_to_hwc

        write_png(tmp / "sheet.png", chw_to_hwc(contact_sheet(kernels.tonemap(images), columns=4)))
        info = {
            "preset": args.preset,
            "camera": camera_pos.tolist(),
            "lights": light_pos.tolist(),
            "material": provenance,
            "files": [f"render_{k:02d}.exr" for k in range(len(images))],
        }
        (tmp / RENDER_MARKER).write_text(json.dumps(info, indent=2))
    print(f"wrote {len(images)} renders to {args.out}")
    return 0
