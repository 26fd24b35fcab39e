"""``relight generate``: relight one flash photo to new point lights with a chosen model."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import torch
from tqdm.auto import tqdm

from matcap.args import parse_position, positions_or_default, set_sampling
from matcap.errors import UsageError
from matcap.outputs import check_output_folder, write_image_pair
from materials.lights import EVAL_CAMERA, EVAL_LIGHTS

__all__ = ["add_parser", "run", "read_photo", "GENERATE_MARKER"]

#: File that marks a folder written by ``relight generate`` (safe to --overwrite).
GENERATE_MARKER = "relit.json"


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "generate",
        help="relight one flash photo to new point lights",
        description="Relight a flash photo (light at the camera) to point lights. PHOTO is a PNG "
        "(tone-mapped: decoded with x^2.2) or an EXR (linear radiance). Writes relit_KK.exr (linear), "
        "relit_KK.png (tone-mapped) and relit.json. Positions are in scene units of the dgrsise "
        "preset (plane of side 4 at z = 0).",
    )
    p.add_argument("photo", type=Path, help="flash photo, .png or .exr")
    p.add_argument("--out", required=True, type=Path, help="output folder (created)")
    p.add_argument(
        "--light",
        action="append",
        metavar="X,Y,Z",
        help="target light position (repeat); default: the 7 evaluation lights",
    )
    p.add_argument(
        "--camera",
        default=",".join(str(v) for v in EVAL_CAMERA),
        metavar="X,Y,Z",
        help="camera (and flash) position (default %(default)s)",
    )
    p.add_argument(
        "--model",
        default="bieron",
        help="relighter: bieron, diffusion, estimator, lambertian, input, or any registered one (default %(default)s)",
    )
    p.add_argument("--checkpoint", type=Path, default=None, help="model folder (default: the shipped weights)")
    p.add_argument("--seed", type=int, default=0, help="seed of stochastic models")
    p.add_argument("--steps", type=int, default=None, help="sampling steps of the diffusion model (default 20)")
    p.add_argument(
        "--samples",
        type=int,
        default=None,
        help="diffusion: average this many samples per light (lower error, proportionally slower; default 1)",
    )
    p.add_argument("--overwrite", action="store_true", help="replace an output folder written by this command")
    p.set_defaults(run=run)


def read_photo(path: Path) -> torch.Tensor:
    """``[C, H, W]`` linear radiance from a PNG (inverse tone map) or an EXR (as stored)."""
    import kernels
    from materials.io import read_exr, read_png
    from materials.io.encoding import hwc_to_chw

    suffix = path.suffix.lower()
    if suffix == ".exr":
        return hwc_to_chw(read_exr(path))
    if suffix == ".png":
        return kernels.inverse_tonemap(hwc_to_chw(read_png(path)))
    raise UsageError(f"photo {str(path)!r} must be a .png (tone-mapped) or .exr (linear) file")


def run(args) -> int:
    from matcap.estimator_relighter import register
    from materials.io.atomic import atomic_folder
    from relight.interface import get_relighter, relighter_names

    register()
    check_output_folder(args.out, overwrite=args.overwrite, marker=GENERATE_MARKER)
    camera_pos = torch.tensor(parse_position(args.camera, "--camera"))
    light_pos = positions_or_default(args.light, torch.tensor(EVAL_LIGHTS, dtype=torch.float32), "--light")
    photo = read_photo(args.photo)
    if photo.shape[0] != 3:
        raise UsageError(f"photo {str(args.photo)!r} has {photo.shape[0]} channel(s); expected 3 (RGB)")
    try:
        relighter = get_relighter(args.model, args.checkpoint)
    except ValueError:
        if args.model in relighter_names():
            raise  # a known relighter that failed to load: its own message
        # Plugins register when imported: import them all, so the list is complete.
        known = relighter_names(discover=True)
        raise UsageError(f"unknown relighter {args.model!r}; known: {', '.join(known)}") from None
    set_sampling(relighter, args.model, args.steps, args.samples)
    gen = torch.Generator().manual_seed(args.seed)
    # One light per call, so a slow model (diffusion sampling, a large photo) shows
    # progress; the generator carries on from light to light.
    relit = torch.cat(
        [
            relighter.relight(
                photo=photo[None], light_pos=light_pos[None, k : k + 1], camera_pos=camera_pos[None], generator=gen
            )[0]
            for k in tqdm(range(len(light_pos)), desc=f"relight ({args.model})", unit="light", leave=False)
        ]
    )
    with atomic_folder(args.out, overwrite=args.overwrite, marker=GENERATE_MARKER) as tmp:
        files = []
        for k, image in enumerate(relit):
            write_image_pair(tmp, f"relit_{k:02d}", image)
            files.append(f"relit_{k:02d}.exr")
        info = {
            "photo": str(args.photo),
            "model": args.model,
            "checkpoint": str(args.checkpoint) if args.checkpoint else "shipped",
            "camera": camera_pos.tolist(),
            "lights": light_pos.tolist(),
            "seed": args.seed,
            "steps": getattr(relighter, "steps", None),
            "samples": getattr(relighter, "num_samples", None),
            "files": files,
        }
        (tmp / GENERATE_MARKER).write_text(json.dumps(info, indent=2))
    print(f"wrote {len(relit)} relit images to {args.out}")
    return 0
