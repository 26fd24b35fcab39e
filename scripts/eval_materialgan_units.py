"""Estimation from captures in the MaterialGAN geometry, with and without the conversion
to the models' units (issue 16, items 3 and the MaterialGAN-geometry targets).

    .venv/bin/python scripts/eval_materialgan_units.py --out results/materialgan_units --num-threads 1

Data: the held-out procedural materials ``EVAL_SEEDS[:16]`` at ``--size`` px (crop seed
``EVAL_CROP_SEED``), each captured as a MaterialGAN / Luo folder would hold it: a plane of
17 cm (preset ``materialgan``), 8 phone positions with the flash 1 cm beside the lens,
camera heights around 41.5 cm (9.76 model units, what a MaterialGAN capture maps to) and
tilted up to 35 degrees (``CaptureDomain`` collocated views), light power 1500 per channel,
1/d^2 falloff, 8-bit (clipped) photos. Those are written with ``materials.io`` and read
back, so the reader is in the loop.

Rows: the shipped estimator on view 0 alone and on all 8 views, fed

- ``raw``: the photos as read, positions scaled to the plane of side 4 (what
  ``relight estimate`` did before ``materials.units``);
- ``model units``: ``materials.units.to_model_units`` (each view's radiance converted to
  intensity pi without falloff), what ``relight estimate`` does now;
- ``dgrsise geometry`` (the reference the issue compares with): the same materials in the
  paper's evaluation setup, camera and flash at (0, 0, 4), views 1..7 under the
  ``EVAL_LIGHTS``, no falloff, 8-bit.
- ``centred at 9.76`` (diagnostic, one view): camera and flash at (0, 0, 9.76), no
  falloff, 8-bit: the MaterialGAN height alone, without its falloff, aiming offset or
  flash offset, so the gap between the first two one-view rows splits into height and
  the rest.

No refinement. Scores: re-render PSNR of the predicted vs the true maps under the 16
``HELDOUT_LIGHTS`` (``estimator.evaluate.rerender_metrics``) and the map MSEs. Writes
``materialgan_units.md`` and ``.json``.
"""

from __future__ import annotations

import argparse
import json
import math
import tempfile
import time
from pathlib import Path

import torch

import kernels
from estimator.evaluate import EVAL_CROP_SEED, MAP_NAMES, rerender_metrics
from matcap.capture_eval import as_8bit
from matcap.estimate import load_estimator
from materials.capture_domain import CaptureDomain, quantize_8bit, sample_geometry
from materials.dataset import EVAL_SEEDS, GroupConfig, RenderedGroups
from materials.io.materialgan import read_materialgan
from materials.types import Capture, Material
from materials.units import MODEL_PLANE_SIZE, to_model_units

#: The MaterialGAN geometry: plane side (cm), light power, and the height its captures
#: map to in model units (issue 16: 9.76).
PLANE_CM = 17.0
LIGHT_POWER = 1500.0
MODEL_HEIGHT = 9.76
VIEWS = 8


def capture_of(material: Material, index: int) -> Capture:
    """A MaterialGAN-geometry capture of ``material`` (module docstring), 8-bit."""
    domain = CaptureDomain(
        camera_height=(MODEL_HEIGHT * 0.9, MODEL_HEIGHT * 1.1),
        p_collocated=1.0,
        flash_offset=(1.0 / 41.5, 1.0 / 41.5),  # 1 cm beside the lens at ~41.5 cm
        p_crop=0.0,
        p_falloff=1.0,
    )
    geometry = sample_geometry(VIEWS, domain, torch.Generator().manual_seed(1000 + index))
    cm = PLANE_CM / MODEL_PLANE_SIZE
    light, camera = geometry.light * cm, geometry.camera * cm
    maps = [t[None] for t in material.map_tensors()]
    views = [kernels.render(*maps, light[v][None, None], camera[v], preset="materialgan")[0, 0] for v in range(VIEWS)]
    # 8-bit photos: clipped at 1, tone-mapped codes, decoded back as a reader does.
    images = as_8bit(torch.stack(views))
    return Capture(images=images, light_pos=light, camera_pos=camera, preset="materialgan")


def write_materialgan(folder: Path, capture: Capture) -> None:
    """The folder layout ``read_materialgan`` reads (SPEC section 6)."""
    from PIL import Image

    folder.mkdir(parents=True, exist_ok=True)
    for v, img in enumerate(capture.images):
        codes = quantize_8bit(img).permute(1, 2, 0).numpy()
        Image.fromarray(codes).save(folder / f"{v}.png")
    rows = lambda t: "\n".join(" ".join(f"{x:.6f}" for x in r) for r in t.tolist()) + "\n"  # noqa: E731
    (folder / "camera_pos.txt").write_text(rows(capture.camera_pos))
    (folder / "light_pos.txt").write_text(rows(capture.light_pos))
    (folder / "image_size.txt").write_text(f"{PLANE_CM}\n")
    (folder / "light_power.txt").write_text(f"{LIGHT_POWER} {LIGHT_POWER} {LIGHT_POWER}\n")


def paper_views(material: Material) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """(images ``[8, 3, H, W]`` 8-bit, light_pos, camera_pos): flash + ``EVAL_LIGHTS`` from (0, 0, 4)."""
    from materials.lights import eval_lights

    light, camera = eval_lights(include_input=True)
    images = kernels.render(*(t[None] for t in material.map_tensors()), light, camera)[0]
    return as_8bit(images), light, camera.expand(len(light), 3).clone()


def centred_view(material: Material, height: float) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """(image ``[1, 3, H, W]`` 8-bit, light_pos, camera_pos ``[1, 3]``): one flash photo
    from (0, 0, ``height``), no falloff."""
    pos = torch.tensor([[0.0, 0.0, height]])
    image = kernels.render(*(t[None] for t in material.map_tensors()), pos[None], pos[0])[0]
    return as_8bit(image), pos, pos.clone()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--count", type=int, default=16)
    parser.add_argument("--size", type=int, default=128)
    parser.add_argument("--estimator", type=Path, default=None)
    parser.add_argument("--num-threads", type=int, default=None)
    args = parser.parse_args()
    if args.num_threads:
        torch.set_num_threads(args.num_threads)
    model = load_estimator(args.estimator)
    groups = RenderedGroups(EVAL_SEEDS[: args.count], GroupConfig(size=args.size, seed=EVAL_CROP_SEED))
    scale = MODEL_PLANE_SIZE / PLANE_CM
    per: dict[str, list[dict]] = {}
    start = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(args.count):
            true = groups.material(i)
            folder = Path(tmp) / f"m{i}"
            write_materialgan(folder, capture_of(true, i))
            capture = read_materialgan(folder)
            converted = to_model_units(capture)
            feeds = {
                "raw": (capture.images, capture.light_pos * scale, capture.camera_pos * scale),
                "model units": (converted.images, converted.light_pos, converted.camera_pos),
                "dgrsise geometry": paper_views(true),
                f"centred at {MODEL_HEIGHT}": centred_view(true, MODEL_HEIGHT),
            }
            for feed, (images, light, camera) in feeds.items():
                for n in sorted({1, min(VIEWS, len(images))}):
                    with torch.no_grad():
                        pred = model(images[None, :n], light[None, :n], camera[None, :n])
                    row = {
                        "psnr": float(rerender_metrics(pred, Material(*(t[None] for t in true.map_tensors())))[0][0])
                    }
                    for name, p, t in zip(MAP_NAMES, pred.map_tensors(), true.map_tensors()):
                        row[name] = float(((p[0] - t) ** 2).mean())
                    per.setdefault(f"{feed}|{n}", []).append(row)
    summary = []
    for key, rows in per.items():
        feed, n = key.split("|")
        mean = {k: sum(r[k] for r in rows) / len(rows) for k in rows[0]}
        summary.append({"feed": feed, "inputs": int(n), "count": len(rows), **mean})
    lines = [
        "| feed | inputs | re-render PSNR (dB) | MSE D | MSE N | MSE R | MSE S |",
        "|---|---|---|---|---|---|---|",
    ]
    for s in summary:
        cells = [s["feed"], str(s["inputs"]), f"{s['psnr']:.2f}", *(f"{s[k]:.4f}" for k in MAP_NAMES)]
        lines.append("| " + " | ".join(cells) + " |")
    table = "\n".join(lines)
    seconds = time.perf_counter() - start
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "materialgan_units.json").write_text(
        json.dumps({"summary": summary, "per_material": per, "seconds": round(seconds, 1)}, indent=2) + "\n"
    )
    head = f"# Estimation in the MaterialGAN geometry ({args.count} materials, {args.size} px, {seconds:.0f} s)\n\n"
    (args.out / "materialgan_units.md").write_text(head + table + "\n")
    print(table)
    assert all(math.isfinite(s["psnr"]) for s in summary)


if __name__ == "__main__":
    main()
