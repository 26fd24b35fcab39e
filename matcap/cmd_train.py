"""``relight train MODEL [flags]``: run a model's training entry point.

Each model keeps its own typed ``TrainConfig`` and ``parse_args(argv)``; this command
only picks the module, so ``relight train estimator --steps 10`` equals
``python -m estimator.train --steps 10``.
"""

from __future__ import annotations

import argparse
import importlib

__all__ = ["add_parser", "run", "TRAINERS"]

#: Model name -> training module (each has ``parse_args(argv)`` and ``main(cfg)``).
TRAINERS = {
    "relight": "relight.diffusion.train",
    "bieron": "relight.bieron.train",
    "estimator": "estimator.train",
}


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "train",
        help="train a model (relight diffusion, bieron baseline, estimator)",
        description="Train a model; flags after MODEL go to its trainer "
        "(see `relight train MODEL --help`). Several processes: "
        "`ACCELERATE_USE_CPU=1 accelerate launch --multi_gpu --num_processes 2 -m <module> ...` "
        "on a CPU, `accelerate launch` on GPUs.",
    )
    p.add_argument("model", choices=sorted(TRAINERS))
    p.add_argument("flags", nargs=argparse.REMAINDER, help="the trainer's own flags")
    p.set_defaults(run=run)


def run(args) -> int:
    module = importlib.import_module(TRAINERS[args.model])
    cfg = module.parse_args(args.flags)
    module.main(cfg)
    return 0
