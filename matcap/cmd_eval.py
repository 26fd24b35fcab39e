"""``relight eval relighting``: the Table-1-style relighting evaluation (``relight.evaluate``);
``relight eval estimation``: the Table-2-style estimator evaluation (``estimator.evaluate``);
``relight eval capture``: Tables 2 and 4 through the whole capture pipeline
(``matcap.capture_eval``).

The targets were called ``relight`` and ``estimator`` before; those spellings still work
for one release, with a deprecation note on stderr (``DEPRECATED_TARGETS``).
"""

from __future__ import annotations

import argparse
import copy
import shlex
import sys
from dataclasses import replace
from pathlib import Path

from matcap.args import check_at_least_one, parse_map_names, set_sampling
from matcap.errors import UsageError
from matcap.outputs import check_output_folder

__all__ = ["add_parser", "run", "EVAL_MARKER", "ESTIMATOR_EVAL_MARKER", "DEPRECATED_TARGETS"]

#: File that marks a folder written by ``relight eval relighting`` (safe to --overwrite).
EVAL_MARKER = "relight_eval.json"
#: Old target names (before issue 17) -> today's; accepted as aliases for one release.
DEPRECATED_TARGETS = {"relight": "relighting", "estimator": "estimation"}


def _note_deprecated(args) -> None:
    """One line on stderr when the target was spelled the old way."""
    new = DEPRECATED_TARGETS.get(args.what)
    if new is not None:
        print(
            f"relight eval {args.what}: deprecated name, use 'relight eval {new}' "
            "(the old name will be removed in the next release)",
            file=sys.stderr,
        )


#: File that marks a folder written by ``relight eval estimator`` (safe to --overwrite).
ESTIMATOR_EVAL_MARKER = "estimator_eval.json"


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "eval", help="evaluations (relighting, estimation, capture)", description="Evaluations of the models."
    )
    what = p.add_subparsers(dest="what", required=True, metavar="WHAT")
    r = what.add_parser(
        "relighting",
        aliases=["relight"],
        help="relighting metrics on held-out procedural materials (Table 1 style; "
        "'relight' is the deprecated old name)",
        description="Relight held-out procedural materials from their flash photo to the 7 evaluation "
        "lights with each method; writes relight_eval.md (table), relight_eval.json (per-image values) "
        "and relight_eval.png (pictures).",
    )
    r.add_argument("--out", required=True, type=Path, help="output folder (created)")
    r.add_argument("--count", type=int, default=16, help="held-out materials (default %(default)s)")
    r.add_argument("--size", type=int, default=64, help="image side in pixels (default %(default)s)")
    r.add_argument(
        "--methods",
        default=None,
        help="comma-separated relighter names (default: every registered one whose weights are present)",
    )
    r.add_argument(
        "--checkpoint",
        action="append",
        default=[],
        metavar="NAME=PATH",
        help="checkpoint folder of a method (repeat); default: its shipped weights",
    )
    r.add_argument(
        "--samples",
        type=int,
        default=1,
        help="samples of stochastic methods; >1 adds a 'mean of N' row (default %(default)s)",
    )
    r.add_argument(
        "--steps",
        default=None,
        metavar="N[,N...]",
        help="sampling steps of stochastic methods "
        "(default: theirs, 20 for diffusion); several, e.g. 10,1, evaluate each setting in the "
        "same run as rows 'NAME (N steps)'",
    )
    r.add_argument(
        "--large",
        default=None,
        metavar="MODE[,MODE...]",
        help="how network relighters treat a photo larger than their native 64 px: global (the "
        "whole plane at 64 px, detail from the Lambertian re-shading), tiles (64 px windows; "
        "diffusion), whole (fully convolutional; bieron); several evaluate each in the same run "
        "as rows 'NAME (MODE)' (default: each relighter's own, global for diffusion, whole for bieron)",
    )
    r.add_argument(
        "--domain",
        choices=("paper", "capture"),
        default="paper",
        help="paper: clean renders, camera (0, 0, 4), the 7 evaluation lights (Table 1); capture: "
        "phone-like photos (random camera, exposure, noise, clipped highlight, 8-bit, JPEG) and "
        "unclipped targets (default %(default)s)",
    )
    r.add_argument(
        "--first",
        type=int,
        default=0,
        help="index of the first held-out material (16: the validation materials; default %(default)s)",
    )
    r.add_argument(
        "--p-crop",
        type=float,
        default=None,
        metavar="P",
        help="with --domain capture, the share of photos showing a window of the plane instead of the "
        "whole plane (0: whole planes only; default: the capture domain's, 0.5)",
    )
    r.add_argument("--chunk", type=int, default=4, help="materials per relight call (default %(default)s)")
    r.add_argument("--seed", type=int, default=0, help="generator seed of stochastic methods")
    r.add_argument("--overwrite", action="store_true", help="replace an output folder written by this command")
    r.set_defaults(run=run)
    e = what.add_parser(
        "estimation",
        aliases=["estimator"],
        help="SVBRDF estimator metrics, 1 vs 8 inputs, with and without refinement (Table 2 style; "
        "'estimator' is the deprecated old name)",
        description="Held-out procedural materials, 1 input (flash) and 8 (flash + 7 renders), each "
        "with and without refinement: map MSE and re-rendered PSNR/SSIM under 16 held-out lights, "
        "plus diffuse error inside the highlight on the most specular third.",
    )
    e.add_argument("--out", required=True, type=Path, help="output folder (created)")
    e.add_argument("--model", type=Path, default=None, help="estimator folder (default: the shipped one)")
    e.add_argument("--num", type=int, default=16, help="held-out materials (default %(default)s)")
    e.add_argument("--size", type=int, default=64, help="image side (default %(default)s)")
    e.add_argument("--refine-steps", type=int, default=100, help="refinement steps (default %(default)s)")
    e.add_argument("--num-threads", type=int, default=None, help="torch threads")
    e.add_argument("--overwrite", action="store_true", help="replace an output folder written by this command")
    e.set_defaults(run=run_estimator)
    _add_capture_parser(what)


def _add_capture_parser(what) -> None:
    from matcap.capture_eval import RUNS, SETS

    c = what.add_parser(
        "capture",
        help="the capture pipeline on rendered flash photos: photo alone vs + relit views vs + ground "
        "truth (Table 2), 1 / 4 / 8 inputs (Table 4)",
        description="Render each held-out material as an 8-bit flash photo, run `relight capture`'s "
        "pipeline once per run (photo alone; + 3 or 7 diffusion-relit views; + 7 Bieron-style; + 7 "
        "ground-truth renders) and score the maps: map MSE, diffuse MSE inside the flash highlight, "
        "re-render PSNR / SSIM / FLIP under 128 novel lights. Writes capture_eval.md and capture_eval.json.",
    )
    c.add_argument("--out", required=True, type=Path, help="output folder (created)")
    c.add_argument(
        "--sets", default="procedural,inria", help=f"comma-separated, of {', '.join(SETS)} (default %(default)s)"
    )
    c.add_argument("--runs", default=",".join(RUNS), help="comma-separated (default %(default)s)")
    c.add_argument("--count", type=int, default=8, help="materials per synthetic set (default %(default)s)")
    c.add_argument("--size", type=int, default=256, help="photo side in pixels (default %(default)s)")
    c.add_argument("--textures", type=Path, default=None, help="folder of texture material folders (the textures set)")
    c.add_argument("--inria", type=Path, default=None, help="folder of INRIA PNGs (default: synthesised held-out ones)")
    c.add_argument("--refine", type=int, default=None, help="refinement steps (default: the pipeline's)")
    c.add_argument(
        "--samples", type=int, default=1, help="diffusion samples per relit view, averaged (default %(default)s)"
    )
    c.add_argument(
        "--relit-size", type=int, default=None, help="side of the relit views (default: the pipeline's, 256)"
    )
    c.add_argument(
        "--estimate-size",
        type=int,
        default=None,
        metavar="PX",
        help="side the estimator sees the views at (default: the pipeline's, 256)",
    )
    c.add_argument(
        "--relit-robust",
        type=float,
        default=None,
        metavar="TAU",
        help="robust refinement loss of the relit views at this scale (default: log-L1)",
    )
    c.add_argument(
        "--relit-highlight",
        type=float,
        default=None,
        metavar="DEG",
        help="half-angle of the flash-highlight disc the relit views' refinement loss leaves out "
        "(0: none; default: the pipeline's)",
    )
    c.add_argument(
        "--flatness",
        type=float,
        default=None,
        metavar="W",
        help="weight of the refinement's flat-sample normal prior (default: the pipeline's)",
    )
    c.add_argument(
        "--radial",
        type=float,
        default=None,
        metavar="W",
        help="weight of the refinement's flash-independence prior (default: the pipeline's)",
    )
    c.add_argument(
        "--radial-maps",
        default=None,
        metavar="NAMES",
        help="comma-separated maps the flash-independence prior looks at (default: the pipeline's)",
    )
    c.add_argument(
        "--vignetting",
        choices=("off", "photo", "all"),
        default=None,
        help="which views the refinement's fitted radial gain multiplies (default: the pipeline's)",
    )
    c.add_argument(
        "--photo-vignetting",
        default=None,
        metavar="A1,A2",
        help="darken the rendered photos by the radial gain exp(A1 rho^2 + A2 rho^4) about their centre "
        "(rho in half-sides; each A <= 0), as a flash's beam and a lens do (default none)",
    )
    c.add_argument(
        "--photo-offset",
        default=None,
        metavar="X,Y",
        help="render the photos with the camera and flash this far (scene units, plane of side 4) from above "
        "the centre, as an off-centre phone photo (default 0,0)",
    )
    c.add_argument(
        "--flash-point",
        choices=("centre", "auto"),
        default=None,
        help="where the pipeline puts the camera: above the photo's centre or above the flash highlight "
        "it locates (default: the pipeline's)",
    )
    c.add_argument(
        "--relit-weight",
        type=float,
        default=None,
        metavar="W",
        help="refinement weight of each relit view, the photo's is 1 (default: the pipeline's)",
    )
    c.add_argument(
        "--relit-maps",
        default=None,
        metavar="NAMES",
        help="comma-separated maps the relit views' refinement loss may change (default: the pipeline's)",
    )
    c.add_argument(
        "--photo-maps",
        default=None,
        metavar="NAMES",
        help="comma-separated maps the estimator takes from the photo alone ('none': none; default: the pipeline's)",
    )
    c.add_argument(
        "--shared-step-maps",
        default=None,
        metavar="NAMES",
        help="comma-separated maps whose refinement step size is shared by their pixels ('none': none; "
        "default: the pipeline's)",
    )
    c.add_argument("--estimator", type=Path, default=None, help="estimator folder (default: the shipped one)")
    c.add_argument(
        "--large",
        default=None,
        metavar="MODE",
        help="how the network relighters that take the mode treat relit views larger than their native "
        "64 px: global, tiles (diffusion) or whole (bieron) (default: each relighter's own, global for "
        "diffusion, whole for bieron)",
    )
    c.add_argument(
        "--checkpoint",
        action="append",
        default=[],
        metavar="NAME=PATH",
        help="weights folder of a relighter (diffusion, bieron; repeat); default: its shipped weights",
    )
    c.add_argument("--num-threads", type=int, default=None, help="torch threads")
    c.add_argument("--overwrite", action="store_true", help="replace an output folder written by this command")
    c.set_defaults(run=run_capture)


def run_capture(args) -> int:
    import torch

    from matcap.capture import CaptureConfig
    from matcap.capture_eval import EVAL_MARKER as CAPTURE_MARKER
    from matcap.capture_eval import RUNS, CaptureEvalConfig, evaluate, format_tables, write_report
    from matcap.estimate import load_estimator
    from materials.io.atomic import atomic_folder
    from relight.interface import get_relighter

    check_output_folder(args.out, overwrite=args.overwrite, marker=CAPTURE_MARKER)
    check_at_least_one("--samples", args.samples)
    try:
        overrides = {
            "estimate_size": args.estimate_size,
            "relit_size": args.relit_size,
            "flatness": args.flatness,
            "radial": args.radial,
            "relit_weight": args.relit_weight,
            "relit_highlight": args.relit_highlight,
            "relit_maps": parse_map_names(args.relit_maps, "--relit-maps", allow_none=False),
            "radial_maps": parse_map_names(args.radial_maps, "--radial-maps"),
            "vignetting": args.vignetting,
            "flash_point": args.flash_point,
            "photo_maps": parse_map_names(args.photo_maps, "--photo-maps"),
            "shared_step_maps": parse_map_names(args.shared_step_maps, "--shared-step-maps"),
        }
        capture = CaptureConfig(
            samples=args.samples,
            relit_robust=args.relit_robust,
            **{k: v for k, v in overrides.items() if v is not None},
        )
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    if args.refine is not None:
        capture = replace(capture, refine_steps=args.refine)
    split = lambda text: tuple(v.strip() for v in text.split(",") if v.strip())  # noqa: E731
    try:
        cfg = CaptureEvalConfig(
            sets=split(args.sets),
            runs=split(args.runs),
            count=args.count,
            size=args.size,
            textures=None if args.textures is None else str(args.textures),
            inria=None if args.inria is None else str(args.inria),
            capture=capture,
            photo_vignetting=() if args.photo_vignetting is None else _floats(args.photo_vignetting),
            photo_offset=(0.0, 0.0) if args.photo_offset is None else _floats(args.photo_offset, "--photo-offset"),
        )
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    for name, folder in (("--textures", args.textures), ("--inria", args.inria)):
        if folder is not None and not folder.is_dir():
            raise UsageError(f"{name} {folder} is not a folder")
    if args.num_threads:
        torch.set_num_threads(args.num_threads)
    needed = sorted({RUNS[r][0] for r in cfg.runs} - {None, "gt"})
    large = _large_list(args.large)
    if large is not None and len(large) > 1:
        raise UsageError(f"--large {args.large!r}: eval capture takes one mode (its rows are named by --runs)")
    if large is not None and not needed:
        raise UsageError("--large applies to relit views; no run of --runs uses a relighter")
    checkpoints = _checkpoints(args.checkpoint)
    unused = sorted(set(checkpoints) - set(needed))
    if unused:
        raise UsageError(f"--checkpoint {', '.join(unused)}: no run of --runs uses it (they use: {', '.join(needed)})")
    estimator = load_estimator(args.estimator)
    relighters = {name: get_relighter(name, checkpoints.get(name)) for name in needed}
    if large is not None:
        relighters = _expand_large(relighters, large)
    command = "relight " + " ".join(shlex.quote(a) for a in sys.argv[1:]) if sys.argv[1:2] == ["eval"] else None
    report = evaluate(cfg, estimator, relighters)
    with atomic_folder(args.out, overwrite=args.overwrite, marker=CAPTURE_MARKER) as tmp:
        write_report(report, tmp, command=command)
    print(format_tables(report))
    print(f"wrote {args.out}")
    return 0


def run_estimator(args) -> int:
    _note_deprecated(args)
    from estimator.evaluate import cli
    from materials.io.atomic import atomic_folder
    from weights import weights_dir

    check_output_folder(args.out, overwrite=args.overwrite, marker=ESTIMATOR_EVAL_MARKER)
    flags = [
        "--model",
        str(args.model or weights_dir("estimator")),
        "--num",
        str(args.num),
        "--size",
        str(args.size),
        "--refine-steps",
        str(args.refine_steps),
    ]
    if args.num_threads:
        flags += ["--num-threads", str(args.num_threads)]
    # The evaluation writes into the folder it is given: give it a temporary one, so an
    # existing folder is never written into file by file (and a failed run leaves nothing).
    with atomic_folder(args.out, overwrite=args.overwrite, marker=ESTIMATOR_EVAL_MARKER) as tmp:
        cli([*flags, "--out", str(tmp)])
    return 0


def _checkpoints(items: list[str]) -> dict[str, str]:
    out = {}
    for item in items:
        name, sep, path = item.partition("=")
        if not sep or not name or not path:
            raise UsageError(f"--checkpoint {item!r} must be NAME=PATH")
        out[name] = path
    return out


def _floats(text: str, flag: str = "--photo-vignetting") -> tuple[float, ...]:
    """``--photo-vignetting`` / ``--photo-offset`` value -> its numbers (the count and
    range are the config's to check)."""
    try:
        return tuple(float(v) for v in text.split(","))
    except ValueError:
        raise UsageError(f"{flag} {text!r} must be comma-separated numbers, e.g. -0.3,-0.05") from None


def _steps_list(text: str | None) -> list[int] | None:
    """``--steps`` value -> step counts (each at least 1, no repeats), or None."""
    if text is None:
        return None
    try:
        values = [int(v) for v in text.split(",")]
    except ValueError:
        raise UsageError(f"--steps {text!r} must be a whole number or a comma-separated list of them") from None
    for v in values:
        check_at_least_one("--steps", v)
    if len(set(values)) != len(values):
        raise UsageError(f"--steps {text!r} repeats a value")
    return values


def _expand_steps(relighters: dict, steps: list[int]) -> dict:
    """Apply ``--steps`` to the sampling relighters; with several values, each sampling
    method becomes one entry per value (shallow copies sharing the model)."""
    from relight.evaluate import step_count

    sampling = [n for n, r in relighters.items() if getattr(r, "stochastic", False)]
    if not sampling:
        raise UsageError(f"--steps applies to sampling methods (diffusion); none of {', '.join(relighters)} samples")
    out = {}
    for name, relighter in relighters.items():
        if name not in sampling:
            out[name] = relighter
        elif len(steps) == 1:
            set_sampling(relighter, name, steps[0])
            out[name] = relighter
        else:
            for n in steps:
                variant = copy.copy(relighter)
                set_sampling(variant, name, n)
                out[f"{name} ({step_count(n)})"] = variant
    return out


def _large_list(text: str | None) -> list[str] | None:
    """``--large`` value -> modes (each in ``relight.detail.LARGE_MODES``, no repeats), or None."""
    from relight.detail import LARGE_MODES

    if text is None:
        return None
    values = [v.strip() for v in text.split(",") if v.strip()]
    for v in values:
        if v not in LARGE_MODES:
            raise UsageError(f"--large {v!r} is not one of {', '.join(LARGE_MODES)}")
    if not values or len(set(values)) != len(values):
        raise UsageError(f"--large {text!r} must name modes, each once")
    return values


def _expand_large(relighters: dict, modes: list[str]) -> dict:
    """Apply ``--large`` to the relighters that have the modes (``large_modes``); with
    several modes, each such relighter becomes one entry per mode it accepts (shallow
    copies sharing the model), the others stay as they are."""
    out, taken = {}, False
    for name, relighter in relighters.items():
        accepted = [m for m in modes if m in getattr(relighter, "large_modes", ())]
        taken = taken or bool(accepted)
        if not accepted:
            out[name] = relighter
            continue
        for mode in accepted:
            variant = copy.copy(relighter)
            variant.large = mode
            out[name if len(modes) == 1 else f"{name} ({mode})"] = variant
    if not taken:
        raise UsageError(
            f"--large applies to network relighters (diffusion, bieron); none of {', '.join(relighters)} takes {', '.join(modes)}"
        )
    return out


def run(args) -> int:
    from matcap.estimator_relighter import register
    from materials.io.atomic import atomic_folder
    from relight.evaluate import EvalConfig, evaluate, format_table, write_report
    from relight.interface import get_relighter, relighter_names

    _note_deprecated(args)
    register()  # the estimator's 1-input maps re-rendered: a Table-1 baseline

    check_output_folder(args.out, overwrite=args.overwrite, marker=EVAL_MARKER)
    steps = _steps_list(args.steps)  # before any model is loaded
    large = _large_list(args.large)
    try:
        cfg = EvalConfig(
            count=args.count,
            size=args.size,
            chunk=args.chunk,
            samples=args.samples,
            seed=args.seed,
            domain=args.domain,
            **({} if args.p_crop is None else {"p_crop": args.p_crop}),
            first=args.first,
        )
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    checkpoints = _checkpoints(args.checkpoint)
    known = relighter_names(discover=True)
    explicit = args.methods is not None
    names = [n.strip() for n in args.methods.split(",") if n.strip()] if explicit else known
    if not names:
        raise UsageError("--methods names no method")
    for name in list(names) + list(checkpoints):
        if name not in known:
            raise UsageError(f"unknown method {name!r}; known: {', '.join(known)}")
    relighters = {}
    for name in names:
        try:
            relighters[name] = get_relighter(name, checkpoints.get(name))
        except FileNotFoundError as exc:
            if explicit or name in checkpoints:
                raise
            print(f"skipping {name}: {exc}", file=sys.stderr)
    if steps is not None:
        relighters = _expand_steps(relighters, steps)
    if large is not None:
        relighters = _expand_large(relighters, large)
    command = "relight " + " ".join(shlex.quote(a) for a in sys.argv[1:]) if sys.argv[1:2] == ["eval"] else None
    result = evaluate(relighters, cfg)
    with atomic_folder(args.out, overwrite=args.overwrite, marker=EVAL_MARKER) as tmp:
        write_report(result, tmp, command=command)
    print(format_table(result))
    print(f"wrote {args.out}")
    return 0
