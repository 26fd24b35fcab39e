"""Write ``tests/data/shipped_reference.safetensors``: fixed inputs and the shipped
checkpoints' outputs on them, the reference of ``tests/relight/test_shipped.py``.

Usage (from the repository root)::

    .venv/bin/python tests/data/make_shipped_reference.py [--out tests/data/shipped_reference.safetensors]

Rerun it only when a shipped checkpoint is retrained on purpose (and say so in the
commit); a conversion of the weight files to another layout must leave the outputs
unchanged, which is what the test checks.

Inputs: procedural material ``SEED`` (``materials.procedural.generate``) rendered by
``kernels.render`` under the evaluation lights (``materials.lights.eval_lights``),
float32, stored in the file so that the reference does not move when the renderer or the
generator changes:

- ``photo64`` ``[1, 3, 64, 64]`` linear flash photo (view 0: light at the camera), for
  the diffusion relighter (its resolution is 64); ``photo32`` ``[1, 3, 32, 32]`` the
  same material at 32 x 32 for the Bieron relighter;
- ``camera`` ``[1, 3]``, ``lights`` ``[1, 2, 3]`` (evaluation targets 1 and 2);
- ``images32`` ``[1, 3, 3, 32, 32]``, ``est_light`` / ``est_camera`` ``[1, 3, 3]``:
  views 0-2, the estimator's input.

Outputs (float32, each from the public loader with its shipped weights):

- ``diffusion`` ``[1, 1, 3, 64, 64]``: ``get_relighter("diffusion")``, 1 DDIM step,
  ``torch.Generator().manual_seed(GENERATOR_SEED)``, target light 1 only;
- ``bieron`` ``[1, 2, 3, 32, 32]``: ``get_relighter("bieron")``;
- ``estimator`` ``[1, 10, 32, 32]``: ``matcap.estimate.load_estimator()``, stacked maps.

The script also runs each network in float64 on the same inputs and prints
max |float32 - float64| per output: the measurement behind the test's tolerances.
"""

from __future__ import annotations

import argparse
import copy
from pathlib import Path

import torch
from safetensors.torch import save_file

import kernels
from materials.lights import eval_lights
from materials.procedural import generate

OUT = Path(__file__).resolve().parent / "shipped_reference.safetensors"
#: Procedural material of the inputs (a glossy one, so the relighters see a highlight).
SEED = 7
#: Seed of the diffusion sampler's generator.
GENERATOR_SEED = 0
#: Sampling steps of the diffusion run (one keeps the test fast).
DIFFUSION_STEPS = 1


def make_inputs() -> dict[str, torch.Tensor]:
    """The fixed float32 inputs (module docstring)."""
    light, camera = eval_lights()
    inputs = {}
    for size in (64, 32):
        maps = [t[None] for t in generate(SEED, size=size).map_tensors()]
        images = kernels.render(*maps, light[:3][None], camera[:3][None])  # [1, 3, 3, S, S]
        inputs[f"photo{size}"] = images[:, 0].contiguous()
        if size == 32:
            inputs["images32"] = images.clone()
    inputs["camera"] = camera[:1].clone()
    inputs["lights"] = light[1:3][None].clone()
    inputs["est_light"] = light[:3][None].clone()
    inputs["est_camera"] = camera[:3][None].clone()
    return inputs


def run_diffusion(relighter, inputs: dict[str, torch.Tensor]) -> torch.Tensor:
    """``[1, 1, 3, 64, 64]`` through the relighter interface (float32)."""
    relighter.steps = DIFFUSION_STEPS
    generator = torch.Generator().manual_seed(GENERATOR_SEED)
    return relighter.relight(inputs["photo64"], inputs["lights"][:, :1], inputs["camera"], generator=generator)


def run_bieron(relighter, inputs: dict[str, torch.Tensor]) -> torch.Tensor:
    """``[1, 2, 3, 32, 32]`` through the relighter interface, in the model's dtype."""
    dtype = next(relighter.model.parameters()).dtype
    return relighter.relight(inputs["photo32"].to(dtype), inputs["lights"].to(dtype), inputs["camera"].to(dtype))


def run_estimator(model, inputs: dict[str, torch.Tensor]) -> torch.Tensor:
    """``[1, 10, 32, 32]`` stacked maps, in the model's dtype."""
    dtype = next(model.parameters()).dtype
    with torch.no_grad():
        args = (inputs["images32"], inputs["est_light"], inputs["est_camera"])
        return model(*(t.to(dtype) for t in args)).stacked()


def diffusion_float64(relighter, inputs: dict[str, torch.Tensor]) -> torch.Tensor:
    """The diffusion relighter's computation (``RelightPipeline.__call__``, one target,
    one sample) with the network in float64: the same float32 noise, cast."""
    model = copy.deepcopy(relighter.pipeline.model).double().eval()
    scheduler = copy.deepcopy(relighter.pipeline.scheduler)
    photo = inputs["photo64"].double()
    light = inputs["lights"][0, :1].double()
    camera = inputs["camera"].double()
    with torch.no_grad():
        cond = model.encode_condition(photo, photo, light, camera)
        generator = torch.Generator().manual_seed(GENERATOR_SEED)
        x = torch.randn((1, *model.sample_shape), generator=generator).double()
        scheduler.set_timesteps(DIFFUSION_STEPS)
        for t in scheduler.timesteps:
            v = model.denoise(x, t.expand(1), *cond)
            x = scheduler.step(v, t, x).prev_sample
        return model.to_linear(x, cond.base_x)[None]


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=OUT)
    args = parser.parse_args(argv)
    torch.set_num_threads(1)

    from matcap.estimate import load_estimator
    from relight.interface import get_relighter

    inputs = make_inputs()
    diffusion = get_relighter("diffusion")
    bieron = get_relighter("bieron")
    estimator = load_estimator()
    outputs = {
        "diffusion": run_diffusion(diffusion, inputs),
        "bieron": run_bieron(bieron, inputs),
        "estimator": run_estimator(estimator, inputs),
    }
    exact = {
        "diffusion": diffusion_float64(diffusion, inputs),
        "bieron": run_bieron(type(bieron)(copy.deepcopy(bieron.model).double()), inputs),
        "estimator": run_estimator(copy.deepcopy(estimator).double(), inputs),
    }
    for name, out in outputs.items():
        err = float((out.double() - exact[name]).abs().max())
        print(f"{name}: shape {tuple(out.shape)}, max |out| {float(out.abs().max()):.4g}, float32 vs float64 {err:.3e}")
    tensors = {k: v.detach().float().contiguous() for k, v in {**inputs, **outputs}.items()}
    save_file(tensors, str(args.out), metadata={"seed": str(SEED), "generator_seed": str(GENERATOR_SEED)})
    print(f"wrote {args.out} ({args.out.stat().st_size} bytes)")


if __name__ == "__main__":
    main()
