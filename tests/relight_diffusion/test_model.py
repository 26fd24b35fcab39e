"""The relighting diffusion model: injection at init, persistence, overfitting, pipeline."""

import pytest
import torch
from accelerate.utils import set_seed

from relight.diffusion import RelightDiffusion, RelightPipeline, make_sample_scheduler, make_train_scheduler
from relight.diffusion.objective import diffusion_loss, pure_noise_velocity
from relight.modules import shuffle_within_groups
from relight.modules.ip_attention import decoupled_processors


def _inputs(model, n=3, seed=0):
    gen = torch.Generator().manual_seed(seed)
    res = model.config.resolution
    photo = torch.rand(n, 3, res, res, generator=gen)
    light = torch.tensor([[1.0, -1.0, 5.0]]).repeat(n, 1)
    camera = torch.tensor([[0.0, 0.0, 4.0]]).repeat(n, 1)
    x = torch.randn(n, 3, res, res, generator=gen)
    t = torch.tensor([10, 500, 900][:n])
    return photo, light, camera, x, t


def test_zero_initialised_injection_leaves_unet_unchanged(tiny_model):
    photo, light, camera, x, t = _inputs(tiny_model)
    with torch.no_grad():
        cond = tiny_model.encode_condition(photo, photo, light, camera)
        with_control = tiny_model.denoise(x, t, *cond)
        plain = tiny_model.unet(tiny_model.unet_input(x, cond.base_x), t, encoder_hidden_states=cond.states).sample
    assert torch.equal(with_control, plain)


def test_light_tokens_enter_once_value_projection_moves(tiny_model):
    photo, light, camera, x, t = _inputs(tiny_model)
    other = light.clone()
    other[:, 0] = -3.0
    with torch.no_grad():
        _, s1, base_x = tiny_model.encode_condition(photo, photo, light, camera)
        _, s2, _ = tiny_model.encode_condition(photo, photo, other, camera)
        x_in = tiny_model.unet_input(x, base_x)
        assert torch.equal(
            tiny_model.unet(x_in, t, encoder_hidden_states=s1).sample,
            tiny_model.unet(x_in, t, encoder_hidden_states=s2).sample,
        )
        for p in decoupled_processors(tiny_model.unet):
            torch.nn.init.normal_(p.to_v_ip.weight, std=0.5)
        assert not torch.allclose(
            tiny_model.unet(x_in, t, encoder_hidden_states=s1).sample,
            tiny_model.unet(x_in, t, encoder_hidden_states=s2).sample,
        )


def test_save_load_round_trip(tiny_model, tmp_path):
    with torch.no_grad():
        for p in tiny_model.parameters():  # move every weight, the zero-initialised ones too
            p.add_(0.01 * torch.randn_like(p))
    tiny_model.save_pretrained(tmp_path / "ckpt")
    loaded = RelightDiffusion.from_pretrained(tmp_path / "ckpt")
    assert len(decoupled_processors(loaded.unet)) == len(decoupled_processors(tiny_model.unet)) > 0
    photo, light, camera, x, t = _inputs(tiny_model)
    with torch.no_grad():
        a = tiny_model.denoise(x, t, *tiny_model.encode_condition(photo, photo, light, camera))
        b = loaded.denoise(x, t, *loaded.encode_condition(photo, photo, light, camera))
    assert torch.equal(a, b)
    assert {p.name for p in (tmp_path / "ckpt").iterdir()} == {"config.json", "diffusion_pytorch_model.safetensors"}
    _, info = RelightDiffusion.from_pretrained(tmp_path / "ckpt", output_loading_info=True)
    assert not info["missing_keys"] and not info["unexpected_keys"] and not info["mismatched_keys"]
    with pytest.raises(OSError, match="config.json"):
        RelightDiffusion.from_pretrained(tmp_path)


@pytest.mark.parametrize("change", ["drop", "add", "reshape"])
def test_from_pretrained_refuses_a_partial_load(tiny_model, tmp_path, change):
    # diffusers alone only warns on an unexpected key and leaves a missing one on the meta
    # device; the model's from_pretrained must refuse both, and a shape mismatch.
    from safetensors.torch import load_file, save_file

    from relight.diffusion.model import WEIGHTS_NAME

    tiny_model.save_pretrained(tmp_path)
    state = load_file(str(tmp_path / WEIGHTS_NAME))
    key = next(k for k in state if ".processor.to_k_ip" in k)
    if change == "drop":
        del state[key]
    elif change == "add":
        state["unet.extra.weight"] = torch.zeros(2)
    else:
        state[key] = torch.zeros(3, 5)
    save_file(state, str(tmp_path / WEIGHTS_NAME), metadata={"format": "pt"})
    kind = {"drop": "missing", "add": "unexpected", "reshape": "size mismatch|mismatched"}[change]
    with pytest.raises((ValueError, RuntimeError), match=kind):
        RelightDiffusion.from_pretrained(tmp_path)


def test_few_steps_overfit_a_fixed_batch(tiny_model, group_batch):
    set_seed(0)
    batch = group_batch(b=1, v=4)
    scheduler = make_train_scheduler()
    opt = torch.optim.AdamW(tiny_model.parameters(), lr=3e-3)
    tiny_model.train()
    losses = []
    for _ in range(40):
        # the same noise and timesteps every step: a fixed objective to overfit
        loss = diffusion_loss(tiny_model, scheduler, batch, torch.Generator().manual_seed(0))
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(float(loss.detach()))
    assert losses[-1] < 0.5 * losses[0], losses


def test_pipeline_deterministic_and_checked(tiny_model):
    pipe = RelightPipeline(tiny_model)
    photo = torch.rand(3, 16, 16)
    light_pos = torch.tensor([[1.0, 1.0, 4.0], [-2.0, 0.5, 6.0]])
    camera_pos = torch.tensor([0.0, 0.0, 4.0])

    def run():
        return pipe(
            photo,
            light_pos,
            camera_pos,
            num_inference_steps=3,
            generator=torch.Generator().manual_seed(3),
            progress=False,
            num_samples=2,
        )

    a, b = run(), run()
    assert a.shape == (2, 3, 16, 16) and torch.equal(a, b) and (a >= 0).all()
    with pytest.raises(ValueError, match=r"H is 8, but 16 in the model's config"):
        pipe(torch.rand(3, 8, 8), light_pos, camera_pos, progress=False)
    with pytest.raises(ValueError, match=r"photo must have shape \[3, H, W\], got \(4, 16, 16\)"):
        pipe(torch.rand(4, 16, 16), light_pos, camera_pos, progress=False)
    with pytest.raises(ValueError, match="light_pos has a position on or below the material plane"):
        pipe(photo, torch.tensor([[0.0, 0.0, -1.0]]), camera_pos, progress=False)


def test_registered_behind_the_common_interface(tiny_model, tmp_path):
    from relight.interface import get_relighter

    tiny_model.save_pretrained(tmp_path / "m", half=True)
    relighter = get_relighter("diffusion", tmp_path / "m")
    relighter.steps = 2
    photo = torch.rand(2, 3, 16, 16)
    light_pos = torch.tensor([[[1.0, 1.0, 4.0], [-1.0, 2.0, 5.0], [0.0, -2.0, 6.0]]]).repeat(2, 1, 1)
    camera_pos = torch.tensor([[0.0, 0.0, 4.0]]).repeat(2, 1)
    out = relighter.relight(photo, light_pos, camera_pos, generator=torch.Generator().manual_seed(0))
    assert out.shape == (2, 3, 3, 16, 16) and getattr(relighter, "stochastic", False)
    with pytest.raises(FileNotFoundError, match="not a relighting checkpoint"):
        get_relighter("diffusion", tmp_path)  # the command line reports FileNotFoundError
    # float16 storage: loaded weights equal the originals rounded to half precision
    loaded = relighter.pipeline.model
    for (name, a), b in zip(tiny_model.state_dict().items(), loaded.state_dict().values()):
        assert torch.equal(a.half().float(), b), name


def test_residual_space_round_trips_and_photo_enters_the_unet(tiny_model):
    photo, light, camera, x, t = _inputs(tiny_model)
    target = torch.rand_like(photo) * 0.8  # inside the tone map's unclamped range
    base_x = RelightDiffusion.tonemapped(photo)
    x0 = tiny_model.to_model_space(target, base_x)
    assert torch.allclose(x0, (RelightDiffusion.tonemapped(target) - base_x) * tiny_model.config.data_scale)
    assert torch.allclose(tiny_model.to_linear(x0, base_x), target, atol=1e-5)
    assert tiny_model.unet.conv_in.in_channels == 6
    with torch.no_grad():
        a = tiny_model.denoise(x, t, *tiny_model.encode_condition(photo, photo, light, camera))
        b = tiny_model.denoise(x, t, *tiny_model.encode_condition(1 - photo, 1 - photo, light, camera))
    assert not torch.allclose(a, b)  # the photo reaches the output at initialisation


def test_checkpoints_without_the_switches_load_as_plain(tiny_args, tmp_path):
    # A config.json saved before photo_concat, residual, data_scale and base existed has
    # none of them: the constructor's defaults are what such a checkpoint was.
    import json

    for name in ("photo_concat", "residual", "data_scale"):
        del tiny_args[name]
    RelightDiffusion(**tiny_args).save_pretrained(tmp_path)
    config = json.loads((tmp_path / "config.json").read_text())
    for name in ("photo_concat", "residual", "data_scale", "base"):
        del config[name]
    (tmp_path / "config.json").write_text(json.dumps(config))
    model = RelightDiffusion.from_pretrained(tmp_path)
    assert not model.config.photo_concat and not model.config.residual and model.config.data_scale == 1.0
    assert model.config.base == "photo" and model.unet.conv_in.in_channels == 3
    target = torch.rand(1, 3, 8, 8) * 0.8
    assert torch.allclose(model.to_linear(model.to_model_space(target, None), None), target, atol=1e-5)


def test_lambertian_base_is_the_lambertian_baseline_and_round_trips(tiny_args):
    from relight.interface import get_relighter

    model = RelightDiffusion(**tiny_args, base="lambertian")
    photo, light, camera, x, t = _inputs(model)
    expected = get_relighter("lambertian").relight(photo, light[:, None], camera)[:, 0]
    base_x = model.residual_base(photo, light, camera)
    torch.testing.assert_close(base_x, RelightDiffusion.tonemapped(expected))
    with torch.no_grad():
        cond = model.encode_condition(photo, photo, light, camera)
    torch.testing.assert_close(cond.base_x, base_x)
    target = torch.rand_like(photo) * 0.8
    torch.testing.assert_close(model.to_linear(model.to_model_space(target, base_x), base_x), target, atol=1e-5, rtol=0)
    # The photo-based default differs wherever the light is not at the camera.
    assert not torch.allclose(base_x, RelightDiffusion.tonemapped(photo))


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        (dict(base="phong"), "base: unknown base 'phong'"),
        (dict(preset="sd21", sd21_path="/nowhere", base="lambertian"), "base 'lambertian' needs the tiny preset"),
        (dict(preset="sdxl"), "preset: unknown preset 'sdxl'"),
        (dict(ablation="wo_everything"), "ablation: unknown ablation"),
        (dict(resolution=20), "resolution must be a multiple of 8"),
        (dict(data_scale=0.0), "data_scale must be positive"),
    ],
)
def test_bad_arguments_are_named(kwargs, message):
    with pytest.raises(ValueError, match=message):
        RelightDiffusion(**kwargs)


def test_pipeline_saves_and_loads_its_scheduler(tiny_model, tmp_path):
    from diffusers import DDIMScheduler

    from relight.diffusion.pipeline import SCHEDULER_CONFIG_NAME

    tiny_model.save_pretrained(tmp_path / "model_only")
    default = RelightPipeline.from_pretrained(tmp_path / "model_only")
    assert default.scheduler.config == make_sample_scheduler().config  # no file: the default
    scheduler = DDIMScheduler.from_config(make_sample_scheduler().config, timestep_spacing="leading")
    RelightPipeline(tiny_model, scheduler).save_pretrained(tmp_path / "pipe")
    assert (tmp_path / "pipe" / SCHEDULER_CONFIG_NAME).is_file()
    loaded = RelightPipeline.from_pretrained(tmp_path / "pipe")
    assert loaded.scheduler.config.timestep_spacing == "leading"
    public = lambda config: {k: v for k, v in config.items() if not k.startswith("_")}  # noqa: E731
    assert public(loaded.scheduler.config) == public(scheduler.config)


def test_objective_and_condition_use_the_same_residual_base(tiny_model, group_batch, monkeypatch):
    # The training target x0 (objective) and the UNet's extra channels (encode_condition)
    # must be relative to the same base, computed once per step from the group's photo
    # and each target's light and camera.
    calls, bases, seen = [], [], []
    original_base, original_denoise = tiny_model.residual_base, tiny_model.denoise

    def spy_base(photo, light, camera):
        calls.append((photo.clone(), light.clone(), camera.clone()))
        bases.append(original_base(photo, light, camera))
        return bases[-1]

    def spy_denoise(x_t, t, feats, states, base_x):
        seen.append(base_x)
        return original_denoise(x_t, t, feats, states, base_x)

    monkeypatch.setattr(tiny_model, "residual_base", spy_base)
    monkeypatch.setattr(tiny_model, "denoise", spy_denoise)
    batch = group_batch(b=1, v=4)
    diffusion_loss(tiny_model, make_train_scheduler(), batch, generator=torch.Generator().manual_seed(0))
    assert len(calls) == 1 and len(seen) == 1
    assert seen[0] is bases[0]
    photo, light, camera = calls[0]
    assert torch.equal(photo, batch["images"][:, :1].expand(-1, 4, -1, -1, -1).flatten(0, 1))
    assert torch.equal(light, batch["light_pos"].flatten(0, 1))
    assert torch.equal(camera, batch["camera_pos"].flatten(0, 1))
    # the condition computes the same base itself when none is given (inference)
    assert torch.equal(tiny_model.encode_condition(photo, photo, light, camera).base_x, bases[0])


@pytest.fixture
def pipeline_calls(monkeypatch):
    """``(num_inference_steps, num_samples)`` of every ``RelightPipeline`` call, in order."""
    from relight.diffusion.pipeline import RelightPipeline

    calls = []
    real_call = RelightPipeline.__call__

    def spy(self, *args, **kwargs):
        calls.append((kwargs["num_inference_steps"], kwargs["num_samples"]))
        return real_call(self, *args, **kwargs)

    monkeypatch.setattr(RelightPipeline, "__call__", spy)
    return calls


def test_sampling_options_reach_the_pipeline(tiny_model, tmp_path, capsys, pipeline_calls):
    """``relight generate --steps --samples`` and ``relight eval relighting --steps`` reach
    ``RelightPipeline.__call__`` and are recorded; refused for methods that do not
    sample, and below 1."""
    import json

    import numpy as np

    from matcap.cli import main
    from materials.io import write_exr

    calls = pipeline_calls
    tiny_model.save_pretrained(tmp_path / "m")
    photo = tmp_path / "photo.exr"
    # 64 px: read_photo's smallest side; generate area-downsamples it to the model's size.
    write_exr(photo, np.random.default_rng(0).random((64, 64, 3)).astype(np.float32))
    base = ["generate", str(photo), "--light", "1,1,4", "--out"]
    diffusion = ["--model", "diffusion", "--checkpoint", str(tmp_path / "m")]
    assert main([*base, str(tmp_path / "a"), *diffusion, "--steps", "2", "--samples", "3"]) == 0
    assert calls == [(2, 3)]
    info = json.loads((tmp_path / "a" / "relit.json").read_text())
    assert (info["steps"], info["samples"]) == (2, 3)
    assert main([*base, str(tmp_path / "b"), "--model", "lambertian", "--samples", "2"]) == 2
    assert "applies to sampling methods" in capsys.readouterr().err
    assert main([*base, str(tmp_path / "c"), *diffusion, "--steps", "0"]) == 2
    assert "--steps must be at least 1" in capsys.readouterr().err
    assert not (tmp_path / "b").exists() and not (tmp_path / "c").exists()

    calls.clear()
    ev = ["eval", "relighting", "--count", "1", "--size", "16", "--out"]
    assert (
        main(
            [
                *ev,
                str(tmp_path / "e"),
                "--methods",
                "lambertian,diffusion",
                "--checkpoint",
                f"diffusion={tmp_path / 'm'}",
                "--steps",
                "2",
            ]
        )
        == 0
    )
    assert calls and all(steps == 2 for steps, _ in calls)
    rows = {r["method"]: r for r in json.loads((tmp_path / "e" / "relight_eval.json").read_text())["rows"]}
    assert rows["diffusion"]["sampling_steps"] == 2 and "sampling_steps" not in rows["lambertian"]
    assert "diffusion: 2 sampling steps" in (tmp_path / "e" / "relight_eval.md").read_text()
    assert main([*ev, str(tmp_path / "f"), "--methods", "lambertian", "--steps", "2"]) == 2
    assert "none of lambertian samples" in capsys.readouterr().err
    assert main([*ev, str(tmp_path / "g"), "--methods", "lambertian", "--steps", "0"]) == 2
    assert "--steps must be at least 1" in capsys.readouterr().err


def test_eval_compares_several_step_counts_in_one_run(tiny_model, tmp_path, capsys, pipeline_calls):
    """``relight eval relighting --steps 2,1``: one row per setting, each sampled with its own
    step count; a bad list is refused before any model is loaded."""
    import json

    from matcap.cli import main

    tiny_model.save_pretrained(tmp_path / "m")
    ev = [
        "eval",
        "relighting",
        "--count",
        "1",
        "--size",
        "16",
        "--methods",
        "lambertian,diffusion",
        "--checkpoint",
        f"diffusion={tmp_path / 'm'}",
        "--out",
    ]
    assert main([*ev, str(tmp_path / "e"), "--steps", "2,1", "--samples", "2"]) == 0
    calls = [steps for steps, _ in pipeline_calls]
    assert sorted(set(calls)) == [1, 2] and calls.count(1) == calls.count(2)
    rows = {r["method"]: r for r in json.loads((tmp_path / "e" / "relight_eval.json").read_text())["rows"]}
    assert set(rows) == {
        "lambertian",
        "diffusion (2 steps)",
        "diffusion (2 steps) (mean of 2)",
        "diffusion (1 step)",
        "diffusion (1 step) (mean of 2)",
    }
    assert rows["diffusion (2 steps)"]["sampling_steps"] == 2 and rows["diffusion (1 step)"]["sampling_steps"] == 1
    for bad, message in (("2,2", "repeats"), ("2,x", "comma-separated"), ("3,0", "at least 1")):
        assert main([*ev, str(tmp_path / "bad"), "--steps", bad]) == 2
        assert message in capsys.readouterr().err
    assert not (tmp_path / "bad").exists()


@pytest.fixture
def denoise_inputs(tiny_model, monkeypatch):
    """``(x_t, t)`` of every ``tiny_model.denoise`` call, in order."""
    calls = []
    original = tiny_model.denoise

    def spy(x_t, t, *rest):
        calls.append((x_t.clone(), t.clone()))
        return original(x_t, t, *rest)

    monkeypatch.setattr(tiny_model, "denoise", spy)
    return calls


@pytest.mark.parametrize("fraction", [0.0, 0.5, 1.0])
def test_terminal_fraction_sets_that_share_of_timesteps_to_the_last(tiny_model, group_batch, denoise_inputs, fraction):
    # One-step sampling only asks the model at the last timestep; the terminal share
    # trains it there. 0 must leave the uniform draw (and the random stream) unchanged.
    scheduler = make_train_scheduler()
    last = scheduler.config.num_train_timesteps - 1
    batch = group_batch(b=8, v=8, size=tiny_model.config.resolution)  # 64 targets
    diffusion_loss(tiny_model, scheduler, batch, torch.Generator().manual_seed(0), terminal_fraction=fraction)
    diffusion_loss(tiny_model, scheduler, batch, torch.Generator().manual_seed(0))
    (_, with_share), (_, uniform) = denoise_inputs
    at_last = (with_share == last).float().mean().item()
    if fraction == 0.0:
        assert torch.equal(with_share, uniform)
    elif fraction == 1.0:
        assert at_last == 1.0
    else:
        # 64 Bernoulli(0.5) draws: 5 standard deviations either side is [0.19, 0.81]
        assert 0.19 < at_last < 0.81
        kept = with_share != last
        assert torch.equal(with_share[kept], uniform[kept])  # the others keep their uniform draw


def test_pure_noise_velocity_makes_the_one_step_sampler_return_x0():
    gen = torch.Generator().manual_seed(0)
    x0, noise = torch.randn(2, 3, 8, 8, generator=gen), torch.randn(2, 3, 8, 8, generator=gen)
    scheduler = make_sample_scheduler()
    scheduler.set_timesteps(1)
    (t,) = scheduler.timesteps
    v = pure_noise_velocity(x0.double(), noise.double(), scheduler.alphas_cumprod[t].double())
    out = scheduler.step(v, t, noise.double())
    assert torch.allclose(out.pred_original_sample, x0.double(), atol=1e-12)


def test_terminal_targets_start_from_pure_noise(tiny_model, group_batch, denoise_inputs):
    batch = group_batch(b=1, v=4, size=tiny_model.config.resolution)
    diffusion_loss(tiny_model, make_train_scheduler(), batch, torch.Generator().manual_seed(0), terminal_fraction=1.0)
    # the same generator draws the same noise: the permutation first, then the noise
    gen = torch.Generator().manual_seed(0)
    shuffle_within_groups(4, 4, gen)
    ((x_t, _),) = denoise_inputs
    assert torch.equal(x_t, torch.randn(x_t.shape, generator=gen))


def test_clean_views_are_the_targets_and_the_degraded_ones_the_condition(tiny_model, group_batch, monkeypatch):
    # Capture-domain groups (``DomainGroups``) carry the degraded photos in ``images`` and
    # the unclipped views in ``clean``: the model must be conditioned on what a photo
    # gives it (the photo's prior and base, the BCE backgrounds) and asked for ``clean``.
    batch = group_batch(b=1, v=4, size=tiny_model.config.resolution)
    batch["clean"] = batch["images"] * 1.5 + 0.1
    seen_linear, seen_condition = [], []
    original_space, original_condition = tiny_model.to_model_space, tiny_model.encode_condition

    def spy_space(linear, base_x):
        seen_linear.append(linear.clone())
        return original_space(linear, base_x)

    def spy_condition(photo, background, *rest):
        seen_condition.append((photo.clone(), background.clone()))
        return original_condition(photo, background, *rest)

    monkeypatch.setattr(tiny_model, "to_model_space", spy_space)
    monkeypatch.setattr(tiny_model, "encode_condition", spy_condition)
    diffusion_loss(tiny_model, make_train_scheduler(), batch, torch.Generator().manual_seed(0))
    ((photo, background),) = seen_condition
    assert torch.equal(seen_linear[0], batch["clean"].flatten(0, 1))
    assert torch.equal(background, batch["images"].flatten(0, 1))
    assert torch.equal(photo, batch["images"][:, :1].expand(-1, 4, -1, -1, -1).flatten(0, 1))
    # without ``clean`` the renders are both (the paper's data, every earlier run)
    seen_linear.clear()
    del batch["clean"]
    diffusion_loss(tiny_model, make_train_scheduler(), batch, torch.Generator().manual_seed(0))
    assert torch.equal(seen_linear[0], batch["images"].flatten(0, 1))


def test_diffusion_relighter_tiles_photos_larger_than_its_resolution(tiny_model):
    # The model's size is one call, untiled; with large="tiles" a larger square photo is
    # relit in windows (relight.tiling); anything smaller or not square is refused with
    # the reason.
    from relight.diffusion.relighter import DiffusionRelighter

    relighter = DiffusionRelighter(tiny_model, steps=1, overlap=4, large="tiles")  # resolution 16
    gen = lambda: torch.Generator().manual_seed(0)  # noqa: E731
    photo = torch.rand(3, 16, 16, generator=gen()) * 0.5 + 0.1
    light = torch.tensor([[1.0, -1.0, 5.0], [-2.0, 0.5, 4.0]])
    camera = torch.tensor([0.0, 0.0, 4.5])
    native = relighter.relight(photo[None], light[None], camera[None], generator=gen())
    direct = relighter.pipeline(photo, light, camera, num_inference_steps=1, generator=gen(), progress=False)
    torch.testing.assert_close(native[0], direct)
    big = torch.rand(3, 40, 40, generator=gen()) * 0.5 + 0.1
    out = relighter.relight(big[None], light[None], camera[None], generator=gen())
    assert out.shape == (1, 2, 3, 40, 40) and torch.isfinite(out).all()
    for bad in (torch.rand(1, 3, 8, 8), torch.rand(1, 3, 32, 40)):
        with pytest.raises(ValueError, match="at least the model's resolution"):
            relighter.relight(bad, light[None], camera[None])


def test_diffusion_relighter_relights_a_larger_photo_globally_by_default(tiny_model):
    # large="global" (the default): one call on the whole plane area-averaged to the
    # model's side, its residual to the re-shading upsampled onto the full-size
    # re-shading (relight.detail); the same generator gives the same sample.
    import torch.nn.functional as F

    import kernels
    from kernels.presets import get_preset
    from relight.diffusion.relighter import DiffusionRelighter
    from relight.shading import lambertian_relight

    relighter = DiffusionRelighter(tiny_model, steps=1)
    assert relighter.large == "global"
    gen = lambda: torch.Generator().manual_seed(0)  # noqa: E731
    big = torch.rand(1, 3, 48, 48, generator=gen()) * 0.5 + 0.1
    light = torch.tensor([[[1.0, -1.0, 5.0], [-2.0, 0.5, 4.0]]])
    camera = torch.tensor([[0.0, 0.0, 4.5]])
    out = relighter.relight(big, light, camera, generator=gen())
    small = F.adaptive_avg_pool2d(big, 16)
    native = relighter.pipeline(small[0], light[0], camera[0], num_inference_steps=1, generator=gen(), progress=False)
    preset = get_preset("dgrsise")
    tm = kernels.tonemap
    residual = tm(native) - tm(lambertian_relight(small, light, camera, preset)[0])
    up = F.interpolate(residual, size=(48, 48), mode="bilinear", align_corners=False)
    expected = kernels.inverse_tonemap(tm(lambertian_relight(big, light, camera, preset)[0]) + up)
    torch.testing.assert_close(out[0], expected)
    with pytest.raises(ValueError, match="large must be one of"):
        DiffusionRelighter(tiny_model, large="whole")


def test_eval_compares_large_photo_modes_in_one_run(tiny_model, tmp_path, capsys, pipeline_calls):
    """``relight eval relighting --large global,tiles``: one row per mode of each network
    relighter, recorded in the row; the global mode calls the model once per photo, at its
    own size; a bad list is refused (an unknown mode before any model is loaded, a mode no
    method takes once they are), with nothing written."""
    import json

    from matcap.cli import main

    tiny_model.save_pretrained(tmp_path / "m")
    ev = ["eval", "relighting", "--count", "1", "--size", "32", "--methods", "lambertian,diffusion"]
    ev += ["--checkpoint", f"diffusion={tmp_path / 'm'}", "--steps", "1", "--out"]
    assert main([*ev, str(tmp_path / "e"), "--large", "global"]) == 0
    assert len(pipeline_calls) == 1  # one photo, its 7 lights in one call at 16 px
    rows = {r["method"]: r for r in json.loads((tmp_path / "e" / "relight_eval.json").read_text())["rows"]}
    assert set(rows) == {"lambertian", "diffusion"} and rows["diffusion"]["large"] == "global"
    assert "large" not in rows["lambertian"]
    for bad, message in (("global,global", "each once"), ("nosuch", "not one of"), ("whole", "none of")):
        assert main([*ev, str(tmp_path / "bad"), "--large", bad]) == 2
        assert message in capsys.readouterr().err
    assert not (tmp_path / "bad").exists()
