"""Our top-level package ``kernels`` shares its import name with Hugging Face's hub-kernels
package (``pip install kernels``), which diffusers and transformers probe for and, when
they believe it is installed, import (``from kernels import get_kernel``).

diffusers decides with ``importlib.util.find_spec("kernels")`` and then
``importlib.metadata.version("kernels")``: ours is found but its distribution is
``dgrsise``, so the version lookup fails and the probe says "not available". transformers
(the sd21 preset's text encoder) falls back to the distribution that provides the import
name: it finds ``dgrsise`` and accepts it only inside its supported range of hub-kernels
versions (``KERNELS_MIN_VERSION`` <= v < ``KERNELS_MAX_VERSION``); our version is outside
it. kernels/DESIGN.md records this. These tests hold both probes at "not available" while
ours is importable, and run the diffusers code paths the project uses with a tripwire on
our module that fails if diffusers, transformers or huggingface_hub touch it.
"""

from __future__ import annotations

import importlib.metadata
import importlib.util
import sys
import types
from pathlib import Path

import pytest
import torch

import kernels

#: Top-level packages that must never reach into our ``kernels``.
FOREIGN = ("diffusers", "transformers", "huggingface_hub", "accelerate")


def test_our_kernels_is_the_importable_one():
    spec = importlib.util.find_spec("kernels")
    assert spec is not None and Path(spec.origin).resolve() == Path(kernels.__file__).resolve()
    assert "dgrsise" in importlib.metadata.packages_distributions().get("kernels", [])
    with pytest.raises(importlib.metadata.PackageNotFoundError):
        importlib.metadata.version("kernels")  # no distribution named "kernels"


def test_diffusers_probe_says_hub_kernels_are_not_available():
    from diffusers.utils import import_utils, is_kernels_available, is_kernels_version

    assert not is_kernels_available()
    assert import_utils._kernels_version == "N/A"
    assert not is_kernels_version(">=", "0.0")


def test_transformers_probe_says_hub_kernels_are_not_available():
    """transformers maps the import name to our distribution and checks its version range:
    a project version inside [KERNELS_MIN_VERSION, KERNELS_MAX_VERSION) would make it
    import our package as hub kernels. This fails first if the version ever gets there."""
    import_utils = pytest.importorskip("transformers.utils.import_utils")
    ours = importlib.metadata.version("dgrsise")
    assert not import_utils.is_kernels_available(), (
        f"transformers takes dgrsise {ours} for hub kernels "
        f"[{import_utils.KERNELS_MIN_VERSION}, {import_utils.KERNELS_MAX_VERSION})"
    )


class _Tripwire(types.ModuleType):
    """Stands in for ``kernels`` in ``sys.modules``: attribute reads are passed to the
    real module, and recorded (then refused) when the first caller outside importlib is
    one of the FOREIGN packages (dunder reads, the import system's probing, pass). Our own modules keep working: they bound the real module
    at import, and their lazy ``from kernels import x`` passes through."""

    def __init__(self, real: types.ModuleType):
        super().__init__(real.__name__)
        object.__setattr__(self, "_real", real)
        object.__setattr__(self, "foreign_reads", [])

    def __getattr__(self, name: str):
        if name.startswith("__") and name.endswith("__"):
            # __spec__, __path__: what find_spec and the import system read to locate a
            # module (a probe), not a use of its contents.
            return getattr(self._real, name)
        frame = sys._getframe(1)
        while frame is not None and frame.f_globals.get("__name__", "").startswith(("importlib", "_frozen_importlib")):
            frame = frame.f_back
        caller = frame.f_globals.get("__name__", "") if frame is not None else ""
        if caller.split(".")[0] in FOREIGN:
            self.foreign_reads.append((caller, name))
            raise ImportError(f"{caller} reached into dgrsise's kernels for {name!r}")
        return getattr(self._real, name)


def test_tripwire_catches_a_foreign_import(monkeypatch):
    """The tripwire is not vacuous: code whose module is under diffusers that runs
    ``from kernels import get_kernel`` (what its hub paths do) is caught; ours is not."""
    wire = _Tripwire(kernels)
    monkeypatch.setitem(sys.modules, "kernels", wire)
    foreign = {"__name__": "diffusers._tripwire_probe"}
    with pytest.raises(ImportError):
        exec("from kernels import get_kernel", foreign)
    with pytest.raises(ImportError):
        exec("import kernels\nkernels.render", foreign)
    assert [name for _, name in wire.foreign_reads] == ["get_kernel", "render"]
    ours = {"__name__": "relight._tripwire_probe"}
    exec("from kernels import render", ours)
    assert ours["render"] is kernels.render


def test_project_diffusers_paths_do_not_touch_our_kernels(monkeypatch, tmp_path):
    """UNet2DConditionModel and ControlNetModel (through the tiny RelightDiffusion, with
    its decoupled-attention processors), DDPM and DDIM scheduler steps, and ModelMixin
    save_pretrained / from_pretrained (UNet, ControlNet, SVBRDFEstimator), with the
    tripwire in place."""
    from diffusers import ControlNetModel, DDPMScheduler, UNet2DConditionModel

    from estimator import SVBRDFEstimator
    from estimator.config import TINY_TEST_CONFIG
    from relight.diffusion import RelightDiffusion
    from relight.diffusion.pipeline import RelightPipeline

    wire = _Tripwire(kernels)
    monkeypatch.setitem(sys.modules, "kernels", wire)
    torch.manual_seed(0)
    model = RelightDiffusion(
        resolution=16,
        block_out_channels=(8, 16),
        cross_attention_dim=16,
        attention_head_dim=4,
        num_light_tokens=2,
        condition_widths=(4, 4, 4, 4, 8, 8),
    ).eval()
    photo = torch.rand(3, 16, 16)
    lights = torch.tensor([[1.0, 0.5, 4.0], [-1.0, 0.0, 5.0]])
    camera = torch.tensor([0.0, 0.0, 4.0])
    out = RelightPipeline(model)(
        photo, lights, camera, num_inference_steps=2, generator=torch.Generator(), progress=False
    )
    assert out.shape == (2, 3, 16, 16) and bool(torch.isfinite(out).all())

    x0 = torch.rand(2, *model.sample_shape)
    noise = torch.randn_like(x0)
    t = torch.tensor([10, 500])
    train_scheduler = DDPMScheduler(num_train_timesteps=1000, prediction_type="v_prediction")
    x_t = train_scheduler.add_noise(x0, noise, t)
    v = model(x_t, t, photo.expand(2, -1, -1, -1), photo.expand(2, -1, -1, -1), lights, camera.expand(2, 3))
    assert train_scheduler.get_velocity(x0, noise, t).shape == v.shape
    train_scheduler.set_timesteps(5)
    train_scheduler.step(v[:1].detach(), train_scheduler.timesteps[0], x_t[:1])

    model.unet.save_pretrained(tmp_path / "unet")
    model.controlnet.save_pretrained(tmp_path / "controlnet")
    UNet2DConditionModel.from_pretrained(tmp_path / "unet")
    ControlNetModel.from_pretrained(tmp_path / "controlnet")
    model.save_pretrained(tmp_path / "relight")
    RelightDiffusion.from_pretrained(tmp_path / "relight")
    SVBRDFEstimator(**TINY_TEST_CONFIG.to_dict()).save_pretrained(tmp_path / "estimator")
    SVBRDFEstimator.from_pretrained(tmp_path / "estimator")

    assert wire.foreign_reads == []
