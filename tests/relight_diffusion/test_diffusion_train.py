"""The diffusion trainer: learning-rate schedule (a function of the step, applied each update)
and the weight average (EMA) saved beside the model."""

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


@pytest.mark.parametrize(
    "kwargs",
    [
        dict(lr_schedule="linear"),
        dict(lr_schedule="cosine", lr_decay_from=5),
        dict(ema_decay=1.0),
        dict(terminal_fraction=1.5),
    ],
)
def test_bad_schedule_is_refused_before_training(kwargs, tmp_path):
    with pytest.raises(ValueError, match="lr_schedule|lr_decay_from|ema_decay|terminal_fraction"):
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
        ckpt_dir=str(tmp_path),
        steps=4,
        resolution=16,
        block_out_channels="8,16",
        ckpt_every=100,
        lr=1e-3,
        lr_schedule="cosine",
        lr_decay_from=2,
    )
    train.main(cfg)
    assert seen == pytest.approx([learning_rate(cfg, s) for s in range(4)])
    assert seen[:3] == pytest.approx([1e-3, 1e-3, 1e-3]) and seen[3] == pytest.approx(5e-4)


#: |s - (s - p) - p| for float32 weights of magnitude <~ 4: a few ulps.
FLOAT32_ROUNDING = 1e-6
SMALL = dict(resolution=16, block_out_channels="8,16", ckpt_every=2, lr=1e-3)


def _weights(folder):
    from relight.diffusion import RelightDiffusion

    return {k: v.clone() for k, v in RelightDiffusion.from_pretrained(folder).state_dict().items()}


def test_ema_is_saved_beside_the_model_and_resumed(tmp_path):
    # decay ~0: the average follows the weights (up to the rounding of s - (s - p)), so
    # ema/ must equal model/; checks that saving the average puts the trained weights back.
    train.main(TrainConfig(ckpt_dir=str(tmp_path / "a"), steps=2, ema_decay=1e-12, **SMALL))
    model, ema = _weights(tmp_path / "a/latest/model"), _weights(tmp_path / "a/latest/ema")
    assert max((model[k] - ema[k]).abs().max().item() for k in model) < FLOAT32_ROUNDING

    # decay 0.9: the average lags the weights; a resumed run continues its count.
    cfg = TrainConfig(ckpt_dir=str(tmp_path / "b"), steps=2, ema_decay=0.9, **SMALL)
    train.main(cfg)
    model, ema = _weights(tmp_path / "b/latest/model"), _weights(tmp_path / "b/latest/ema")
    assert any(not torch.equal(model[k], ema[k]) for k in model)
    train.main(TrainConfig(**{**cfg.__dict__, "steps": 4}))
    state = torch.load(tmp_path / "b/latest/state.pt", weights_only=False)
    assert state["step"] == 4 and state["ema"]["optimization_step"] == 4


def test_no_ema_folder_without_ema(tmp_path):
    train.main(TrainConfig(ckpt_dir=str(tmp_path), steps=1, **SMALL))
    assert (tmp_path / "latest/model").is_dir() and not (tmp_path / "latest/ema").exists()
    assert "ema" not in torch.load(tmp_path / "latest/state.pt", weights_only=False)
