"""``relight``: the command line. Each subcommand lives in its own module."""

from __future__ import annotations

import argparse
import sys

from matcap import cmd_capture, cmd_convert, cmd_estimate, cmd_eval, cmd_generate, cmd_render, cmd_synth, cmd_train
from matcap.args import join_negative_values
from matcap.errors import UsageError
from matcap.web import cmd_serve

__all__ = ["main", "build_parser"]

_SUBCOMMANDS = [cmd_capture, cmd_render, cmd_synth, cmd_convert, cmd_generate, cmd_estimate, cmd_eval, cmd_train]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="relight",
        description="Material capture from one flash photo: relighting, SVBRDF maps, re-renders.",
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for module in _SUBCOMMANDS:
        module.add_parser(sub)
    cmd_serve.add_parser(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(join_negative_values(sys.argv[1:] if argv is None else argv))
    from materials.io.errors import FormatError
    from materials.types import MapError

    try:
        return int(args.run(args) or 0)
    except (UsageError, FormatError, MapError, FileExistsError, FileNotFoundError, ValueError, TypeError) as exc:
        # A bad input is the user's to fix: one clear line, no traceback.
        print(f"relight {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
