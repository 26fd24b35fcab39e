"""How well ``matcap.capture.flash.locate_flash`` finds the point under the flash.

Synthetic: every held-out material of ``relight eval capture``'s sets rendered as an 8-bit
flash photo (``matcap.capture_eval.flash_photo``, 1/d^2 falloff at the default camera
height) from the centre and from ``--offsets`` random camera positions off the centre
(x, y ~ U[-``--max-offset``, ``--max-offset``] plane units, seed ``--seed``); the located
point against the true one, in plane units (side 4). Real: the located point of every
photo given, drawn on it (``--figure``).

    python scripts/eval_flash_point.py --sets procedural,inria,textures \\
        --textures ../shared/data/real-dev/materials --count 8 --size 256 \\
        --photos ../shared/data/real-dev/photos/*/*.png --out results/capture_flash_point

Writes ``flash_point.json`` (every case) and ``real_photos.png`` under ``--out``.
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
from pathlib import Path

import torch


def synthetic(args) -> list[dict]:
    from matcap.capture.flash import locate_flash
    from matcap.capture_eval import CaptureEvalConfig, as_8bit, flash_photo, load_materials
    from materials.camera import camera_from_fov
    from materials.frame import prepare_photo

    cfg = CaptureEvalConfig(
        sets=tuple(args.sets.split(",")), count=args.count, size=args.size, textures=args.textures, runs=("alone",)
    )
    centre = camera_from_fov()
    g = torch.Generator().manual_seed(args.seed)
    rows = []
    for item in load_materials(cfg):
        offsets = [(0.0, 0.0)]
        for _ in range(args.offsets):
            u = (torch.rand(2, generator=g, dtype=torch.float64) * 2 - 1) * args.max_offset
            offsets.append((float(u[0]), float(u[1])))
        _, frame = prepare_photo(item.material.diffuse)  # the square photo's frame
        for dx, dy in offsets:
            camera = centre + torch.tensor([dx, dy, 0.0])
            point = locate_flash(as_8bit(flash_photo(item.material, camera)))
            x, y = point.plane_point(frame)
            rows.append(
                {
                    "set": item.set,
                    "material": item.name,
                    "offset": [round(dx, 3), round(dy, 3)],
                    "found": point.found,
                    "contrast": round(point.contrast, 3),
                    "error": round(math.hypot(x - dx, y - dy), 4),
                    # What assuming the centre costs: the distance of the true point from it.
                    "centre_error": round(math.hypot(dx, dy), 4),
                }
            )
    return rows


def summarise(rows: list[dict]) -> list[dict]:
    out = []
    for set_name in dict.fromkeys(r["set"] for r in rows):
        for kind, sel in (
            ("centred", [r for r in rows if r["set"] == set_name and r["offset"] == [0.0, 0.0]]),
            ("offset", [r for r in rows if r["set"] == set_name and r["offset"] != [0.0, 0.0]]),
        ):
            if not sel:
                continue
            errors = [r["error"] for r in sel]
            out.append(
                {
                    "set": set_name,
                    "photos": kind,
                    "count": len(sel),
                    "found": sum(r["found"] for r in sel),
                    "median_error": round(statistics.median(errors), 3),
                    "max_error": round(max(errors), 3),
                    "median_centre_error": round(statistics.median(r["centre_error"] for r in sel), 3),
                    "better_than_centre": sum(r["error"] < r["centre_error"] for r in sel),
                    "worse_than_centre": sum(r["error"] > r["centre_error"] + 1e-9 for r in sel),
                }
            )
    return out


def real(photos: list[str], out: Path) -> list[dict]:
    import numpy as np
    from PIL import Image, ImageDraw

    import kernels
    from matcap.capture.flash import locate_flash
    from materials.io.photo import read_photo

    side = 128
    rows, tiles = [], []
    for path in photos:
        image = read_photo(path).image
        point = locate_flash(image)
        h, w = image.shape[-2:]
        rows.append({"photo": "/".join(Path(path).parts[-2:]), "size": [h, w], **point.to_dict()})
        small = torch.nn.functional.interpolate(image[None], size=(side, side), mode="area")[0]
        pixels = (kernels.tonemap(small).clamp(0, 1) * 255).round().byte().permute(1, 2, 0).numpy()
        pil = Image.fromarray(pixels)
        draw = ImageDraw.Draw(pil)
        c = side / 2
        draw.line([c - 6, c, c + 6, c], fill="white")
        draw.line([c, c - 6, c, c + 6], fill="white")
        y, x = (point.row + 0.5) * side / h, (point.col + 0.5) * side / w
        draw.ellipse([x - 5, y - 5, x + 5, y + 5], outline="lime" if point.found else "red", width=2)
        tiles.append(np.asarray(pil))
    per_row = 5
    while len(tiles) % per_row:
        tiles.append(np.zeros_like(tiles[0]))
    grid = np.concatenate([np.concatenate(tiles[i : i + per_row], 1) for i in range(0, len(tiles), per_row)], 0)
    Image.fromarray(grid).save(out / "real_photos.png")
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sets", default="procedural,inria,textures")
    parser.add_argument("--textures", default=None)
    parser.add_argument("--count", type=int, default=8)
    parser.add_argument("--size", type=int, default=256)
    parser.add_argument("--offsets", type=int, default=3, help="random off-centre cameras per material")
    parser.add_argument("--max-offset", type=float, default=0.8, help="plane units (side 4)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--photos", nargs="*", default=[])
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    rows = synthetic(args)
    summary = summarise(rows)
    report = {"command": " ".join(sys.argv), "summary": summary, "rows": rows}
    if args.photos:
        report["real"] = real(args.photos, args.out)
    (args.out / "flash_point.json").write_text(json.dumps(report, indent=2) + "\n")
    for s in summary:
        print(s)
    for r in report.get("real", []):
        print(r)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
