"""The diffusion trainer: learning-rate schedule (a function of the step, applied each update),
the weight average (EMA) saved beside the model, exact resume, snapshots, old flags."""

import math

import pytest
import torch

from relight.diffusion import train
from relight.diffusion.train import DiffusionModelConfig, TrainConfig, learning_rate, parse_args
from training.checkpoint import latest_checkpoint, load_checkpoint, read_trainer_state

TINY = DiffusionModelConfig(resolution=16, block_out_channels=(8, 16))


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
    assert not list(tmp_path.iterdir())  # nothing written


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
        model=TINY,
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
SMALL = dict(model=TINY, ckpt_every=2, lr=1e-3)


def _weights(folder):
    from relight.diffusion import RelightDiffusion

    return {k: v.clone() for k, v in RelightDiffusion.from_pretrained(folder).state_dict().items()}


def test_ema_is_saved_beside_the_model_and_resumed(tmp_path):
    # decay ~0: the average follows the weights (up to the rounding of s - (s - p)), so
    # ema/ must equal model/; checks that saving the average puts the trained weights back.
    last = train.main(TrainConfig(ckpt_dir=str(tmp_path / "a"), steps=2, ema_decay=1e-12, **SMALL))
    model, ema = _weights(last / "model"), _weights(last / "ema")
    assert max((model[k] - ema[k]).abs().max().item() for k in model) < FLOAT32_ROUNDING

    # decay 0.9: the average lags the weights; a resumed run continues its count.
    cfg = TrainConfig(ckpt_dir=str(tmp_path / "b"), steps=2, ema_decay=0.9, **SMALL)
    last = train.main(cfg)
    model, ema = _weights(last / "model"), _weights(last / "ema")
    assert any(not torch.equal(model[k], ema[k]) for k in model)
    last = train.main(TrainConfig(**{**cfg.__dict__, "steps": 4}))
    state = load_checkpoint(last, restore_rng=False)
    assert state.step == 4 and state.ema["optimization_step"] == 4


def test_no_ema_folder_without_ema(tmp_path):
    last = train.main(TrainConfig(ckpt_dir=str(tmp_path), steps=1, **SMALL))
    assert (last / "model").is_dir() and not (last / "ema").exists()
    assert load_checkpoint(last, restore_rng=False).ema is None


def test_resume_equals_an_uninterrupted_run_and_keeps_snapshots(tmp_path):
    # The data order is the step's and the torch RNG state is restored, so 2 + 2 steps
    # give the weights of 4, bit for bit (one process, CPU); the EMA continues too.
    cfg = dict(SMALL, ckpt_every=1, ema_decay=0.9)
    straight = train.main(TrainConfig(ckpt_dir=str(tmp_path / "a"), steps=4, **cfg))
    train.main(TrainConfig(ckpt_dir=str(tmp_path / "b"), steps=2, keep_every=2, **cfg))
    resumed = train.main(TrainConfig(ckpt_dir=str(tmp_path / "b"), steps=4, keep_every=2, **cfg))
    for sub in ("model", "ema"):
        a, b = _weights(straight / sub), _weights(resumed / sub)
        for k in a:
            torch.testing.assert_close(a[k], b[k], atol=0, rtol=0, msg=f"{sub} {k}")
    history = read_trainer_state(latest_checkpoint(tmp_path / "b"))["history"]
    assert [h["step"] for h in history] == [1, 2, 3, 4]
    # keep_checkpoints 1: only the latest, plus the snapshots at multiples of keep_every.
    assert sorted(p.name for p in (tmp_path / "b").glob("checkpoint-*")) == ["checkpoint-0000002", "checkpoint-0000004"]
    assert sorted(p.name for p in (tmp_path / "a").glob("checkpoint-*")) == ["checkpoint-0000004"]


def test_old_architecture_flags_still_work_for_one_release(capsys):
    cfg = parse_args(["--resolution", "32", "--block-out-channels", "16,32", "--base", "lambertian", "--steps", "3"])
    assert cfg.model.resolution == 32 and cfg.model.block_out_channels == (16, 32) and cfg.model.base == "lambertian"
    assert cfg.steps == 3
    assert "--resolution is deprecated" in capsys.readouterr().err
    new = parse_args(["--model.resolution", "32", "--model.block-out-channels", "16,32", "--model.base", "lambertian"])
    assert new.model == cfg.model
