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


def test_capture_domain_data_is_what_the_pipeline_hands_the_relighter(tmp_path):
    from materials.domain_groups import REAL_DEV_TRAIN, REAL_DEV_VALIDATION, DomainGroups, save_texture_folder
    from materials.procedural import generate

    for k, name in enumerate((*REAL_DEV_TRAIN, *REAL_DEV_VALIDATION)):
        save_texture_folder(tmp_path / name, generate(100 + k, size=32))
    data = train.training_data(TrainConfig(domain="capture", textures=str(tmp_path), p_texture=0.5, **SMALL))
    assert isinstance(data, DomainGroups)
    assert data.texture_names == list(REAL_DEV_TRAIN)  # the validation materials stay out
    for i in range(6):
        item = data[i]
        assert item["images"].shape == item["clean"].shape == (8, 3, 16, 16)
        # a fixed camera (the pipeline relights around one camera) and no falloff (the
        # pipeline divides the photo's out before relighting)
        assert torch.equal(item["camera_pos"], item["camera_pos"][:1].expand(8, 3))
        assert not bool(item["inverse_square"])
    # the clipped, quantised photos are the condition, the unclipped renders the targets
    assert any(float(data[i]["clean"].max()) > 1.0 for i in range(6))
    assert all(float(data[i]["images"].max()) <= 1.0 for i in range(6))
    assert isinstance(train.training_data(TrainConfig(**SMALL)), train.RenderedGroups)


def test_a_capture_domain_run_trains_and_init_from_starts_it_from_saved_weights(tmp_path):
    from relight.diffusion import RelightDiffusion

    torch.manual_seed(3)
    RelightDiffusion(**TINY.__dict__).save_pretrained(tmp_path / "start")
    start = _weights(tmp_path / "start")
    # lr 0: the weights stay the saved ones, so the run must have started from them
    cfg = dict(SMALL, lr=0.0)
    last = train.main(TrainConfig(ckpt_dir=str(tmp_path / "a"), steps=1, init_from=str(tmp_path / "start"), **cfg))
    for k, v in _weights(last / "model").items():
        torch.testing.assert_close(v, start[k], atol=0, rtol=0, msg=k)
    # one real step in the capture domain moves them, with a finite loss
    last = train.main(TrainConfig(ckpt_dir=str(tmp_path / "b"), steps=1, domain="capture", **SMALL))
    (entry,) = read_trainer_state(last)["history"]
    assert math.isfinite(entry["loss"])


def test_init_from_is_checked():
    with pytest.raises(FileNotFoundError, match="no config.json"):
        train.main(TrainConfig(ckpt_dir="runs/never", steps=1, init_from="/nonexistent", **SMALL))


def test_init_from_refuses_another_architecture(tmp_path):
    from relight.diffusion import RelightDiffusion

    RelightDiffusion(**TINY.__dict__).save_pretrained(tmp_path / "start")
    other = DiffusionModelConfig(resolution=16, block_out_channels=(8, 8))
    with pytest.raises(ValueError, match="another architecture"):
        train.main(TrainConfig(ckpt_dir=str(tmp_path / "a"), steps=1, init_from=str(tmp_path / "start"), model=other))


@pytest.mark.parametrize(
    "kwargs, message",
    [
        (dict(domain="nosuch"), "domain must be one of"),
        (dict(textures="x"), "textures needs domain='capture'"),
        (dict(domain="capture", p_paper=1.5), "p_paper must be in"),
    ],
)
def test_bad_data_options_are_refused(kwargs, message):
    with pytest.raises(ValueError, match=message):
        TrainConfig(**kwargs)
