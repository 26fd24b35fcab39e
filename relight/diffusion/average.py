"""Average the weights of several checkpoints of one training run (post-hoc weight averaging).

    python -m relight.diffusion.average --out DIR CKPT [CKPT ...] [--half]

Training runs at a constant learning rate with one material per step, so consecutive
checkpoints scatter around a minimum; the mean of the last few (snapshots a few hundred
steps apart, e.g. the trainer's ``--keep-every`` copies) sits nearer its centre. This is
the stochastic weight averaging of Izmailov et al. 2018, and an after-the-fact stand-in
for the exponential moving average diffusion models are usually sampled from. Only the
weights are averaged: the result is an ordinary checkpoint (``save_pretrained``).
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path
from typing import Sequence

import torch

from relight.diffusion.model import RelightDiffusion

__all__ = ["average_checkpoints", "main"]


def average_checkpoints(folders: Sequence[str | os.PathLike]) -> RelightDiffusion:
    """The model whose every weight is the mean of the checkpoints' (float64 sum, then cast).

    Args:
        folders: at least one ``save_pretrained`` folder (or a training checkpoint's
            ``model`` folder), all with the same ``RelightConfig``.
    Returns:
        A ``RelightDiffusion`` with the first checkpoint's config.
    Raises:
        ValueError: no folder, or configs that differ (weights of different
            architectures or switches cannot be averaged meaningfully).
    """
    if not folders:
        raise ValueError("average_checkpoints needs at least one checkpoint folder")
    models = [RelightDiffusion.from_pretrained(f) for f in folders]
    first = models[0]
    for folder, m in zip(folders[1:], models[1:]):
        if m.config != first.config:
            raise ValueError(f"{folder}: config differs from {folders[0]}'s; only checkpoints of one run can be averaged")
    states = [m.state_dict() for m in models]
    averaged = {}
    for key, value in states[0].items():
        if value.is_floating_point():
            total = sum(s[key].to(torch.float64) for s in states)
            averaged[key] = (total / len(states)).to(value.dtype)
        else:  # integer buffers (none today) are taken from the first checkpoint
            averaged[key] = value
    first.load_state_dict(averaged)
    return first


def main(argv: list[str] | None = None) -> Path:
    parser = argparse.ArgumentParser(prog="python -m relight.diffusion.average", description=__doc__.split("\n\n")[0])
    parser.add_argument("checkpoints", nargs="+", help="save_pretrained folders of one run")
    parser.add_argument("--out", required=True, type=Path, help="folder for the averaged checkpoint (created)")
    parser.add_argument("--half", action="store_true", help="store float16 weights (as the shipped checkpoint)")
    args = parser.parse_args(argv)
    if args.out.exists() and any(args.out.iterdir()):
        parser.error(f"--out {args.out} exists and is not empty")
    average_checkpoints(args.checkpoints).save_pretrained(args.out, half=args.half)
    print(f"averaged {len(args.checkpoints)} checkpoints into {args.out}")
    return args.out


if __name__ == "__main__":
    main()
