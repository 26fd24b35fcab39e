"""Convert a relighting diffusion folder from the v1 layout to diffusers' standard one.

v1 (``RelightDiffusion`` before 2026-12-02, its own save/load)::

    relight_config.json   the fields of the removed ``RelightConfig`` dataclass
    relight.safetensors   the state dict (float16 in the shipped folder)

v2 (``ModelMixin.from_pretrained`` reads it; ``RelightPipeline.from_pretrained`` too)::

    config.json                          the constructor's arguments, every one explicit
    diffusion_pytorch_model.safetensors  the same file, renamed: the same bytes
    scheduler_config.json                the sampler (``make_sample_scheduler()``)

Run once on the shipped weights, 2026-12-02, from the repository root at the commit that
moved them to ``weights/`` (AMD EPYC, torch 2.13.0, diffusers 0.42.1)::

    python scripts/convert_weights_v2.py weights/diffusion --check-shipped

The Bieron relighter and the estimator were already in diffusers' layout with every
argument explicit in their config.json; they only moved (``git mv``), and
``--check-shipped`` checks all three. Use it the same way on a v1 training checkpoint's
``model/`` or ``ema/`` folder (in place, or with ``--out``).

Checks (each an ``AssertionError`` if it fails):
1. the weights are the v1 file's tensors, bit for bit: the renamed file is read back and
   compared key by key (names, dtypes, values), and ``RelightDiffusion.from_pretrained``
   (strict) loads it with no missing or unexpected key, every weight equal to the file's
   tensor cast to float32 (exact: float16 -> float32 is);
2. saving the loaded model again (``save_pretrained(half=True)``) writes the same tensors;
3. ``--check-shipped``: the three shipped networks' float32 outputs on the inputs recorded
   before the conversion with the v1 code (``tests/data/weights_v1_outputs.safetensors``,
   made by ``scripts/record_weights_v1_outputs.py`` at commit 5165520, removed since) are
   bit-identical: same machine, same weights, same operations (printed maximum
   differences: 0.000e+00 for all six outputs).
"""

from __future__ import annotations

import argparse
import json
import shutil
import tempfile
from pathlib import Path

import torch
from safetensors.torch import load_file

from relight.diffusion.model import WEIGHTS_NAME, RelightDiffusion
from relight.diffusion.pipeline import make_sample_scheduler

V1_CONFIG = "relight_config.json"
V1_WEIGHTS = "relight.safetensors"
#: v1 config keys that are not constructor arguments: ``extra`` was an unused dict.
V1_ONLY_KEYS = ("extra",)
RECORDED = Path("tests/data/weights_v1_outputs.safetensors")


def convert(folder: Path, out: Path) -> None:
    """Write the v2 layout of the v1 ``folder`` into ``out`` (may be ``folder``)."""
    missing = [name for name in (V1_CONFIG, V1_WEIGHTS) if not (folder / name).is_file()]
    if missing:
        raise FileNotFoundError(f"{folder}: not a v1 RelightDiffusion folder (no {', '.join(missing)})")
    old_config = json.loads((folder / V1_CONFIG).read_text())
    old_tensors = load_file(str(folder / V1_WEIGHTS))
    out.mkdir(parents=True, exist_ok=True)
    if out.resolve() == folder.resolve():
        (folder / V1_WEIGHTS).rename(out / WEIGHTS_NAME)
        (folder / V1_CONFIG).unlink()
    else:
        shutil.copyfile(folder / V1_WEIGHTS, out / WEIGHTS_NAME)
    args = {k: v for k, v in old_config.items() if k not in V1_ONLY_KEYS}
    RelightDiffusion(**args).save_config(out)  # the architecture, every argument explicit
    make_sample_scheduler().save_pretrained(out)
    check(out, old_tensors)
    print(f"{out}: converted, {len(old_tensors)} tensors bit-identical")


def check(folder: Path, old_tensors: dict[str, torch.Tensor]) -> None:
    new_tensors = load_file(str(folder / WEIGHTS_NAME))
    assert new_tensors.keys() == old_tensors.keys()
    for k, v in old_tensors.items():
        assert new_tensors[k].dtype == v.dtype and torch.equal(new_tensors[k], v), k
    model, info = RelightDiffusion.from_pretrained(folder, output_loading_info=True)
    assert not info["missing_keys"] and not info["unexpected_keys"] and not info["mismatched_keys"], info
    state = model.state_dict()
    assert state.keys() == old_tensors.keys()
    for k, v in old_tensors.items():
        assert state[k].dtype == torch.float32 and torch.equal(state[k], v.float()), k
    half = all(v.dtype == torch.float16 for v in old_tensors.values() if v.is_floating_point())
    with tempfile.TemporaryDirectory() as tmp:
        model.save_pretrained(tmp, half=half)
        again = load_file(str(Path(tmp) / WEIGHTS_NAME))
    assert again.keys() == old_tensors.keys()
    for k, v in old_tensors.items():
        assert again[k].dtype == v.dtype and torch.equal(again[k], v), k


def check_shipped() -> None:
    """Step 3 of the module docstring, through the public loaders."""
    from estimator.model import SVBRDFEstimator
    from relight.bieron.model import BieronRelighter
    from weights import weights_dir

    torch.set_num_threads(1)  # as when the outputs were recorded
    rec = load_file(str(RECORDED))
    with torch.no_grad():
        diffusion = RelightDiffusion.from_pretrained(weights_dir("diffusion"))
        cond = diffusion.encode_condition(
            rec["diffusion.photo"], rec["diffusion.photo"], rec["diffusion.light"], rec["diffusion.camera"]
        )
        got = {"diffusion.v": diffusion.denoise(rec["diffusion.x_t"], rec["diffusion.t"], *cond)}
        bieron = BieronRelighter.from_pretrained(weights_dir("bieron"))
        got["bieron.out"] = bieron(rec["bieron.photo"], rec["bieron.lights"], rec["bieron.camera"])
        estimator = SVBRDFEstimator.from_pretrained(weights_dir("estimator"))
        maps = estimator(rec["estimator.images"], rec["estimator.light"], rec["estimator.camera"])
        got |= {f"estimator.{k}": v for k, v in maps.maps().items()}
    for k, v in got.items():
        diff = (v - rec[f"{k}.float32"]).abs().max().item()
        print(f"{k}: max |v2 - v1| (float32, same machine) = {diff:.3e}")
        assert diff == 0.0, k


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("folder", type=Path, help="a v1 RelightDiffusion folder (relight_config.json + relight.safetensors)")
    p.add_argument("--out", type=Path, default=None, help="write the v2 folder here (default: in place)")
    p.add_argument("--check-shipped", action="store_true", help="also compare the shipped networks' outputs")
    args = p.parse_args(argv)
    convert(args.folder, args.out or args.folder)
    if args.check_shipped:
        check_shipped()


if __name__ == "__main__":
    main()
