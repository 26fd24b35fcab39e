"""Training: the loss can overfit a tiny batch; checkpoints resume exactly; CLI parsing."""

from __future__ import annotations

import dataclasses
import json

import pytest
import torch
import torch.nn.functional as F
from safetensors.torch import load_file

from estimator import SVBRDFEstimator, estimator_loss
from estimator.config import TRAINING_DEFAULTS
from estimator.losses import NORMAL_MSE_SCALE
from estimator.train import (
    EstimatorModelConfig,
    StepBatchSampler,
    TrainConfig,
    _load_initial_weights,
    main,
    parse_args,
    select_views,
    training_data,
)
from materials.dataset import TRAIN_SEEDS, GroupConfig, RenderedGroups
from materials.domain_groups import REAL_DEV_TRAIN, REAL_DEV_VALIDATION, DomainGroups, save_texture_folder
from materials.procedural import generate
from materials.types import Material
from training.checkpoint import flatten_state, latest_checkpoint, unflatten_state
from training.config import config_of

#: The tiny architecture of the fast tests (32 x 32 images, a few thousand parameters).
TINY = EstimatorModelConfig(
    base_channels=8, channel_mults=(1, 2, 4), adapter_width=8, norm_groups=4, shading_channels=4
)

#: Overfitting a fixed batch of 2 materials x 3 views with the tiny model: the loss
#: falls to ~28% of its start in 60 Adam steps (measured, 1 thread); 50% leaves room for noise.
OVERFIT_STEPS = 60
OVERFIT_RATIO = 0.5
#: How close a fitted constant slope must come to the L1 / MSE optimum (median 0; mean of
#: the slopes 0.06): measured 3e-6 and 0.058 (normalising the normals pulls the MSE optimum
#: a little below the mean slope); Adam at lr 1e-3 in the last 200 steps jitters far less.
MEDIAN_TOLERANCE = 0.005


def _tiny_train_config(tmp_path, **kw) -> TrainConfig:
    base = dict(
        steps=4,
        batch_size=2,
        size=32,
        max_views=4,
        ckpt_dir=str(tmp_path / "ckpt"),
        out_dir=str(tmp_path / "out"),
        ckpt_every=2,
        log_every=2,
        progress=False,
        model=TINY,
    )
    base.update(kw)
    return TrainConfig(**base)


def test_overfits_a_fixed_batch():
    torch.manual_seed(0)
    data = RenderedGroups(TRAIN_SEEDS[:2], GroupConfig(size=32, views=3, source_size=64))
    batch = torch.utils.data.default_collate([data[0], data[1]])
    target = Material.from_stacked(batch["maps"])
    model = SVBRDFEstimator(**dataclasses.asdict(TINY))
    opt = torch.optim.Adam(model.parameters(), lr=3e-3)
    losses = []
    for _ in range(OVERFIT_STEPS):
        pred = model(batch["images"], batch["light_pos"], batch["camera_pos"])
        loss = estimator_loss(pred, target, generator=torch.Generator().manual_seed(0))["loss"]
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(float(loss.detach()))
    assert min(losses[-5:]) < OVERFIT_RATIO * losses[0], losses[::10]


def test_select_views_always_has_the_flash_view():
    seen = set()
    for s in range(200):
        v = select_views(8, 8, torch.Generator().manual_seed(s))
        assert v[0] == 0 and len(set(v)) == len(v) and all(0 <= i < 8 for i in v)
        seen.add(len(v))
    assert seen == set(range(1, 9))
    assert select_views(8, 1, torch.Generator().manual_seed(0)) == [0]


def test_select_views_min_views():
    # min_views 1 is the default stream (resumed runs of older configs see the same views)
    for s in range(20):
        g = lambda s=s: torch.Generator().manual_seed(s)  # noqa: E731
        assert select_views(8, 8, g()) == select_views(8, 8, g(), min_views=1)
    counts = {len(select_views(8, 8, torch.Generator().manual_seed(s), min_views=6)) for s in range(100)}
    assert counts == {6, 7, 8}
    assert select_views(8, 8, torch.Generator().manual_seed(0), min_views=8) == list(range(8))
    assert select_views(3, 8, torch.Generator().manual_seed(0), min_views=8) == [0, 1, 2]  # capped by the group
    with pytest.raises(ValueError, match="min_views"):
        TrainConfig(min_views=5, max_views=4)


def test_step_sampler_resumes_the_same_stream():
    full = list(StepBatchSampler(100, 4, seed=1, start=0, steps=6))
    assert list(StepBatchSampler(100, 4, seed=1, start=3, steps=6)) == full[3:]


def test_flatten_state_round_trip():
    model = torch.nn.Linear(3, 2)
    opt = torch.optim.AdamW(model.parameters())
    model(torch.ones(1, 3)).sum().backward()
    opt.step()
    tensors, skeleton = flatten_state(opt.state_dict())
    back = unflatten_state(tensors, json.loads(json.dumps(skeleton)))
    assert back["param_groups"] == opt.state_dict()["param_groups"]
    for k, v in opt.state_dict()["state"].items():
        for name, t in v.items():
            torch.testing.assert_close(back["state"][k][name], t)


def test_train_resume_matches_uninterrupted_run(tmp_path):
    straight = main(_tiny_train_config(tmp_path / "a", steps=4))
    main(_tiny_train_config(tmp_path / "b", steps=2))
    resumed = main(_tiny_train_config(tmp_path / "b", steps=4))
    a = load_file(str(next(straight.glob("*.safetensors"))))
    b = load_file(str(next(resumed.glob("*.safetensors"))))
    for k in a:
        torch.testing.assert_close(a[k], b[k], atol=0, rtol=0, msg=k)
    ckpt = latest_checkpoint(tmp_path / "b" / "ckpt")
    assert ckpt is not None and ckpt.name.endswith("0000004")
    state = json.loads((ckpt / "trainer_state.json").read_text())
    assert [h["step"] for h in state["history"]] == [1, 2, 3, 4]
    assert (tmp_path / "b" / "ckpt" / "loss.png").is_file()
    assert (tmp_path / "b" / "out" / "loss.png").is_file()
    assert len(list((tmp_path / "b" / "ckpt").glob("checkpoint-*"))) <= 2


def test_resume_a_run_whose_model_predates_the_shading_branch(tmp_path):
    """A checkpoint whose model/config.json has no shading_channels (saved before the
    field existed) resumes as the model package loads it (no branch); asking for a branch
    is refused, not crashed."""
    plain = dataclasses.replace(TINY, shading_channels=0)
    main(_tiny_train_config(tmp_path, steps=2, model=plain))
    config_file = latest_checkpoint(tmp_path / "ckpt") / "model" / "config.json"
    saved = json.loads(config_file.read_text())
    del saved["shading_channels"]
    config_file.write_text(json.dumps(saved))
    with pytest.raises(ValueError, match="architecture"):
        main(_tiny_train_config(tmp_path, steps=3))  # TINY has the branch
    main(_tiny_train_config(tmp_path, steps=3, model=plain))
    assert latest_checkpoint(tmp_path / "ckpt").name.endswith("0000003")


def test_resume_refuses_a_different_architecture(tmp_path):
    main(_tiny_train_config(tmp_path, steps=2))
    other = EstimatorModelConfig(base_channels=4, channel_mults=(1, 2, 4), adapter_width=4, norm_groups=4)
    with pytest.raises(ValueError, match="architecture"):
        main(_tiny_train_config(tmp_path, steps=3, model=other))


def test_parse_args_builds_the_dataclass():
    cfg = parse_args(
        [
            "--steps",
            "7",
            "--size",
            "48",
            "--no-resume",
            "--num-threads",
            "1",
            "--model.base-channels",
            "8",
            "--model.channel-mults",
            "1,2,4",
        ]
    )
    assert cfg.steps == 7 and cfg.size == 48 and cfg.resume is False and cfg.num_threads == 1
    assert cfg.model.base_channels == 8 and cfg.model.channel_mults == (1, 2, 4)
    assert cfg.source_size == 96
    # The default architecture is the model's own (its signature is the only copy), with
    # what a new run builds on top (TRAINING_DEFAULTS: the shading branch).
    assert parse_args([]).model == config_of(EstimatorModelConfig, SVBRDFEstimator(**TRAINING_DEFAULTS))
    assert TRAINING_DEFAULTS == {"shading_channels": 16}


def test_init_from_starts_at_the_saved_weights(tmp_path):
    # steps=1 with lr=0: the exported model must equal the one it started from.
    source = main(_tiny_train_config(tmp_path / "a", steps=2))
    started = main(_tiny_train_config(tmp_path / "b", steps=1, lr=0.0, init_from=str(source)))
    a = load_file(str(next(source.glob("*.safetensors"))))
    b = load_file(str(next(started.glob("*.safetensors"))))
    assert a.keys() == b.keys()
    for k in a:
        torch.testing.assert_close(a[k], b[k], atol=0, rtol=0, msg=k)


def test_init_from_grows_the_shading_branch(tmp_path, random_views):
    """A model saved without the shading branch starts a run with one: every saved weight
    is copied and the zero-initialised shading head leaves the output unchanged."""
    plain = dataclasses.replace(TINY, shading_channels=0)
    source = main(_tiny_train_config(tmp_path / "a", steps=1, model=plain))
    grown = main(_tiny_train_config(tmp_path / "b", steps=1, lr=0.0, init_from=str(source)))
    a = SVBRDFEstimator.from_pretrained(source).eval()
    b = SVBRDFEstimator.from_pretrained(grown).eval()
    assert config_of(EstimatorModelConfig, b) == TINY and config_of(EstimatorModelConfig, a) == plain
    images, light, camera = random_views(1, 3, seed=2)
    with torch.no_grad():
        torch.testing.assert_close(b(images, light, camera).stacked(), a(images, light, camera).stacked())
    # Only "no branch -> branch" grows; other differences are still refused.
    wider = dataclasses.replace(TINY, shading_channels=8)
    with pytest.raises(ValueError, match="architecture"):
        main(_tiny_train_config(tmp_path / "c", steps=1, model=wider, init_from=str(grown)))


def test_init_from_refuses_a_missing_folder_or_another_architecture(tmp_path):
    with pytest.raises(FileNotFoundError, match="init_from"):
        main(_tiny_train_config(tmp_path / "x", steps=1, init_from=str(tmp_path / "nowhere")))
    source = main(_tiny_train_config(tmp_path / "a", steps=1))
    other = EstimatorModelConfig(base_channels=4, channel_mults=(1, 2, 4), adapter_width=4, norm_groups=4)
    with pytest.raises(ValueError, match="architecture"):
        main(_tiny_train_config(tmp_path / "b", steps=1, model=other, init_from=str(source)))


def test_init_from_refuses_to_resume_another_run(tmp_path):
    source = main(_tiny_train_config(tmp_path / "a", steps=1))
    main(_tiny_train_config(tmp_path / "b", steps=1))  # a checkpoint without init_from
    with pytest.raises(ValueError, match="fresh --ckpt-dir"):
        main(_tiny_train_config(tmp_path / "b", steps=2, init_from=str(source)))
    # The same fine-tuning run resumes normally.
    main(_tiny_train_config(tmp_path / "c", steps=1, init_from=str(source)))
    main(_tiny_train_config(tmp_path / "c", steps=2, init_from=str(source)))
    assert latest_checkpoint(tmp_path / "c" / "ckpt").name.endswith("0000002")


def test_normal_weight_scales_only_the_normal_term():
    g = torch.Generator().manual_seed(0)
    maps = lambda: Material.from_stacked(torch.rand(2, 10, 8, 8, generator=g))  # noqa: E731
    pred, target = maps(), maps()
    one = estimator_loss(pred, target, render_weight=0.0, normal_loss="l1")
    three = estimator_loss(pred, target, render_weight=0.0, normal_weight=3.0, normal_loss="l1")
    torch.testing.assert_close(three["map"] - one["map"], 2.0 * one["normal"])
    torch.testing.assert_close(three["normal"], one["normal"])


def test_normal_mse_replaces_only_the_normal_term():
    g = torch.Generator().manual_seed(1)
    maps = lambda: Material.from_stacked(torch.rand(2, 10, 8, 8, generator=g))  # noqa: E731
    pred, target = maps(), maps()
    l1 = estimator_loss(pred, target, render_weight=0.0, normal_weight=2.0, normal_loss="l1")
    mse = estimator_loss(pred, target, render_weight=0.0, normal_weight=2.0)  # the default
    expected_mse = ((pred.normal - target.normal) ** 2).mean()
    torch.testing.assert_close(mse["normal_mse"], expected_mse)
    torch.testing.assert_close(mse["map"] - l1["map"], 2.0 * (NORMAL_MSE_SCALE * expected_mse - l1["normal"]))
    for name in ("diffuse", "normal", "roughness", "specular"):  # the logged L1s are unchanged
        torch.testing.assert_close(mse[name], l1[name])
    with pytest.raises(ValueError, match="normal_loss"):
        estimator_loss(pred, target, normal_loss="l2")
    with pytest.raises(ValueError, match="normal_loss"):
        TrainConfig(normal_loss="huber")
    assert parse_args(["--normal-loss", "l1"]).normal_loss == "l1" and parse_args([]).normal_loss == "mse"


def test_normal_mse_does_not_settle_on_the_flat_median():
    """Why ``normal_loss="mse"``: for sparse relief (here 80% flat pixels, 20% tilted by 0.3)
    and no per-pixel evidence, the L1-optimal guess is the median (flat) and the
    MSE-optimal one the mean (0.06), which is what the evaluation's normal MSE rewards."""

    def unit(slope_x: torch.Tensor) -> torch.Tensor:  # [P] x-slopes -> [1, 3, 1, P] unit normals
        normal = torch.stack([slope_x, torch.zeros_like(slope_x), torch.ones_like(slope_x)])
        return F.normalize(normal[None, :, None], dim=1)

    tilt = torch.zeros(1000)
    tilt[:200] = 0.3
    zeros = lambda c: torch.zeros(1, c, 1, 1000)  # noqa: E731
    target = Material(zeros(3), unit(tilt), zeros(1), zeros(3))
    found = {}
    for loss_name in ("l1", "mse"):
        guess = torch.zeros(1, requires_grad=True)  # one shared x-slope for every pixel
        opt = torch.optim.Adam([guess], lr=1e-2)
        sched = torch.optim.lr_scheduler.MultiStepLR(opt, [200], gamma=0.1)
        for _ in range(400):
            pred = Material(target.diffuse, unit(guess).expand_as(target.normal), target.roughness, target.specular)
            loss = estimator_loss(pred, target, render_weight=0.0, normal_loss=loss_name)["loss"]
            opt.zero_grad()
            loss.backward()
            opt.step()
            sched.step()
        found[loss_name] = float(guess.detach())
    assert abs(found["l1"]) < MEDIAN_TOLERANCE
    assert abs(found["mse"] - 0.2 * 0.3) < MEDIAN_TOLERANCE


def _texture_folders(root, names, size: int = 48):
    """Texture material folders named ``names`` under ``root``, made from procedural
    materials; returns ``root``."""
    for k, name in enumerate(names):
        save_texture_folder(root / name, generate(100 + k, size=size))
    return root


def test_paper_domain_is_the_rendered_groups_stream(tmp_path):
    """``--domain paper`` (the default) trains on exactly the data of every earlier run."""
    cfg = _tiny_train_config(tmp_path)
    assert cfg.domain == "paper" and parse_args([]).domain == "paper"
    data = training_data(cfg)
    assert type(data) is RenderedGroups
    reference = RenderedGroups(TRAIN_SEEDS, GroupConfig(size=32, views=4, source_size=64, seed=0))
    for i in (0, 7):
        a, b = data[i], reference[i]
        assert a.keys() == b.keys()
        for key in ("images", "light_pos", "camera_pos", "maps"):
            assert torch.equal(a[key], b[key]), key


def test_capture_domain_data_uses_only_the_training_textures(tmp_path):
    root = _texture_folders(tmp_path / "tex", (*REAL_DEV_TRAIN, *REAL_DEV_VALIDATION), size=40)
    cfg = _tiny_train_config(tmp_path, domain="capture", textures=str(root), p_texture=0.5, p_mix=0.3)
    data = training_data(cfg)
    assert type(data) is DomainGroups
    assert data.texture_names == list(REAL_DEV_TRAIN)  # the validation materials stay out
    assert (data.p_texture, data.p_mix) == (0.5, 0.3)
    assert data.config == cfg.group_config()
    assert type(training_data(_tiny_train_config(tmp_path, domain="capture"))) is DomainGroups
    with pytest.raises(FileNotFoundError, match="training materials"):
        training_data(_tiny_train_config(tmp_path, domain="capture", textures=str(tmp_path / "nowhere")))
    with pytest.raises(ValueError, match="domain"):
        TrainConfig(domain="photos")
    with pytest.raises(ValueError, match="capture"):
        TrainConfig(textures=str(root))  # textures only mean something in the capture domain
    with pytest.raises(ValueError, match="p_mix"):
        TrainConfig(domain="capture", p_mix=1.5)
    cli = parse_args(["--domain", "capture", "--textures", str(root), "--p-texture", "0.25", "--p-mix", "0.2"])
    assert (cli.domain, cli.textures, cli.p_texture, cli.p_mix) == ("capture", str(root), 0.25, 0.2)


def test_capture_domain_trains_and_resumes_exactly(tmp_path):
    root = _texture_folders(tmp_path / "tex", REAL_DEV_TRAIN, size=40)
    capture = dict(domain="capture", textures=str(root), p_texture=0.5, p_mix=0.5)
    straight = main(_tiny_train_config(tmp_path / "a", steps=2, ckpt_every=1, **capture))
    main(_tiny_train_config(tmp_path / "b", steps=1, ckpt_every=1, **capture))
    resumed = main(_tiny_train_config(tmp_path / "b", steps=2, ckpt_every=1, **capture))
    a = load_file(str(next(straight.glob("*.safetensors"))))
    b = load_file(str(next(resumed.glob("*.safetensors"))))
    for k in a:
        torch.testing.assert_close(a[k], b[k], atol=0, rtol=0, msg=k)
    paper = load_file(str(next(main(_tiny_train_config(tmp_path / "p", steps=2)).glob("*.safetensors"))))
    assert any(not torch.equal(a[k], paper[k]) for k in a)  # the data did change
    # A checkpoint resumes only with the data it was trained on.
    with pytest.raises(ValueError, match="domain"):
        main(_tiny_train_config(tmp_path / "b", steps=3))
    with pytest.raises(ValueError, match="p_mix"):
        main(_tiny_train_config(tmp_path / "b", steps=3, **{**capture, "p_mix": 0.1}))


def test_relit_pool_data_and_flags(tmp_path):
    from materials.relit_pool import RelitMixedGroups, write_relit_pool

    pool_cfg = GroupConfig(size=32, views=4, source_size=64, seed=0)
    relit = torch.rand(2, 3, 3, 32, 32, generator=torch.Generator().manual_seed(1))
    pool = write_relit_pool(tmp_path / "pool.safetensors", torch.arange(2), relit, pool_cfg, {"relighter": "test"})
    cfg = _tiny_train_config(tmp_path, relit_pool=str(pool), p_relit=1.0)
    data = training_data(cfg)
    assert type(data) is RelitMixedGroups and data.p_relit == 1.0
    torch.testing.assert_close(data[1]["images"][1:], relit[1], atol=2.0**-11, rtol=0)
    # The pool must match the run's size and views.
    with pytest.raises(ValueError, match="views"):
        training_data(_tiny_train_config(tmp_path, relit_pool=str(pool), max_views=3))
    with pytest.raises(ValueError, match="p_relit"):
        TrainConfig(p_relit=2.0)
    cli = parse_args(["--relit-pool", str(pool), "--p-relit", "0.3"])
    assert (cli.relit_pool, cli.p_relit) == (str(pool), 0.3)
    # It trains, and a checkpoint resumes only with the same pool setting.
    main(_tiny_train_config(tmp_path / "r", steps=1, ckpt_every=1, relit_pool=str(pool), p_relit=0.5))
    with pytest.raises(ValueError, match="p_relit"):
        main(_tiny_train_config(tmp_path / "r", steps=2, relit_pool=str(pool), p_relit=0.2))


def test_relit_pool_mixes_with_the_capture_domain_and_marks_generated_views(tmp_path):
    # Relit items (the pool's paper groups) and capture-domain items batch together: both
    # are cut to the pool's keys. The relit items' views 1.. are the ones marked generated.
    from estimator.train import generated_views
    from materials.relit_pool import ITEM_KEYS, RelitMixedGroups, write_relit_pool

    pool_cfg = GroupConfig(size=32, views=4, source_size=64, seed=0)
    relit = torch.rand(2, 3, 3, 32, 32, generator=torch.Generator().manual_seed(1))
    pool = write_relit_pool(tmp_path / "pool.safetensors", torch.arange(2), relit, pool_cfg, {"relighter": "test"})
    cfg = _tiny_train_config(tmp_path, domain="capture", relit_pool=str(pool), p_relit=0.5)
    data = training_data(cfg)
    assert type(data) is RelitMixedGroups and type(data.base) is DomainGroups
    items = [data[i] for i in range(8)]
    kinds = {bool(item["relit"]) for item in items}
    assert kinds == {True, False}  # both kinds in 8 draws at p = 0.5 for this seed
    for i, item in enumerate(items):
        assert set(item) == {*ITEM_KEYS, "relit"}
        if not item["relit"]:
            assert torch.equal(item["images"], data.base[i]["images"])  # the capture stream's own item
    batch = torch.utils.data.default_collate(items)
    flags = generated_views(batch, [0, 2, 3])
    assert flags.shape == (8, 3) and not bool(flags[:, 0].any())
    assert torch.equal(flags[:, 1], batch["relit"]) and torch.equal(flags[:, 2], batch["relit"])
    assert not bool(generated_views({"images": batch["images"]}, [0, 1]).any())
    # One step of a flagged model on that mix.
    main(
        _tiny_train_config(
            tmp_path / "g",
            steps=1,
            ckpt_every=1,
            domain="capture",
            relit_pool=str(pool),
            model=dataclasses.replace(TINY, generated_flag=True),
        )
    )


def test_init_from_grows_the_generated_flag_without_changing_the_output(tmp_path):
    source = SVBRDFEstimator(**dataclasses.asdict(TINY))
    source.save_pretrained(tmp_path / "src")
    flagged = dataclasses.replace(TINY, generated_flag=True)
    cfg = _tiny_train_config(tmp_path, init_from=str(tmp_path / "src"), model=flagged)
    model = SVBRDFEstimator(**dataclasses.asdict(flagged))
    _load_initial_weights(model, cfg)
    images = torch.rand(1, 3, 3, 32, 32, generator=torch.Generator().manual_seed(2))
    lights = torch.tensor([[0.0, 0.0, 4.0], [2.0, 1.0, 5.0], [-1.0, 2.0, 4.0]])
    camera = torch.tensor([0.0, 0.0, 4.0]).expand(3, 3)
    marks = torch.tensor([False, True, True])
    with torch.no_grad():
        a, b = source(images, lights, camera), model(images, lights, camera, generated=marks)
    for name, t in a.maps().items():
        assert torch.equal(t, b.maps()[name]), name
    # The flag is part of the architecture: a flagged source does not start an unflagged run.
    model.save_pretrained(tmp_path / "flagged")
    with pytest.raises(ValueError, match="architecture"):
        _load_initial_weights(
            SVBRDFEstimator(**dataclasses.asdict(TINY)),
            _tiny_train_config(tmp_path, init_from=str(tmp_path / "flagged")),
        )


def test_camera_height_sets_the_capture_items_heights(tmp_path):
    # View 0's camera height of capture items (p_paper 0): never below the range's low end
    # (a crop only raises it: the window is rescaled to the plane's side), and the
    # default range reaches lower. The range also survives the checkpoint's JSON.
    def heights(**kw) -> torch.Tensor:
        data = training_data(_tiny_train_config(tmp_path, domain="capture", **kw))
        return torch.stack([data[i]["camera_pos"][0, 2] for i in range(32)])

    far = heights(camera_height=(6.0, 13.0))
    assert far.min() >= 6.0 - 1e-4
    assert heights().min() < 6.0
    assert parse_args(["--domain", "capture", "--camera-height", "6,13"]).camera_height == (6.0, 13.0)
    with pytest.raises(ValueError, match="camera_height"):
        TrainConfig(camera_height=(6.0, 13.0))  # the paper's data has its own heights
    with pytest.raises(ValueError, match="camera_height"):
        TrainConfig(domain="capture", camera_height=(6.0,))
    far_run = dict(domain="capture", camera_height=(6.0, 13.0))
    main(_tiny_train_config(tmp_path / "r", steps=1, ckpt_every=1, **far_run))
    main(_tiny_train_config(tmp_path / "r", steps=2, ckpt_every=1, **far_run))  # resumes: same data
    with pytest.raises(ValueError, match="camera_height"):
        main(_tiny_train_config(tmp_path / "r", steps=3, domain="capture"))
