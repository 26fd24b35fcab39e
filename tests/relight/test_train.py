"""The training entry point: a tiny run writes an atomic checkpoint, a loss curve and a
history; a rerun resumes from it; flags map onto the config dataclass."""

import json

import pytest

from relight.bieron.checkpoint import latest_checkpoint, load_state
from relight.bieron.model import BieronRelighter
from relight.bieron.train import TrainConfig, main, parse_args


def _cfg(tmp_path, steps):
    return TrainConfig(
        ckpt_dir=str(tmp_path / "ckpt"),
        steps=steps,
        size=16,
        batch=2,
        targets_per_group=2,
        base_channels=8,
        channel_mults=(1, 2),
        norm_groups=4,
        progress=False,
        warmup_steps=2,
    )


def test_train_checkpoint_and_resume(tmp_path):
    summary = main(_cfg(tmp_path, 3))
    assert summary["step"] == 3
    first = latest_checkpoint(tmp_path / "ckpt")
    assert first is not None and first.name == "step_0000003"
    assert (tmp_path / "ckpt" / "loss_curve.png").is_file()
    state, history = load_state(first)
    assert state["step"] == 3 and len(history["loss"]) == 3
    assert json.loads(state["config"])["size"] == 16
    BieronRelighter.from_pretrained(first / "model")

    summary = main(_cfg(tmp_path, 5))  # resumes at step 3, runs 2 more
    assert summary["step"] == 5
    _, history = load_state(latest_checkpoint(tmp_path / "ckpt"))
    assert len(history["loss"]) == 5
    assert not list((tmp_path / "ckpt").glob(".*tmp"))  # no temporary folders left


def test_wall_clock_budget_stops_the_run(tmp_path):
    cfg = _cfg(tmp_path, 10_000)
    cfg.minutes = 1e-4  # 6 ms: stops after the first step
    summary = main(cfg)
    assert 1 <= summary["step"] < 10_000
    assert latest_checkpoint(tmp_path / "ckpt") is not None


def test_flags_follow_the_dataclass():
    cfg = parse_args(["--steps", "7", "--channel-mults", "1,2", "--no-progress", "--minutes", "0.5"])
    assert cfg.steps == 7 and cfg.channel_mults == (1, 2) and cfg.progress is False and cfg.minutes == 0.5
    with pytest.raises(ValueError, match="targets_per_group"):
        TrainConfig(targets_per_group=8)
