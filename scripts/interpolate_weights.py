"""Weight interpolation of two fine-tunes of one model (a "model soup" of two).

``theta = (1 - alpha) * theta_a + alpha * theta_b`` for every tensor; both folders must
hold the same architecture (``config.json`` equal) in ``diffusion_pytorch_model.safetensors``
(the diffusers layout every model here saves). Used to trade a capture-domain
fine-tune's gains against its loss on the paper's domain (results/estimator_domain).

    python scripts/interpolate_weights.py A B --alpha 0.5 --out DIR
"""

from __future__ import annotations

import argparse
import json
import shutil
from pathlib import Path

from safetensors.torch import load_file, save_file

WEIGHTS = "diffusion_pytorch_model.safetensors"
CONFIG = "config.json"


def interpolate(a: Path, b: Path, alpha: float, out: Path) -> None:
    """Write ``(1 - alpha) * a + alpha * b`` to ``out`` (config copied from ``a``)."""
    if not 0.0 <= alpha <= 1.0:
        raise ValueError(f"alpha must lie in [0, 1], got {alpha}")
    if json.loads((a / CONFIG).read_text()) != json.loads((b / CONFIG).read_text()):
        raise ValueError(f"{a} and {b} hold different architectures (config.json differs)")
    ta, tb = load_file(a / WEIGHTS), load_file(b / WEIGHTS)
    if ta.keys() != tb.keys():
        raise ValueError(f"{a} and {b} hold different tensors")
    mixed = {}
    for name, x in ta.items():
        y = tb[name]
        # Integer buffers (counters) are not interpolated: they are taken from a.
        mixed[name] = x.lerp(y, alpha).contiguous() if x.is_floating_point() else x.clone()
    out.mkdir(parents=True, exist_ok=True)
    save_file(mixed, out / WEIGHTS)
    shutil.copy(a / CONFIG, out / CONFIG)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("a", type=Path, help="first model folder (alpha = 0)")
    p.add_argument("b", type=Path, help="second model folder (alpha = 1)")
    p.add_argument("--alpha", type=float, required=True, help="share of b, in [0, 1]")
    p.add_argument("--out", type=Path, required=True, help="output folder")
    args = p.parse_args()
    interpolate(args.a, args.b, args.alpha, args.out)


if __name__ == "__main__":
    main()
