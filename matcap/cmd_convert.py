"""``relight convert``: read a material or capture in a foreign format, write ours."""

from __future__ import annotations

import argparse
from pathlib import Path

from matcap.outputs import check_output_folder
from materials.io import load_capture, load_material, save_capture, save_material
from materials.io.ours import CAPTURE_JSON, MATERIAL_JSON

__all__ = ["add_parser", "run"]

_MATERIAL_FORMATS = ("inria", "matsynth")
_CAPTURE_FORMATS = ("materialgan",)


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "convert",
        help="convert INRIA / MatSynth materials or MaterialGAN captures to our format",
        description="Convert SRC to our format: a material folder (EXR + PNG maps + material.json) "
        "for inria/matsynth, a capture folder (PNGs + capture.json) for materialgan.",
    )
    p.add_argument("src", type=Path, help="source file or folder")
    p.add_argument("--from", dest="fmt", required=True, choices=_MATERIAL_FORMATS + _CAPTURE_FORMATS)
    p.add_argument("--out", type=Path, required=True, help="output folder (created)")
    p.add_argument("--size", type=int, default=None, help="matsynth only: downsample maps to this size")
    p.add_argument("--overwrite", action="store_true", help="replace an output folder written by this tool")
    p.set_defaults(run=run)


def run(args) -> int:
    if not args.src.exists():
        raise FileNotFoundError(f"{args.src}: does not exist")
    if args.size and args.fmt != "matsynth":
        raise ValueError("--size applies to --from matsynth only")
    marker = CAPTURE_JSON if args.fmt in _CAPTURE_FORMATS else MATERIAL_JSON
    check_output_folder(args.out, overwrite=args.overwrite, marker=marker)
    if args.fmt in _CAPTURE_FORMATS:
        capture = load_capture(args.src, fmt=args.fmt)
        save_capture(args.out, capture, overwrite=args.overwrite)
        print(f"wrote a capture of {capture.num_views} images to {args.out}")
        return 0
    kwargs = {"size": args.size} if args.fmt == "matsynth" and args.size else {}
    material, meta = load_material(args.src, fmt=args.fmt, **kwargs)
    provenance = {"converted_from": args.fmt, "source": str(args.src)}
    save_material(args.out, material, provenance=provenance, overwrite=args.overwrite)
    print(f"wrote a {material.shape[0]}x{material.shape[1]} material to {args.out}")
    return 0
