"""Compare saved estimators on the same held-out capture-domain and paper-domain data.

    .venv/bin/python scripts/eval_domain.py --models weights/estimator RUN/export/model \\
        --names shipped fine-tuned --out results/estimator_domain --num-threads 1

Sets (all 64 x 64 unless ``--size``; none of them is in any training stream):

- ``capture``: the procedural materials ``EVAL_SEEDS[16:48]`` rendered by ``DomainGroups``
  with ``CaptureDomain()`` (random camera height and offset, flash falloff or none,
  exposure, white balance, noise, clipped highlights, 8-bit, JPEG), crop seed
  ``DOMAIN_SEED``; the estimator sees view 0 (the flash photo) or all 8 views.
- ``paper-8bit`` (a diagnostic): the same materials in the paper's geometry (random paper
  lights, no falloff) with clipping at 1 and the 8-bit round trip only.
- ``real:<name>``: the held-out real textures ``REAL_DEV_VALIDATION`` (from ``--textures``),
  ``--crops`` random crops each (``p_texture=1``), same domain and views; ``real`` pools
  the two.
- ``paper``: ``estimator.evaluate.evaluate`` on ``EVAL_SEEDS[16:48]``: the paper's clean
  setup (camera (0, 0, 4), flash + the 7 ``EVAL_LIGHTS``).

Metrics per set and view count, averaged over the materials: map MSE of diffuse (linear),
normal, roughness, specular; re-render PSNR of the predicted vs the true maps under the 16
``HELDOUT_LIGHTS`` (tone-mapped, MSE pooled over lights and pixels per material, as
``estimator.evaluate``). With two models, a table of differences (second minus first)
follows. Writes ``eval_domain.md`` and ``eval_domain.json`` to ``--out``.
"""

from __future__ import annotations

import argparse
import json
import time
from collections.abc import Sequence
from pathlib import Path

import torch

from estimator.evaluate import EVAL_CROP_SEED, MAP_NAMES, evaluate, rerender_metrics
from estimator.model import SVBRDFEstimator
from materials.capture_domain import CaptureDomain
from materials.dataset import EVAL_SEEDS, GroupConfig
from materials.domain_groups import REAL_DEV_VALIDATION, DomainGroups
from materials.io.atomic import atomic_file
from materials.types import Material

#: Held-out procedural materials: ``EVAL_SEEDS[:16]`` is what the shipped model's
#: TRAINING.md tables report, so this comparison uses the next 32.
PROCEDURAL = EVAL_SEEDS[16:48]
#: Crop / geometry / degradation seed of the capture-domain sets (``GroupConfig.seed``);
#: fixed so that every model sees the same images.
DOMAIN_SEED = 1234
#: Views per group (1: view 0 only; 8: all of them).
VIEW_COUNTS = (1, 8)
VIEWS = 8


def load(folder: str | Path) -> SVBRDFEstimator:
    """A ``save_pretrained`` folder, or a training checkpoint holding one in ``model/``."""
    folder = Path(folder)
    inner = folder / "model"
    return SVBRDFEstimator.from_pretrained(inner if (inner / "config.json").is_file() else folder).eval()


def domain_sets(size: int, textures: Path | None, crops: int) -> dict[str, DomainGroups]:
    """The capture-domain sets (module docstring), by name."""
    config = GroupConfig(size=size, views=VIEWS, source_size=2 * size, seed=DOMAIN_SEED)
    sets = {
        "capture": DomainGroups(PROCEDURAL, config, CaptureDomain()),
        # Diagnostic: the paper's geometry (random paper lights) with only the sensor's
        # clipping and 8-bit tone-map round trip, to tell a loss on "paper" caused by
        # unclipped inputs (never seen in the capture domain) from one caused by geometry.
        "paper-8bit": DomainGroups(PROCEDURAL, config, CaptureDomain.paper().switched(clip=True, quantize=True)),
    }
    if textures is not None:
        for name in REAL_DEV_VALIDATION:
            # The seeds only count the items: with p_texture 1 every item is a crop of the texture.
            sets[f"real:{name}"] = DomainGroups(
                EVAL_SEEDS[:crops], config, CaptureDomain(), textures=[textures / name], p_texture=1.0
            )
    return sets


def score(model: SVBRDFEstimator, data: DomainGroups, batch_size: int) -> dict[int, dict[str, torch.Tensor]]:
    """Per-material metrics ``{inputs: {metric: [count] float64}}`` of ``model`` on ``data``."""
    per = {n: {k: [] for k in (*MAP_NAMES, "psnr")} for n in VIEW_COUNTS}
    for start in range(0, len(data), batch_size):
        batch = torch.utils.data.default_collate([data[i] for i in range(start, min(start + batch_size, len(data)))])
        true = Material.from_stacked(batch["maps"])
        for n in VIEW_COUNTS:
            with torch.no_grad():
                pred = model(batch["images"][:, :n], batch["light_pos"][:, :n], batch["camera_pos"][:, :n])
                for name, p, t in zip(MAP_NAMES, pred.map_tensors(), true.map_tensors()):
                    per[n][name].append(((p - t) ** 2).mean((1, 2, 3)).double())
                per[n]["psnr"].append(rerender_metrics(pred, true)[0])
    return {n: {k: torch.cat(v) for k, v in per[n].items()} for n in VIEW_COUNTS}


def _rows(model: str, set_name: str, per: dict[int, dict[str, torch.Tensor]]) -> list[dict]:
    return [
        {
            "model": model,
            "set": set_name,
            "inputs": n,
            "count": len(m["psnr"]),
            **{k: float(v.mean()) for k, v in m.items()},
        }
        for n, m in per.items()
    ]


def compare(
    folders: Sequence[str],
    names: Sequence[str],
    *,
    size: int = 64,
    textures: Path | None = None,
    crops: int = 24,
    batch_size: int = 8,
) -> dict:
    """``{"rows": [{"model", "set", "inputs", "count", "diffuse", ..., "psnr"}], "meta"}``."""
    models = {name: load(f) for name, f in zip(names, folders)}
    rows = []
    real = {name: [] for name in models}  # per-texture metrics, pooled into the "real" rows
    for set_name, data in domain_sets(size, textures, crops).items():
        for name, model in models.items():
            tick = time.perf_counter()
            per = score(model, data, batch_size)
            rows += _rows(name, set_name, per)
            if set_name.startswith("real:"):
                real[name].append(per)
            print(f"{set_name} {name}: {time.perf_counter() - tick:.1f} s", flush=True)
    for name, parts in real.items():
        if parts:
            pooled = {n: {k: torch.cat([p[n][k] for p in parts]) for k in parts[0][n]} for n in VIEW_COUNTS}
            rows += _rows(name, "real", pooled)
    for name, model in models.items():
        report = evaluate(model, PROCEDURAL, size, batch_size=batch_size, progress=False)
        for r in report["rows"]:
            rows.append(
                {
                    "model": name,
                    "set": "paper",
                    "inputs": r["inputs"],
                    "count": r["count"],
                    **{m: r[f"mse_{m}"] for m in MAP_NAMES},
                    "psnr": r["psnr"],
                }
            )
    meta = {
        "models": dict(zip(names, map(str, folders))),
        "procedural_seeds": [PROCEDURAL[0], PROCEDURAL[-1]],
        "domain_seed": DOMAIN_SEED,
        "paper_crop_seed": EVAL_CROP_SEED,
        "textures": [str(textures / n) for n in REAL_DEV_VALIDATION] if textures is not None else [],
        "crops_per_texture": crops,
        "size": size,
    }
    return {"rows": rows, "meta": meta}


def markdown(report: dict) -> str:
    """The rows as one table, the models of a (set, inputs) pair next to each other."""
    lines = [
        "| set | inputs | model | n | MSE D | MSE N | MSE R | MSE S | re-render PSNR (dB) |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in report["rows"]:
        lines.append(
            f"| {r['set']} | {r['inputs']} | {r['model']} | {r['count']} | {r['diffuse']:.4f} | {r['normal']:.4f} "
            f"| {r['roughness']:.4f} | {r['specular']:.4f} | {r['psnr']:.2f} |"
        )
    names = list(report["meta"]["models"])
    if len(names) == 2:
        a, b = names
        lines += [
            "",
            f"{b} minus {a} (PSNR: higher is better; MSE: lower is better):",
            "",
            "| set | inputs | d PSNR (dB) | d MSE D | d MSE N | d MSE R | d MSE S |",
            "|---|---|---|---|---|---|---|",
        ]
        by = {(r["model"], r["set"], r["inputs"]): r for r in report["rows"]}
        for r in report["rows"]:
            if r["model"] != a or (b, r["set"], r["inputs"]) not in by:
                continue
            o = by[(b, r["set"], r["inputs"])]
            lines.append(
                f"| {r['set']} | {r['inputs']} | {o['psnr'] - r['psnr']:+.2f} | "
                + " | ".join(f"{o[m] - r[m]:+.4f}" for m in MAP_NAMES)
                + " |"
            )
    return "\n".join(lines) + "\n"


def main(argv: Sequence[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--models", nargs="+", required=True, help="estimator folders (save_pretrained or checkpoint)")
    parser.add_argument("--names", nargs="+", default=None, help="one label per model (default: the folder names)")
    parser.add_argument(
        "--textures",
        default="../shared/data/real-dev/materials",
        help="folder holding the REAL_DEV_VALIDATION material folders ('' to skip the real-texture sets)",
    )
    parser.add_argument("--crops", type=int, default=24, help="random crops per validation texture")
    parser.add_argument("--size", type=int, default=64)
    parser.add_argument("--batch-size", type=int, default=8)
    parser.add_argument("--out", default="runs/eval_domain")
    parser.add_argument("--num-threads", type=int, default=None)
    args = parser.parse_args(argv)
    names = args.names or [Path(m).name for m in args.models]
    if len(names) != len(args.models):
        parser.error("--names needs one label per --models folder")
    if args.num_threads is not None:
        torch.set_num_threads(args.num_threads)
    textures = Path(args.textures) if args.textures else None
    report = compare(
        args.models, names, size=args.size, textures=textures, crops=args.crops, batch_size=args.batch_size
    )
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    table = markdown(report)
    with atomic_file(out / "eval_domain.md") as tmp:
        tmp.write_text(table)
    with atomic_file(out / "eval_domain.json") as tmp:
        tmp.write_text(json.dumps(report, indent=2))
    print(table)
    return report


if __name__ == "__main__":
    main()
