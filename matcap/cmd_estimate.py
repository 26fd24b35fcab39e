"""``relight estimate``: SVBRDF maps from a capture folder, plus re-renders."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import torch

import kernels
from matcap.estimate import estimate_material, load_estimator
from matcap.outputs import check_output_folder, contact_sheet, write_image_pair
from materials.io import load_capture, save_material, write_png
from materials.io.atomic import atomic_folder
from materials.io.encoding import chw_to_hwc
from materials.lights import EVAL_LIGHTS

__all__ = ["add_parser", "run", "ESTIMATE_MARKER"]

#: File that marks a folder written by ``relight estimate`` (safe to --overwrite).
ESTIMATE_MARKER = "estimate.json"


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "estimate",
        help="estimate SVBRDF maps from a capture folder",
        description="Read a capture (ours: PNGs + capture.json; or MaterialGAN/Luo: photos + "
        "camera_pos.txt, light_pos.txt ...), estimate diffuse/normal/roughness/specular maps, "
        "and write them (material/: EXR + PNG) with re-renders under the inputs' lights "
        "(renders/input_KK) and a few new ones (renders/novel_KK), plus preview.png.",
    )
    p.add_argument("capture", type=Path, help="capture folder")
    p.add_argument("--out", type=Path, required=True, help="output folder (created)")
    p.add_argument("--refine", type=int, default=0, metavar="STEPS", help="test-time refinement steps (default 0)")
    p.add_argument("--model", type=Path, default=None, help="estimator folder (default: the shipped one)")
    p.add_argument("--overwrite", action="store_true", help="replace an output folder written by this command")
    p.set_defaults(run=run)


def run(args) -> int:
    if args.refine < 0:
        raise ValueError(f"--refine must be >= 0, got {args.refine}")
    check_output_folder(args.out, overwrite=args.overwrite, marker=ESTIMATE_MARKER)
    capture = load_capture(args.capture)
    model = load_estimator(args.model)
    material, history = estimate_material(capture, model, refine_steps=args.refine)
    maps = [t[None] for t in material.map_tensors()]
    kw = capture.render_kwargs()
    rerender = kernels.render(*maps, capture.light_pos, capture.camera_pos, **kw)[0]
    # Novel lights: the evaluation set, scaled from the dgrsise plane to the capture's.
    plane = capture.plane_size or kernels.get_preset(capture.preset).plane_size
    novel_light_pos = torch.tensor(EVAL_LIGHTS) * (plane / kernels.get_preset("dgrsise").plane_size)
    novel = kernels.render(*maps, novel_light_pos, capture.camera_pos[0], **kw)[0]
    with atomic_folder(args.out, overwrite=args.overwrite, marker=ESTIMATE_MARKER) as tmp:
        save_material(
            tmp / "material",
            material,
            preset=capture.preset,
            plane_size=capture.plane_size,
            provenance={"estimated_from": str(args.capture), "refine_steps": args.refine},
        )
        (tmp / "renders").mkdir()
        for k, image in enumerate(rerender):
            write_image_pair(tmp / "renders", f"input_{k:02d}", image)
        for k, image in enumerate(novel):
            write_image_pair(tmp / "renders", f"novel_{k:02d}", image)
        rows = torch.cat([capture.images, rerender])
        write_png(tmp / "preview.png", chw_to_hwc(contact_sheet(kernels.tonemap(rows), columns=capture.num_views)))
        info = {
            "capture": str(args.capture),
            "views": capture.num_views,
            "refine_steps": args.refine,
            "refine_loss": history[-1:] and history[-1],
            "novel_lights": novel_light_pos.tolist(),
        }
        (tmp / ESTIMATE_MARKER).write_text(json.dumps(info, indent=2))
    print(f"wrote maps and {len(rerender) + len(novel)} re-renders to {args.out}")
    return 0
