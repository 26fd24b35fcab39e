"""Compare ``relight eval capture`` reports (``capture_eval.json``) on the materials they share.

    python scripts/compare_capture_evals.py shipped=A/capture_eval.json fine-tuned=B/capture_eval.json

A name given twice pools the two reports' rows (e.g. two runs of one model on other sets).

Prints a Markdown table: per set and run, the means of each report holding that set, over
the materials all of those reports hold (runs made with different ``--count`` share only
part of their materials; the INRIA set of ``--count N`` is ``EVAL_SEEDS[N:2N]``).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

KEYS = ("psnr", "ssim", "mse_diffuse", "mse_diffuse_highlight", "mse_normal", "mse_roughness", "mse_specular")


def compare(reports: dict[str, list[dict]]) -> str:
    """Markdown table of the reports' rows (name -> rows), per set on the materials shared
    by the reports holding it."""
    lines = ["| set | run | report | n | " + " | ".join(KEYS) + " |", "|" + "---|" * (4 + len(KEYS))]
    sets = dict.fromkeys(r["set"] for rows in reports.values() for r in rows)
    runs = dict.fromkeys(r["run"] for rows in reports.values() for r in rows)
    for set_name in sets:
        holding = {n: [r for r in rows if r["set"] == set_name] for n, rows in reports.items()}
        holding = {n: rows for n, rows in holding.items() if rows}
        common = set.intersection(*({r["material"] for r in rows} for rows in holding.values()))
        for run in runs:
            for name, rows in holding.items():
                sel = [r for r in rows if r["run"] == run and r["material"] in common]
                if not sel:
                    continue
                cells = []
                for key in KEYS:
                    values = [r[key] for r in sel if key in r and r[key] == r[key]]  # NaN != NaN
                    cells.append(f"{sum(values) / len(values):.4g}" if values else "")
                lines.append(f"| {set_name} | {run} | {name} | {len(sel)} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    if not args or any("=" not in a for a in args):
        print(__doc__, file=sys.stderr)
        return 2
    reports = {}
    for arg in args:
        name, path = arg.split("=", 1)
        reports.setdefault(name, []).extend(json.loads(Path(path).read_text())["rows"])  # a name may repeat
    print(compare(reports))
    return 0


if __name__ == "__main__":
    sys.exit(main())
