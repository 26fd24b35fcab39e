"""``relight generate``: relight one flash photo to new point lights with a chosen model."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import torch

from matcap.args import parse_position, positions_or_default, set_sampling
from matcap.errors import UsageError
from matcap.outputs import check_output_folder, write_image_pair
from materials.lights import EVAL_LIGHTS

__all__ = ["add_parser", "run", "read_photo", "GENERATE_MARKER", "DEFAULT_MODEL"]

#: File that marks a folder written by ``relight generate`` (safe to --overwrite).
GENERATE_MARKER = "relit.json"
#: The default relighter: the diffusion model at one sampling step, its best measured
#: setting (README "Relighting": 28.12 dB, against 27.12 for Bieron and 25.89 at 10 steps).
DEFAULT_MODEL = "diffusion"


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "generate",
        help="relight one flash photo to new point lights",
        description="Relight a flash photo (light at the camera) to point lights. PHOTO is a PNG "
        "(8/16-bit) or JPEG (tone-mapped: decoded with x^2.2) or an EXR (linear radiance), 64 to 2048 "
        "pixels a side, any aspect ratio (padded to a square for the model). Writes relit_KK.exr "
        "(linear) and relit_KK.png (tone-mapped) on the photo's pixel grid, relit.json, and capture/ "
        "(our capture format at the model's resolution: the photo as view 0, then the relit views; "
        "`relight estimate` reads it). Positions are in scene units of the dgrsise preset (plane of "
        "side 4 at z = 0); the default camera is `relight capture`'s: above the photo's centre at a "
        "45 degree field of view (or the EXIF focal length).",
    )
    p.add_argument("photo", type=Path, help="flash photo, .png, .jpg or .exr")
    p.add_argument("--out", required=True, type=Path, help="output folder (created)")
    p.add_argument(
        "--light",
        action="append",
        metavar="X,Y,Z",
        help="target light position (repeat); default: the 7 evaluation lights",
    )
    p.add_argument(
        "--camera",
        default=None,
        metavar="X,Y,Z",
        help="camera (and flash) position (default: above the photo's centre, 45 degree field of view)",
    )
    p.add_argument(
        "--model",
        default=DEFAULT_MODEL,
        help="relighter: diffusion, bieron, estimator, lambertian, input, or any registered one (default %(default)s)",
    )
    p.add_argument("--checkpoint", type=Path, default=None, help="model folder (default: the shipped weights)")
    p.add_argument("--seed", type=int, default=0, help="seed of stochastic models")
    p.add_argument(
        "--steps",
        type=int,
        default=None,
        help="sampling steps of the diffusion model (default 1, its best measured setting)",
    )
    p.add_argument(
        "--samples",
        type=int,
        default=None,
        help="diffusion: average this many samples per light (lower error, proportionally slower; default 1)",
    )
    p.add_argument("--overwrite", action="store_true", help="replace an output folder written by this command")
    p.set_defaults(run=run)


def read_photo(path: Path) -> torch.Tensor:
    """``[3, H, W]`` linear radiance of a photo file (``materials.io.read_photo``)."""
    from materials.io import read_photo as read

    return read(path).image


def run(args) -> int:
    from matcap.capture import (
        DEFAULT_RELIGHT_STEPS,
        MAX_SIDE,
        area_downsample,
        capture_scene,
        native_resolution,
        relight_views,
    )
    from matcap.estimator_relighter import register
    from materials.frame import prepare_photo
    from materials.io import read_photo as read
    from materials.io import write_capture
    from materials.io.atomic import atomic_folder
    from materials.types import Capture
    from relight.interface import get_relighter, relighter_names

    register()
    check_output_folder(args.out, overwrite=args.overwrite, marker=GENERATE_MARKER)
    camera = parse_position(args.camera, "--camera") if args.camera else None
    light_pos = positions_or_default(args.light, torch.tensor(EVAL_LIGHTS, dtype=torch.float32), "--light")
    photo = read(args.photo)
    if max(photo.size) > MAX_SIDE:
        h, w = photo.size
        raise UsageError(
            f"photo {str(args.photo)!r} is {w}x{h} (W x H); relighting runs at full resolution up to {MAX_SIDE} "
            "pixels on the long side: downscale it first"
        )
    try:
        relighter = get_relighter(args.model, args.checkpoint)
    except ValueError:
        if args.model in relighter_names():
            raise  # a known relighter that failed to load: its own message
        # Plugins register when imported: import them all, so the list is complete.
        known = relighter_names(discover=True)
        raise UsageError(f"unknown relighter {args.model!r}; known: {', '.join(known)}") from None
    steps = args.steps if args.steps is not None or not hasattr(relighter, "steps") else DEFAULT_RELIGHT_STEPS
    set_sampling(relighter, args.model, steps, args.samples)
    # A model with one input size (diffusion, 64 px) sees the photo padded to a square
    # and area-downsampled to it; the others see the padded photo at full resolution.
    native = native_resolution(relighter)
    image, frame = prepare_photo(photo, multiple=native or 8)
    working = area_downsample(image, native) if native else image
    scene = capture_scene(photo, frame, light_pos, falloff="none", camera=camera)
    gen = torch.Generator().manual_seed(args.seed)
    relit, _ = relight_views(
        relighter, working, light_pos, scene.camera_pos, generator=gen, progress=True, desc=f"relight ({args.model})"
    )
    with atomic_folder(args.out, overwrite=args.overwrite, marker=GENERATE_MARKER) as tmp:
        files = []
        for k, image in enumerate(frame.to_photo(relit)):
            write_image_pair(tmp, f"relit_{k:02d}", image)
            files.append(f"relit_{k:02d}.exr")
        capture = Capture(
            images=torch.cat([working[None], relit]),
            light_pos=torch.cat([scene.camera_pos[None], light_pos]),
            camera_pos=scene.camera_pos.expand(1 + len(light_pos), 3).clone(),
            plane_size=frame.plane_size,
            meta={
                "made_by": "relight generate",
                "photo": str(args.photo),
                "model": args.model,
                "frame": frame.to_dict(),
            },
        )
        write_capture(tmp / "capture", capture)
        info = {
            "photo": str(args.photo),
            "model": args.model,
            "checkpoint": str(args.checkpoint) if args.checkpoint else "shipped",
            "camera": scene.camera_pos.tolist(),
            "camera_source": scene.camera_source,
            "lights": light_pos.tolist(),
            "seed": args.seed,
            "steps": getattr(relighter, "steps", None),
            "samples": getattr(relighter, "num_samples", None),
            "frame": frame.to_dict(),
            "model_resolution": native,
            "files": files,
            "capture": "capture/: the photo (prepared) and the relit views at the model's resolution",
        }
        (tmp / GENERATE_MARKER).write_text(json.dumps(info, indent=2))
    print(f"wrote {len(relit)} relit images and capture/ to {args.out}")
    return 0
