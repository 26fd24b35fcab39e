"""``relight train MODEL [flags]``: run a model's training entry point.

Each model keeps its own typed ``TrainConfig`` and ``parse_args(argv)`` (on the shared
``training`` stack); this command only picks the module, so ``relight train estimator
--steps 10`` equals ``python -m estimator.train --steps 10``.
"""

from __future__ import annotations

import argparse
import importlib
import sys

__all__ = ["add_parser", "run", "TRAINERS", "ALIASES"]

#: Model name -> training module (each has ``parse_args(argv, prog=...)`` and ``main(cfg)``).
TRAINERS = {
    "diffusion": "relight.diffusion.train",
    "bieron": "relight.bieron.train",
    "estimator": "estimator.train",
}

#: Old target names, kept for one release (a note on stderr says the new one).
ALIASES = {"relight": "diffusion"}


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "train",
        help="train a model (diffusion relighter, bieron baseline, estimator)",
        description="Train a model; flags after MODEL go to its trainer "
        "(see `relight train MODEL --help`). Several processes: "
        "`ACCELERATE_USE_CPU=1 accelerate launch --multi_gpu --num_processes 2 -m <module> ...` "
        "on a CPU, `accelerate launch` on GPUs.",
    )
    p.add_argument(
        "model",
        choices=[*TRAINERS, *ALIASES],
        metavar="{" + ",".join(TRAINERS) + "}",
        help="what to train (`relight` is the old name of `diffusion`, kept for one release)",
    )
    p.add_argument("flags", nargs=argparse.REMAINDER, help="the trainer's own flags")
    p.set_defaults(run=run)


def run(args) -> int:
    name = args.model
    if name in ALIASES:
        print(
            f"relight train: note: `relight train {name}` is deprecated (removed in the next release); "
            f"use `relight train {ALIASES[name]}`",
            file=sys.stderr,
        )
        name = ALIASES[name]
    module = importlib.import_module(TRAINERS[name])
    cfg = module.parse_args(args.flags, prog=f"relight train {name}")
    module.main(cfg)
    return 0
