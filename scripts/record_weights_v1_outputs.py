"""One-off: record the shipped networks' outputs with the code and weight layout of
commit 1c092f3 (before the weights moved to ``weights/``), for the conversion check.

Run once, 2026-12-02, from the repository root: ``python scripts/record_weights_v1_outputs.py``.
It writes ``tests/data/weights_v1_outputs.safetensors``: fixed inputs, and each network's
output on them in float32 (the weights as shipped, cast to float32 on load) and in
float64 (the same weights cast to float64, every operation in double precision).
``tests/test_weights_conversion.py`` reloads the converted weights and compares.
This file is deleted by the conversion commit (it imports the classes that commit removes).
"""

from __future__ import annotations

from pathlib import Path

import torch
from safetensors.torch import save_file

from estimator.model import SVBRDFEstimator
from relight.bieron.model import BieronRelighter
from relight.diffusion.model import RelightDiffusion

OUT = Path("tests/data/weights_v1_outputs.safetensors")


def inputs() -> dict[str, torch.Tensor]:
    g = torch.Generator().manual_seed(20261203)
    return {
        # diffusion: one target at 64x64 (the model's resolution), at t = 999 from pure
        # noise (the shipped one-step setting); kept small, the file is committed
        "diffusion.photo": torch.rand(1, 3, 64, 64, generator=g) * 0.6,
        "diffusion.light": torch.tensor([[1.5, -1.0, 4.5]]),
        "diffusion.camera": torch.tensor([[0.0, 0.0, 4.0]]),
        "diffusion.x_t": torch.randn(1, 3, 64, 64, generator=g),
        "diffusion.t": torch.tensor([999]),
        # bieron: one photo, two targets, 32x32 (a multiple of 8)
        "bieron.photo": torch.rand(1, 3, 32, 32, generator=g) * 0.6,
        "bieron.camera": torch.tensor([[0.0, 0.0, 4.0]]),
        "bieron.lights": torch.tensor([[[2.0, 1.0, 4.0], [-1.0, -2.0, 6.0]]]),
        # estimator: one material, three views, 32x32 (a multiple of 16)
        "estimator.images": torch.rand(1, 3, 3, 32, 32, generator=g) * 0.6,
        "estimator.light": torch.tensor([[[0.0, 0.0, 4.0], [2.0, 1.0, 5.0], [-1.5, 2.0, 4.5]]]),
        "estimator.camera": torch.tensor([[0.0, 0.0, 4.0]]).expand(1, 3, 3).contiguous(),
    }


@torch.no_grad()
def outputs(x: dict[str, torch.Tensor], dtype: torch.dtype) -> dict[str, torch.Tensor]:
    f = {k: (v.to(dtype) if v.is_floating_point() else v) for k, v in x.items()}
    out = {}
    diffusion = RelightDiffusion.from_pretrained("relight/weights/diffusion").to(dtype).eval()
    cond = diffusion.encode_condition(
        f["diffusion.photo"], f["diffusion.photo"], f["diffusion.light"], f["diffusion.camera"]
    )
    out["diffusion.v"] = diffusion.denoise(f["diffusion.x_t"], f["diffusion.t"], *cond)
    bieron = BieronRelighter.from_pretrained("relight/weights/bieron").to(dtype).eval()
    out["bieron.out"] = bieron(f["bieron.photo"], f["bieron.camera"], f["bieron.lights"])
    estimator = SVBRDFEstimator.from_pretrained("estimator/weights").to(dtype).eval()
    maps = estimator(f["estimator.images"], f["estimator.light"], f["estimator.camera"])
    for name, value in maps.maps().items():
        out[f"estimator.{name}"] = value
    return out


def main() -> None:
    torch.set_num_threads(1)
    x = inputs()
    f32 = outputs(x, torch.float32)
    f64 = outputs(x, torch.float64)
    record = dict(x)
    for k in f32:
        record[f"{k}.float32"] = f32[k].contiguous()
        record[f"{k}.float64"] = f64[k].contiguous()
        err = (f32[k].double() - f64[k]).abs().max().item()
        print(f"{k}: max |f32 - f64| {err:.3e}, max |f64| {f64[k].abs().max().item():.3e}")
    OUT.parent.mkdir(parents=True, exist_ok=True)
    save_file(record, str(OUT), metadata={"commit": "1c092f3", "recorded": "2026-12-02"})
    print("wrote", OUT)


if __name__ == "__main__":
    main()
