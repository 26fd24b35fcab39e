"""Means over photos of `scripts/capture_real_photos.py` records, one table row per run.

    python results/capture_vignetting/summarise.py base=real_photos_base.json va=real_photos_va.json

Edge drop is averaged as an absolute value (a map darker or brighter at the rim is equally
far from flat); `abs(hr-1)` is the mean distance of the diffuse highlight ratio from 1.
"""

import json
import statistics
import sys
from pathlib import Path

KEYS = (
    "profile_diffuse",
    "profile_roughness",
    "profile_specular",
    "edge_drop_diffuse",
    "tilt_deg",
    "crease_deg",
)


def summarise(tag: str, records: list[dict]) -> list[str]:
    """One markdown row per run ("relit", "alone") of one measured set."""
    rows = []
    for run in ("relit", "alone"):
        cells = []
        for key in KEYS:
            xs = [r[f"{key}_{run}"] for r in records if f"{key}_{run}" in r]
            if key.startswith("edge"):
                xs = [abs(x) for x in xs]
            cells.append(f"{statistics.mean(xs):.3f}" if xs else "-")
        ratios = [abs(r[f"highlight_ratio_{run}"] - 1) for r in records if f"highlight_ratio_{run}" in r]
        cells.append(f"{statistics.mean(ratios):.3f}" if ratios else "-")
        rows.append(f"| {tag} | {run} | {len(records)} | " + " | ".join(cells) + " |")
    return rows


def main(args: list[str]) -> None:
    print("| tag | run | n | " + " | ".join(KEYS) + " | abs(hr-1) |")
    print("|" + "---|" * (len(KEYS) + 4))
    for arg in args:
        tag, path = arg.split("=", 1)
        for row in summarise(tag, json.loads(Path(path).read_text())):
            print(row)


if __name__ == "__main__":
    main(sys.argv[1:])
