"""``relight capture``: one flash photo -> relit views -> SVBRDF maps, exports, re-renders."""

from __future__ import annotations

import argparse
from pathlib import Path

from matcap.args import check_at_least_one, parse_map_names, parse_position
from matcap.errors import UsageError

__all__ = ["add_parser", "run", "read_capture_photo", "BUILTIN"]

#: PHOTO value that asks for the built-in flash photo (``builtin`` or ``builtin:NAME``).
BUILTIN = "builtin"


def add_parser(sub: argparse._SubParsersAction) -> None:
    # Defaults are imported lazily by run(); the help repeats them as plain numbers (a
    # test keeps them equal to matcap.capture's constants).
    p = sub.add_parser(
        "capture",
        help="flash photo -> relit views -> SVBRDF maps (EXR, PNG, glTF) and re-renders",
        description="Capture a material from one flash photo: relight it to K lights, estimate "
        "diffuse/normal/roughness/specular maps from the photo and the relit views, refine them at "
        "the photo's full resolution, and write material/ (EXR + PNG maps, metallic-roughness, "
        "material.glb), renders/, relit/, capture/ (rerun with `relight estimate`), preview.png and "
        "provenance.json. PHOTO: a PNG (8/16-bit), JPEG or EXR, 64 to 2048 pixels a side; or "
        "'builtin' / 'builtin:NAME' (a procedural material the project renders under the flash; "
        "NAME a seed or a family). Scene: the camera and flash above the photo's flash highlight (or its centre) at a 45 "
        "degree field of view across its long side (or the EXIF focal length, --fov, --camera).",
    )
    p.add_argument("photo", help="flash photo (.png, .jpg, .exr) or 'builtin[:NAME]'")
    p.add_argument("--out", required=True, type=Path, help="output folder (created)")
    p.add_argument("--relit", type=int, default=7, metavar="K", help="relit views, 0-7 (0: the photo alone; default 7)")
    where = p.add_mutually_exclusive_group()
    where.add_argument("--camera", metavar="X,Y,Z", help="camera and flash position, scene units (plane of side 4)")
    where.add_argument("--fov", type=float, metavar="DEG", help="field of view across the photo's long side")
    p.add_argument(
        "--flash-point",
        choices=("centre", "auto"),
        default=None,
        help="camera and flash above the flash highlight located in the photo (auto, the default: photos are "
        "rarely taken exactly over the centre; the centre when no clear highlight is found) or above its centre",
    )
    p.add_argument("--relighter", default="diffusion", metavar="NAME", help="relighting model (default diffusion)")
    p.add_argument("--relighter-checkpoint", type=Path, default=None, help="relighter folder (default: shipped)")
    p.add_argument("--estimator", type=Path, default=None, help="estimator folder (default: the shipped one)")
    p.add_argument("--steps", type=int, default=None, help="diffusion sampling steps (default 1, its best setting)")
    p.add_argument("--samples", type=int, default=None, help="samples per relit view; 2+ adds a confidence map")
    p.add_argument(
        "--refine", type=int, default=None, metavar="STEPS", help="full-resolution refinement steps (default 100)"
    )
    p.add_argument(
        "--relit-weight",
        type=float,
        default=None,
        help="refinement weight of each relit view; the photo's is 1 (default 0.03: the relit views "
        "mostly inform the estimator, the refinement mostly fits the photo)",
    )
    p.add_argument(
        "--relit-highlight",
        type=float,
        default=None,
        metavar="DEG",
        help="leave the photo's flash highlight out of the relit views' refinement loss: the disc "
        "within DEG degrees under the flash and the photo's clipped pixels (default 0: off; 6 helped held-out "
        "photos and stamped a dark disc on some real ones)",
    )
    p.add_argument(
        "--relit-maps",
        default=None,
        metavar="NAMES",
        help="maps the relit views may change in the refinement, comma-separated; the others are "
        "fitted to the photo alone (default diffuse,roughness,specular: the relit views tilted real photos' normals)",
    )
    p.add_argument(
        "--photo-maps",
        default=None,
        metavar="NAMES",
        help="maps the estimator takes from the photo alone, comma-separated, or none; the others "
        "from the photo and the relit views (default diffuse,normal)",
    )
    p.add_argument(
        "--shared-step-maps",
        default=None,
        metavar="NAMES",
        help="maps whose refinement step size is shared by all their pixels, comma-separated, or none; "
        "the others get Adam per pixel (default normal: steps per pixel crease the normals through the flash)",
    )
    p.add_argument(
        "--flatness",
        type=float,
        default=None,
        metavar="W",
        help="refinement weight of the flat-sample prior against low-frequency normal tilt (default 3; 0 turns it off)",
    )
    p.add_argument(
        "--radial",
        type=float,
        default=None,
        metavar="W",
        help="refinement weight of the flash-independence prior against discs and rings centred on the flash "
        "(default 1; 0 turns it off)",
    )
    p.add_argument(
        "--radial-maps",
        default=None,
        metavar="NAMES",
        help="maps the flash-independence prior looks at, comma-separated (default normal,roughness,specular)",
    )
    p.add_argument(
        "--vignetting",
        choices=("off", "photo", "all"),
        default=None,
        help="fit a smooth darkening radial gain (a flash's beam, a lens's vignetting) with the maps, "
        "on the render of the photo or of all views (default off)",
    )
    p.add_argument(
        "--falloff",
        choices=("none", "inverse-square"),
        default=None,
        help="the flash's light falloff in the photo (default inverse-square: a phone flash)",
    )
    p.add_argument(
        "--relit-size",
        type=int,
        default=None,
        metavar="PX",
        help="side of the relit views, a multiple of 64 (default 256, or the largest multiple of 64 "
        "that divides the padded photo's side); above the networks' 64 px the whole plane is relit "
        "at 64 px with the photo's detail carried at full size (relight.detail); refined against at that size",
    )
    p.add_argument(
        "--estimate-size",
        type=int,
        default=None,
        metavar="PX",
        help="side the estimator sees the photo and relit views at, a multiple of 64 (default 256, "
        "or the photo's side when smaller); the maps are then refined at the photo's resolution",
    )
    p.add_argument("--max-side", type=int, default=None, help="downscale photos longer than this (at most 2048)")
    p.add_argument("--seed", type=int, default=0, help="seed of the relighter's sampling (default 0)")
    p.add_argument(
        "--normals",
        choices=("opengl", "directx"),
        default="opengl",
        help="normal map convention of the exported files (default opengl: green up, Blender/Unity; "
        "directx: green down, Unreal)",
    )
    p.add_argument(
        "--tileable",
        action="store_true",
        help="also write material_tileable/: the maps blended with their half-period shift so they "
        "repeat without a seam (the blend band softens detail; seam errors in its export.json)",
    )
    p.add_argument("--overwrite", action="store_true", help="replace an output folder written by this command")
    p.set_defaults(run=run)


def read_capture_photo(text: str, falloff: str):
    """``builtin[:NAME]`` -> ``builtin_photo``; anything else -> ``materials.io.read_photo``."""
    from matcap.capture import builtin_photo
    from materials.io import read_photo

    if text == BUILTIN or text.startswith(BUILTIN + ":"):
        try:
            return builtin_photo(text[len(BUILTIN) + 1 :], falloff=falloff)
        except ValueError as err:
            raise UsageError(str(err)) from None
    return read_photo(text)


def _config(args):
    """The ``CaptureConfig`` of the flags; a bad value is a ``UsageError`` naming its flag."""
    from matcap.capture import MAX_SIDE, WORKING_SIZE, CaptureConfig
    from materials.lights import EVAL_LIGHTS

    check_at_least_one("--steps", args.steps)
    check_at_least_one("--samples", args.samples)
    checks = [
        ("--relit", args.relit, lambda v: 0 <= v <= len(EVAL_LIGHTS), f"must be 0..{len(EVAL_LIGHTS)}"),
        ("--refine", args.refine, lambda v: v >= 0, "must be >= 0"),
        ("--relit-weight", args.relit_weight, lambda v: 0 <= v < float("inf"), "must be a number >= 0"),
        ("--flatness", args.flatness, lambda v: 0 <= v < float("inf"), "must be a number >= 0"),
        ("--relit-highlight", args.relit_highlight, lambda v: 0 <= v < 90, "must lie in [0, 90) degrees"),
        ("--radial", args.radial, lambda v: 0 <= v < float("inf"), "must be a number >= 0"),
        ("--fov", args.fov, lambda v: 0 < v < 180, "must lie strictly between 0 and 180 degrees"),
        ("--max-side", args.max_side, lambda v: WORKING_SIZE <= v <= MAX_SIDE, f"must be {WORKING_SIZE}..{MAX_SIDE}"),
        (
            "--relit-size",
            args.relit_size,
            lambda v: WORKING_SIZE <= v <= MAX_SIDE and v % WORKING_SIZE == 0,
            f"must be a multiple of {WORKING_SIZE} up to {MAX_SIDE}",
        ),
        (
            "--estimate-size",
            args.estimate_size,
            lambda v: WORKING_SIZE <= v <= MAX_SIDE and v % WORKING_SIZE == 0,
            f"must be a multiple of {WORKING_SIZE} up to {MAX_SIDE}",
        ),
    ]
    for flag, value, ok, rule in checks:
        if value is not None and not ok(value):
            raise UsageError(f"{flag} {rule}, got {value}")
    settings = {
        "relit": args.relit,
        "steps": args.steps,
        "samples": args.samples,
        "refine_steps": args.refine,
        "relit_weight": args.relit_weight,
        "relit_highlight": args.relit_highlight,
        "flatness": args.flatness,
        "radial": args.radial,
        "relit_maps": parse_map_names(args.relit_maps, "--relit-maps", allow_none=False),
        "radial_maps": parse_map_names(args.radial_maps, "--radial-maps"),
        "vignetting": args.vignetting,
        "photo_maps": parse_map_names(args.photo_maps, "--photo-maps"),
        "shared_step_maps": parse_map_names(args.shared_step_maps, "--shared-step-maps"),
        "falloff": args.falloff,
        "fov": args.fov,
        "camera": parse_position(args.camera, "--camera") if args.camera else None,
        "flash_point": args.flash_point,
        "max_side": args.max_side,
        "relit_size": args.relit_size,
        "estimate_size": args.estimate_size,
        "seed": args.seed,
    }
    try:
        return CaptureConfig(**{k: v for k, v in settings.items() if v is not None})
    except ValueError as exc:  # a combination the flags' own checks cannot see
        raise UsageError(str(exc)) from None


def run(args) -> int:
    from matcap.args import set_sampling
    from matcap.capture import PROVENANCE_JSON, CapturePipeline
    from matcap.estimate import load_estimator
    from matcap.estimator_relighter import register
    from matcap.outputs import check_output_folder
    from relight.interface import get_relighter, relighter_names

    config = _config(args)
    check_output_folder(args.out, overwrite=args.overwrite, marker=PROVENANCE_JSON)
    photo = read_capture_photo(args.photo, config.falloff)
    relighter = None
    if config.relit:
        register()
        try:
            relighter = get_relighter(args.relighter, args.relighter_checkpoint)
        except ValueError:
            if args.relighter in relighter_names():
                raise
            known = relighter_names(discover=True)
            raise UsageError(f"unknown relighter {args.relighter!r}; known: {', '.join(known)}") from None
        # Explicit --steps / --samples on a relighter that does not sample is an error.
        set_sampling(relighter, args.relighter, args.steps, None)
        if args.samples is not None and args.samples > 1 and not getattr(relighter, "stochastic", False):
            raise UsageError(f"--samples applies to sampling methods (diffusion), not to {args.relighter!r}")
    pipeline = CapturePipeline(
        relighter, load_estimator(args.estimator), config=config, names={"relighter": args.relighter}
    )
    output = pipeline(photo, progress=True)
    output.save(args.out, overwrite=args.overwrite, normal_convention=args.normals, tileable=args.tileable)
    h, w = output.photo.size
    print(
        f"wrote {w}x{h} maps (material/, material.glb), {len(output.renders)} re-renders, "
        f"{len(output.relit)} relit views and capture/ to {args.out}"
    )
    return 0
