"""training.checkpoint: a save/restore round trip gives back the weights, the optimizer,
the EMA and the RNG states exactly (so training continues as if never stopped); the
``latest`` pointer, pruning and snapshots; a failed save leaves the previous checkpoint."""

import json
import random

import numpy as np
import pytest
import torch
from diffusers.configuration_utils import ConfigMixin, register_to_config
from diffusers.models.modeling_utils import ModelMixin
from diffusers.training_utils import EMAModel
from safetensors.torch import load_file

from training.checkpoint import (
    flatten_state,
    latest_checkpoint,
    load_checkpoint,
    read_trainer_state,
    save_checkpoint,
    trainable_parameters,
    unflatten_state,
)


class Tiny(ModelMixin, ConfigMixin):
    """A linear layer that trains and one that is frozen (not in the optimizer or the EMA)."""

    @register_to_config
    def __init__(self, width: int = 4):
        super().__init__()
        self.trained = torch.nn.Linear(3, width)
        self.frozen = torch.nn.Linear(width, 1)
        self.frozen.requires_grad_(False)

    def forward(self, x):
        return self.frozen(torch.tanh(self.trained(x)))


def _train(model, optimizer, ema, steps):
    for _ in range(steps):
        loss = model(torch.randn(5, 3)).pow(2).mean()  # draws from the global torch RNG
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        ema.step(trainable_parameters(model))


def _setup(seed=0):
    torch.manual_seed(seed)
    model = Tiny()
    optimizer = torch.optim.AdamW(trainable_parameters(model), lr=1e-2, betas=(0.8, 0.95))
    ema = EMAModel(trainable_parameters(model), decay=0.9)
    return model, optimizer, ema


def _save(ckpt_dir, model, optimizer, ema, step, **kw):
    history = [{"step": s, "loss": 1.0 / s} for s in range(1, step + 1)]
    return save_checkpoint(
        ckpt_dir, step=step, model=model, optimizer=optimizer, history=history, config={"lr": 1e-2}, ema=ema, **kw
    )


def test_round_trip_continues_training_exactly(tmp_path):
    model, optimizer, ema = _setup()
    _train(model, optimizer, ema, 3)
    np.random.seed(5)
    random.seed(6)
    folder = _save(tmp_path, model, optimizer, ema, 3, elapsed_s=12.5)
    expected_draws = (torch.rand(4), np.random.rand(), random.random())
    torch.manual_seed(123), np.random.seed(123), random.seed(123)  # disturb every RNG

    restored = Tiny.from_pretrained(folder / "model")
    opt2 = torch.optim.AdamW(trainable_parameters(restored), lr=1e-2)
    state = load_checkpoint(folder, optimizer=opt2)
    assert (torch.rand(4).tolist(), np.random.rand(), random.random()) == (
        expected_draws[0].tolist(),
        expected_draws[1],
        expected_draws[2],
    )
    assert state.step == 3 and state.elapsed_s == 12.5 and state.config == {"lr": 1e-2}
    assert [h["step"] for h in state.history] == [1, 2, 3]
    assert opt2.state_dict()["param_groups"] == optimizer.state_dict()["param_groups"]
    ema2 = EMAModel(trainable_parameters(restored), decay=0.5)
    ema2.load_state_dict(state.ema)
    assert ema2.decay == 0.9 and ema2.optimization_step == 3
    for a, b in zip(ema.shadow_params, ema2.shadow_params):
        torch.testing.assert_close(a, b, atol=0, rtol=0)

    # The ema/ folder holds the average, and saving it left the trained weights in place.
    averaged = Tiny.from_pretrained(folder / "ema")
    torch.testing.assert_close(averaged.trained.weight, ema.shadow_params[0], atol=0, rtol=0)
    torch.testing.assert_close(restored.trained.weight, model.trained.weight, atol=0, rtol=0)

    # One more step from each: identical (weights, Adam moments, EMA, RNG all restored).
    rng = torch.get_rng_state()
    _train(restored, opt2, ema2, 1)
    torch.set_rng_state(rng)
    _train(model, optimizer, ema, 1)
    for a, b in zip(model.parameters(), restored.parameters()):
        torch.testing.assert_close(a, b, atol=0, rtol=0)
    for a, b in zip(ema.shadow_params, ema2.shadow_params):
        torch.testing.assert_close(a, b, atol=0, rtol=0)


def test_no_ema_means_no_ema_folder(tmp_path):
    model, optimizer, _ = _setup()
    folder = _save(tmp_path, model, optimizer, None, 1)
    assert (folder / "model" / "config.json").is_file() and not (folder / "ema").exists()
    assert load_checkpoint(folder, restore_rng=False).ema is None


def test_nothing_is_pickled(tmp_path):
    model, optimizer, ema = _setup()
    _train(model, optimizer, ema, 1)
    folder = _save(tmp_path, model, optimizer, ema, 1)
    names = sorted(p.relative_to(folder).as_posix() for p in folder.rglob("*") if p.is_file())
    assert all(n.endswith((".json", ".safetensors")) for n in names), names
    json.loads((folder / "trainer_state.json").read_text())
    load_file(str(folder / "state.safetensors"))


def test_keep_and_snapshots(tmp_path):
    model, optimizer, ema = _setup()
    for step in range(1, 7):
        _save(tmp_path, model, optimizer, ema, step, keep=2, keep_every=3)
    kept = sorted(p.name for p in tmp_path.glob("checkpoint-*"))
    # The newest two (5, 6) and the multiples of 3 (3, 6).
    assert kept == ["checkpoint-0000003", "checkpoint-0000005", "checkpoint-0000006"]
    assert latest_checkpoint(tmp_path).name == "checkpoint-0000006"
    assert read_trainer_state(latest_checkpoint(tmp_path))["step"] == 6


def test_a_restarted_run_leaves_later_checkpoints_alone(tmp_path):
    model, optimizer, ema = _setup()
    _save(tmp_path, model, optimizer, ema, 10, keep=1)
    _save(tmp_path, model, optimizer, ema, 2, keep=1)  # e.g. --no-resume into the same folder
    assert latest_checkpoint(tmp_path).name == "checkpoint-0000002"
    assert (tmp_path / "checkpoint-0000010").is_dir()


def test_a_failed_save_keeps_the_previous_checkpoint(tmp_path, monkeypatch):
    model, optimizer, ema = _setup()
    _save(tmp_path, model, optimizer, ema, 1)

    def broken(*args, **kwargs):
        raise OSError("disk full")

    monkeypatch.setattr(Tiny, "save_pretrained", broken)
    with pytest.raises(OSError, match="disk full"):
        _save(tmp_path, model, optimizer, ema, 2)
    assert latest_checkpoint(tmp_path).name == "checkpoint-0000001"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["checkpoint-0000001", "latest"]  # no temporary left


def test_latest_is_none_for_an_empty_or_missing_folder(tmp_path):
    assert latest_checkpoint(tmp_path) is None
    assert latest_checkpoint(tmp_path / "nowhere") is None


@pytest.mark.parametrize(
    "files",
    [
        ["latest/state.pt", "latest/model/relight_config.json"],  # the diffusion trainer's
        ["step_0000947/state.pt", "step_0000947/model/config.json"],  # the Bieron trainer's
        ["latest", "checkpoint-0000100/optimizer.safetensors", "checkpoint-0000100/trainer_state.json"],  # estimator
    ],
)
def test_old_layouts_are_refused_with_a_way_out(tmp_path, files):
    for name in files:
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_text("checkpoint-0000100\n" if name == "latest" else "{}")
    with pytest.raises(ValueError, match="old layout.*new --ckpt-dir"):
        latest_checkpoint(tmp_path)


def test_flatten_state_round_trip_and_refusals():
    model = torch.nn.Linear(3, 2)
    opt = torch.optim.AdamW(model.parameters())
    model(torch.ones(1, 3)).sum().backward()
    opt.step()
    tensors, skeleton = flatten_state(opt.state_dict())
    back = unflatten_state(tensors, json.loads(json.dumps(skeleton)))
    assert back["param_groups"] == opt.state_dict()["param_groups"]  # tuples (betas) stay tuples
    for k, v in opt.state_dict()["state"].items():  # int keys stay ints
        for name, t in v.items():
            torch.testing.assert_close(back["state"][k][name], t, atol=0, rtol=0)
    with pytest.raises(TypeError, match="cannot checkpoint a object"):
        flatten_state({"a": object()})
    with pytest.raises(TypeError, match="keys must be int or str"):
        flatten_state({(1, 2): 0})
