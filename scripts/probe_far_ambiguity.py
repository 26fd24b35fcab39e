"""How much one far flash photo pins the diffuse / specular split (issue 16, one-view
MaterialGAN target): a linear probe with no network in it.

    .venv/bin/python scripts/probe_far_ambiguity.py --out results/estimator_far --num-threads 1

Data: the held-out procedural materials ``EVAL_SEEDS[:16]`` at ``--size`` px (crop seed
``EVAL_CROP_SEED``), the materials of ``scripts/eval_materialgan_units.py``. Each is
photographed once with camera and flash at (0, 0, h), no falloff, for h = 4 (the dgrsise
geometry's input) and h = 9.76 (a MaterialGAN capture in model units).

A "traded" material scales the whole diffuse map by ``g`` (one wrong global gain, as an
estimator that misjudges the split would) and the specular (F0) map by the per-channel
``k`` that best explains the photo in linear least squares; normal and roughness stay
true. The photo is close to linear in the two maps but not exactly (the diffuse term
carries ``1 - F0``, Fresnel carries F0), so ``k`` is found per channel by a two-level
grid search over ``[0, 1 / max F0]`` (F0 stays at most 1), each level ``GRID`` renders.

Scores per h and g, means over the materials:

- ``photo fit``: PSNR of the traded material's photo against the true photo, both
  tone-mapped (``kernels.tonemap``): how well the one input view hides the trade. An
  8-bit photo's quantisation alone is about 59 dB.
- ``novel lights``: the traded material's re-render PSNR under the ``HELDOUT_LIGHTS``
  (``estimator.evaluate.rerender_metrics``, the estimator evaluation's score): what the
  trade costs where it matters.

A far view that fits the traded material far better than a near one cannot tell the
split apart, so no estimator can be as accurate from it as from the near view without
leaning on priors. With ``--compare`` (a ``materialgan_units.json`` of
``scripts/eval_materialgan_units.py`` on the same materials) it also ranks, per material,
how much better the far photo hides a 30 % diffuse error against how much the
estimator's one-view score drops from the dgrsise input to ``centred at 9.76``
(Spearman's rho), and splits the drop by the hiding gain. Writes ``far_ambiguity.md``
and ``.json``.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import torch

import kernels
from estimator.evaluate import EVAL_CROP_SEED, rerender_metrics
from materials.dataset import EVAL_SEEDS, GroupConfig, RenderedGroups
from materials.metrics import psnr_from_mse
from materials.types import Material

#: Camera heights in model units: the dgrsise input view and a MaterialGAN capture.
HEIGHTS = (4.0, 9.76)
#: Wrong diffuse gains tried (1 is the truth, a sanity row: k must come out 1 and the
#: fit near exact).
GAINS = (1.0, 0.85, 0.7, 0.5)
#: The gain and the hiding-gain threshold (dB) of the ``--compare`` split.
COMPARE_GAIN = 0.7
HIDING_SPLIT_DB = 3.0


#: Points per level of the grid search for ``k`` (two levels: the second spans the two
#: cells around the first's best, so ``k`` is resolved to about (1 / max F0) / GRID^2 / 2).
GRID = 65


def flash_photos(
    diffuse: torch.Tensor, normal: torch.Tensor, roughness: torch.Tensor, specular: torch.Tensor, height: float
) -> torch.Tensor:
    """``[B, 3, H, W]`` linear radiance of maps ``[B, C, H, W]`` photographed with camera
    and flash at (0, 0, ``height``), no falloff."""
    pos = torch.tensor([[0.0, 0.0, height]])
    return kernels.render(diffuse, normal, roughness, specular, pos[None], pos[0])[:, 0]


def specular_gain(material: Material, height: float, gain: float) -> torch.Tensor:
    """``[3]`` the least-squares ``k`` of the traded material (module docstring)."""
    diffuse, normal, roughness, specular = material.map_tensors()
    photo = flash_photos(diffuse[None], normal[None], roughness[None], specular[None], height)[0]
    top = 1.0 / specular.flatten(1).amax(1).clamp_min(1e-6)  # [3]: keeps F0 <= 1
    lo, hi = torch.zeros(3), top
    for _ in range(2):
        grid = lo + (hi - lo) * torch.linspace(0.0, 1.0, GRID)[:, None]  # [GRID, 3]
        photos = flash_photos(
            (diffuse * gain).expand(GRID, -1, -1, -1),
            normal.expand(GRID, -1, -1, -1),
            roughness.expand(GRID, -1, -1, -1),
            specular * grid[:, :, None, None],
            height,
        )
        best = ((photos - photo) ** 2).sum((2, 3)).argmin(0)  # [3]
        step = (hi - lo) / (GRID - 1)
        k = grid[best, torch.arange(3)]
        lo, hi = (k - step).clamp_min(0.0), torch.minimum(k + step, top)
    return k


def trade(material: Material, height: float, gain: float) -> tuple[float, float, list[float]]:
    """(photo-fit PSNR, novel-light PSNR, k per channel) of the traded material (module
    docstring) seen from ``height``."""
    k = specular_gain(material, height, gain)
    diffuse, normal, roughness, specular = material.map_tensors()
    traded = Material(diffuse * gain, normal, roughness, specular * k[:, None, None])
    batch = lambda m: Material(*(t[None] for t in m.map_tensors()))  # noqa: E731
    photo, fitted = (flash_photos(*batch(m).map_tensors(), height)[0] for m in (material, traded))
    fit = float(psnr_from_mse(((kernels.tonemap(fitted) - kernels.tonemap(photo)) ** 2).mean()))
    novel = float(rerender_metrics(batch(traded), batch(material))[0][0])
    return fit, novel, k.tolist()


def spearman(x: list[float], y: list[float]) -> float:
    """Spearman's rank correlation (no ties expected: continuous scores)."""

    def ranks(v: list[float]) -> list[int]:
        order = sorted(range(len(v)), key=v.__getitem__)
        out = [0] * len(v)
        for rank, i in enumerate(order):
            out[i] = rank
        return out

    n = len(x)
    return 1.0 - 6.0 * sum((a - b) ** 2 for a, b in zip(ranks(x), ranks(y))) / (n * (n * n - 1))


def compare(rows: list[dict], units_json: Path, count: int) -> tuple[dict, list[str]]:
    """Per-material hiding gain (far minus near photo fit at ``COMPARE_GAIN``) against the
    estimator's one-view drop (dgrsise input minus ``centred at 9.76``) in ``units_json``."""
    per = json.loads(units_json.read_text())["per_material"]
    near, far = per["dgrsise geometry|1"], per[f"centred at {HEIGHTS[1]}|1"]
    fit = {(r["material"], r["height"]): r["fit"] for r in rows if r["gain"] == COMPARE_GAIN}
    hiding = [fit[(m, HEIGHTS[1])] - fit[(m, HEIGHTS[0])] for m in range(count)]
    drop = [near[m]["psnr"] - far[m]["psnr"] for m in range(count)]
    hidden = [m for m in range(count) if hiding[m] > HIDING_SPLIT_DB]
    rest = [m for m in range(count) if m not in hidden]
    mean = lambda idx: sum(drop[m] for m in idx) / max(len(idx), 1)  # noqa: E731
    result = {
        "spearman": spearman(hiding, drop),
        "hidden": hidden,
        "drop_hidden": mean(hidden),
        "drop_rest": mean(rest),
        "hiding": hiding,
        "drop": drop,
    }
    lines = [
        "| material | hiding gain at g = 0.7 (dB) | estimator one-view drop (dB) |",
        "|---|---|---|",
        *(f"| {m} | {hiding[m]:.1f} | {drop[m]:.2f} |" for m in range(count)),
        "",
        f"Spearman's rho {result['spearman']:.2f}. Materials whose far photo hides the trade by more than "
        f"{HIDING_SPLIT_DB:.0f} dB ({hidden}): mean drop {result['drop_hidden']:.2f} dB; the other "
        f"{len(rest)}: {result['drop_rest']:.2f} dB.",
    ]
    return result, lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--count", type=int, default=16)
    parser.add_argument("--size", type=int, default=128)
    parser.add_argument("--num-threads", type=int, default=None)
    parser.add_argument("--compare", type=Path, default=None, help="materialgan_units.json (module docstring)")
    args = parser.parse_args()
    if args.num_threads:
        torch.set_num_threads(args.num_threads)
    if args.compare is not None and not args.compare.is_file():
        parser.error(f"--compare: no such file: {args.compare}")
    start = time.perf_counter()
    groups = RenderedGroups(EVAL_SEEDS[: args.count], GroupConfig(size=args.size, seed=EVAL_CROP_SEED))
    rows = []
    for i in range(args.count):
        material = groups.material(i)
        for height in HEIGHTS:
            for gain in GAINS:
                fit, novel, k = trade(material, height, gain)
                rows.append({"material": i, "height": height, "gain": gain, "fit": fit, "novel": novel, "k": k})
    summary = []
    for height in HEIGHTS:
        for gain in GAINS:
            sel = [r for r in rows if r["height"] == height and r["gain"] == gain]
            fits = [min(r["fit"], 99.0) for r in sel]  # the exact fit at g = 1 is infinite
            summary.append(
                {
                    "height": height,
                    "gain": gain,
                    "fit": sum(fits) / len(fits),
                    "fit_min": min(fits),
                    "novel": sum(min(r["novel"], 99.0) for r in sel) / len(sel),
                }
            )
    lines = [
        "| height | diffuse gain g | photo fit (dB), mean | photo fit, worst material | novel lights (dB) |",
        "|---|---|---|---|---|",
    ]
    for s in summary:
        lines.append(f"| {s['height']} | {s['gain']} | {s['fit']:.2f} | {s['fit_min']:.2f} | {s['novel']:.2f} |")
    payload: dict = {"summary": summary, "per_material": rows}
    if args.compare is not None:
        payload["compare"], more = compare(rows, args.compare, args.count)
        lines += ["", f"Against `{args.compare.name}`:", "", *more]
    table = "\n".join(lines)
    seconds = time.perf_counter() - start
    args.out.mkdir(parents=True, exist_ok=True)
    payload["seconds"] = round(seconds, 1)
    (args.out / "far_ambiguity.json").write_text(json.dumps(payload, indent=2) + "\n")
    head = (
        f"# One flash photo, diffuse traded for specular ({args.count} materials, {args.size} px, "
        f"{seconds:.0f} s; values capped at 99 dB)\n\n"
    )
    (args.out / "far_ambiguity.md").write_text(head + table + "\n")
    print(table)


if __name__ == "__main__":
    main()
