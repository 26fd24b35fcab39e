"""``python -m estimator {train,evaluate} ...``: the estimator's command line.

``train`` takes the flags of ``python -m estimator.train`` (one per ``TrainConfig``
field); ``evaluate`` those of ``estimator.evaluate.cli``.
"""

from __future__ import annotations

import sys


def main(argv: list[str] | None = None) -> None:
    argv = sys.argv[1:] if argv is None else argv
    if not argv or argv[0] not in ("train", "evaluate"):
        raise SystemExit("usage: python -m estimator {train,evaluate} [--help | flags]")
    if argv[0] == "train":
        from estimator.train import main as train
        from estimator.train import parse_args

        train(parse_args(argv[1:]))
    else:
        from estimator.evaluate import cli

        cli(argv[1:])


if __name__ == "__main__":
    main()
