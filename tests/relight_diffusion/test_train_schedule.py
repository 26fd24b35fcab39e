"""The diffusion trainer's learning-rate schedule: a function of the step, applied each update."""

import math

import pytest
import torch

from relight.diffusion import train
from relight.diffusion.train import TrainConfig, learning_rate


def test_constant_schedule_keeps_the_rate():
    cfg = TrainConfig(lr=3e-4, steps=100)
    assert {learning_rate(cfg, s) for s in range(0, 100, 7)} == {3e-4}


def test_cosine_holds_then_falls_to_zero_at_the_last_step():
    cfg = TrainConfig(lr=2e-4, steps=300, lr_schedule="cosine", lr_decay_from=100)
    assert learning_rate(cfg, 0) == learning_rate(cfg, 100) == 2e-4
    assert math.isclose(learning_rate(cfg, 200), 1e-4, rel_tol=1e-12)  # half way: half the rate
    assert learning_rate(cfg, 300) == pytest.approx(0.0, abs=1e-20)
    rates = [learning_rate(cfg, s) for s in range(100, 301)]
    assert all(a >= b for a, b in zip(rates, rates[1:]))


@pytest.mark.parametrize("kwargs", [dict(lr_schedule="linear"), dict(lr_schedule="cosine", lr_decay_from=5)])
def test_bad_schedule_is_refused_before_training(kwargs, tmp_path):
    with pytest.raises(ValueError, match="lr_schedule|lr_decay_from"):
        train.main(TrainConfig(ckpt_dir=str(tmp_path), steps=5, **kwargs))
    assert not (tmp_path / "latest").exists()


def test_training_applies_the_schedule_each_update(tmp_path, monkeypatch):
    seen = []
    step = torch.optim.AdamW.step

    def spy(self, *args, **kwargs):
        seen.append(self.param_groups[0]["lr"])
        return step(self, *args, **kwargs)

    monkeypatch.setattr(torch.optim.AdamW, "step", spy)
    cfg = TrainConfig(
        ckpt_dir=str(tmp_path), steps=4, resolution=16, block_out_channels="8,16", ckpt_every=100,
        lr=1e-3, lr_schedule="cosine", lr_decay_from=2,
    )
    train.main(cfg)
    assert seen == pytest.approx([learning_rate(cfg, s) for s in range(4)])
    assert seen[:3] == pytest.approx([1e-3, 1e-3, 1e-3]) and seen[3] == pytest.approx(5e-4)
