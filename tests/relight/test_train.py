"""The training entry point: a tiny run writes an atomic checkpoint, a loss curve and a
history; a rerun resumes from it (exactly: the same weights as an uninterrupted run);
flags map onto the config dataclass."""

import pytest
import torch
from safetensors.torch import load_file

from relight.bieron.model import BieronRelighter
from relight.bieron.train import BieronModelConfig, TrainConfig, main, parse_args
from training.checkpoint import latest_checkpoint, read_trainer_state

TINY = BieronModelConfig(base_channels=8, channel_mults=(1, 2), norm_groups=4, residual="lambertian")


def _cfg(folder, steps, **kw):
    base = dict(
        ckpt_dir=str(folder / "ckpt"),
        steps=steps,
        size=16,
        batch=2,
        targets_per_group=2,
        model=TINY,
        progress=False,
        warmup_steps=2,
        ckpt_every=2,
    )
    return TrainConfig(**{**base, **kw})


def _weights(ckpt_dir):
    return load_file(str(latest_checkpoint(ckpt_dir) / "model" / "diffusion_pytorch_model.safetensors"))


def test_train_checkpoint_and_resume(tmp_path):
    summary = main(_cfg(tmp_path, 3))
    assert summary["step"] == 3
    first = latest_checkpoint(tmp_path / "ckpt")
    assert first is not None and first.name == "checkpoint-0000003"
    assert (tmp_path / "ckpt" / "loss.png").is_file()
    state = read_trainer_state(first)
    assert state["step"] == 3 and [h["step"] for h in state["history"]] == [1, 2, 3]
    assert state["config"]["size"] == 16 and state["config"]["model"]["base_channels"] == 8
    BieronRelighter.from_pretrained(first / "model")

    summary = main(_cfg(tmp_path, 5))  # resumes at step 3, runs 2 more
    assert summary["step"] == 5
    assert len(read_trainer_state(latest_checkpoint(tmp_path / "ckpt"))["history"]) == 5
    assert not list((tmp_path / "ckpt").glob(".*tmp"))  # no temporary folders left


def test_resume_equals_an_uninterrupted_run(tmp_path):
    # Batches are seeded by (seed, step) and the schedule is a function of the step, so
    # 2 + 2 steps must give the same weights, bit for bit, as 4 (one process, CPU).
    main(_cfg(tmp_path / "a", 4))
    main(_cfg(tmp_path / "b", 2))
    main(_cfg(tmp_path / "b", 4))
    a, b = _weights(tmp_path / "a" / "ckpt"), _weights(tmp_path / "b" / "ckpt")
    assert a.keys() == b.keys()
    for k in a:
        torch.testing.assert_close(a[k], b[k], atol=0, rtol=0, msg=k)


def test_resume_refuses_another_architecture(tmp_path):
    main(_cfg(tmp_path, 1))
    with pytest.raises(ValueError, match="architecture"):
        main(_cfg(tmp_path, 2, model=BieronModelConfig(base_channels=4, channel_mults=(1, 2), norm_groups=4)))


def test_wall_clock_budget_stops_the_run(tmp_path):
    cfg = _cfg(tmp_path, 10_000)
    cfg.minutes = 1e-4  # 6 ms: stops after the first step
    summary = main(cfg)
    assert 1 <= summary["step"] < 10_000
    assert latest_checkpoint(tmp_path / "ckpt") is not None


def test_flags_follow_the_dataclass(capsys):
    cfg = parse_args(["--steps", "7", "--model.channel-mults", "1,2", "--no-progress", "--minutes", "0.5"])
    assert cfg.steps == 7 and cfg.model.channel_mults == (1, 2) and cfg.progress is False and cfg.minutes == 0.5
    assert cfg.model.residual == "lambertian"  # the trainer's default, not the class's "none"
    with pytest.raises(ValueError, match="targets_per_group"):
        TrainConfig(targets_per_group=8)


def test_old_architecture_flags_still_work_for_one_release(capsys):
    cfg = parse_args(["--base-channels", "16", "--channel-mults", "1,2", "--residual", "none"])
    assert cfg.model.base_channels == 16 and cfg.model.channel_mults == (1, 2) and cfg.model.residual == "none"
    err = capsys.readouterr().err
    assert "--base-channels is deprecated" in err and "--model.base-channels" in err
