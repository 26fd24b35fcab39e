"""The training entry point: a tiny run writes an atomic checkpoint, a loss curve and a
history; a rerun resumes from it (exactly: the same weights as an uninterrupted run);
flags map onto the config dataclass."""

import dataclasses

import pytest
import torch
from safetensors.torch import load_file

from materials.capture_domain import CaptureDomain
from materials.dataset import GroupConfig, RenderedGroups
from materials.domain_groups import REAL_DEV_TRAIN, DomainGroups, relighting_groups, save_texture_folder
from materials.procedural import generate
from relight.bieron.model import BieronRelighter
from relight.bieron.train import MAX_PROCESSES, BieronModelConfig, TrainConfig, main, parse_args, sample_batch
from training.checkpoint import latest_checkpoint, read_trainer_state
from training.seeding import step_generator

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


def _texture_root(root):
    """The ``REAL_DEV_TRAIN`` texture folders under ``root``, made from procedural maps."""
    for k, name in enumerate(REAL_DEV_TRAIN):
        save_texture_folder(root / name, generate(200 + k, size=40))
    return root


def test_capture_domain_targets_the_unclipped_views(tmp_path):
    """``--domain capture`` shares the diffusion trainer's data (``relighting_groups``): the
    photo is the degraded view 0, the targets are the items' ``clean`` views."""
    root = _texture_root(tmp_path / "tex")
    cfg = _cfg(tmp_path, 2, domain="capture", textures=str(root), p_texture=0.5, p_mix=0.5)
    data = relighting_groups(
        GroupConfig(size=cfg.size, views=8, seed=cfg.seed), "capture", root, p_texture=0.5, p_mix=0.5
    )
    assert type(data) is DomainGroups and data.texture_names == list(REAL_DEV_TRAIN)
    batch = sample_batch(data, cfg, step=0)
    # Rebuild the batch from the items the step drew: targets from "clean", not "images".
    index = torch.randint(0, len(data), (cfg.batch,), generator=step_generator(cfg.seed, 0, streams=MAX_PROCESSES))
    items = [data[int(i)] for i in index]
    torch.testing.assert_close(batch["photo"], torch.stack([it["images"][0] for it in items]), atol=0, rtol=0)
    clean = torch.stack([it["clean"] for it in items])  # [B, 8, 3, H, W]
    degraded = torch.stack([it["images"] for it in items])
    assert not torch.equal(clean, degraded)  # the degradations did change the views
    for b in range(cfg.batch):
        for t in range(cfg.targets_per_group):
            matches = [v for v in range(1, 8) if torch.equal(batch["target"][b, t], clean[b, v])]
            assert matches, f"target {b},{t} is not one of the item's clean views"
    # The paper domain (the default) is the stream of every earlier run.
    assert type(relighting_groups(GroupConfig(size=16, views=8, seed=0))) is RenderedGroups


def test_p_crop_zero_trains_on_whole_planes():
    """``p_crop`` = 0: every capture-domain item shows the whole plane, so its camera stays
    at a height the geometry samples (``CaptureDomain.camera_height``); with ``p_crop`` = 1
    every item is a window, which scales positions by 4 / side and lifts some cameras
    above that range (a window of side s is the plane seen from 4 / s times as high)."""
    config = GroupConfig(size=8, views=8, seed=3)
    low, high = CaptureDomain.camera_height
    heights = {}
    for p in (0.0, 1.0):
        data = relighting_groups(config, "capture", p_crop=p)
        assert type(data) is DomainGroups and data.domain.p_crop == p
        heights[p] = torch.stack([data[i]["camera_pos"][0, 2] for i in range(24)])
    assert ((heights[0.0] >= low - 1e-4) & (heights[0.0] <= high + 1e-4)).all()
    assert (heights[1.0] > high).sum() >= 4
    with pytest.raises(ValueError, match="p_crop"):
        relighting_groups(config, "capture", p_crop=1.5)
    assert parse_args(["--domain", "capture", "--p-crop", "0"]).p_crop == 0.0


def test_capture_domain_fine_tune_from_saved_weights_and_resume_checks(tmp_path):
    root = _texture_root(tmp_path / "tex")
    start = BieronRelighter(**dataclasses.asdict(TINY))
    start.save_pretrained(tmp_path / "start")
    capture = dict(domain="capture", textures=str(root), p_texture=0.5, p_paper=0.3, init_from=str(tmp_path / "start"))
    cfg = _cfg(tmp_path, 2, **capture)
    cfg.lr = 0.0  # the weights stay those of init_from: the run did start from them
    cfg.weight_decay = 0.0
    main(cfg)
    trained, saved = _weights(tmp_path / "ckpt"), start.state_dict()
    for k in saved:
        torch.testing.assert_close(trained[k], saved[k], atol=0, rtol=0, msg=k)
    # A checkpoint resumes only with the data (and init_from) it was trained on.
    with pytest.raises(ValueError, match="p_paper"):
        main(_cfg(tmp_path, 3, **{**capture, "p_paper": 0.0}))
    with pytest.raises(ValueError, match="p_crop"):
        main(_cfg(tmp_path, 3, **{**capture, "p_crop": 0.0}))
    with pytest.raises(ValueError, match="domain"):
        main(_cfg(tmp_path, 3, init_from=capture["init_from"]))
    with pytest.raises(ValueError, match="another run"):
        main(_cfg(tmp_path, 3, **{**capture, "init_from": str(root)}))
    # init_from must hold a model of the requested architecture.
    with pytest.raises(FileNotFoundError, match="config.json"):
        main(_cfg(tmp_path / "x", 1, init_from=str(root)))
    with pytest.raises(ValueError, match="architecture"):
        main(
            _cfg(tmp_path / "y", 1, init_from=str(tmp_path / "start"), model=dataclasses.replace(TINY, base_channels=4))
        )
    flags = parse_args(["--domain", "capture", "--textures", str(root), "--p-paper", "0.3", "--init-from", "w"])
    assert (flags.domain, flags.textures, flags.p_paper, flags.init_from) == ("capture", str(root), 0.3, "w")
    with pytest.raises(ValueError, match="capture"):
        TrainConfig(textures=str(root))  # textures only mean something in the capture domain
