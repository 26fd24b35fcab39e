"""The sd21 preset, on a randomly initialised miniature of Stable Diffusion 2.1's layout
(real weights cannot be fetched here): the same classes and folder structure, tiny sizes."""

import json
import string

import pytest
import torch
from safetensors.torch import load_file

from relight.diffusion import RelightDiffusion, RelightPipeline, make_train_scheduler
from relight.diffusion.model import WEIGHTS_NAME
from relight.diffusion.objective import diffusion_loss
from relight.modules.ip_attention import decoupled_processors

pytest.importorskip("transformers")

#: Text width = the UNet's cross-attention width, as in SD 2.1 (1024 there).
TEXT_DIM = 16


def _write_tokenizer(folder):
    from transformers import CLIPTokenizer

    folder.mkdir(parents=True)
    vocab = {c: i for i, c in enumerate(string.ascii_lowercase)}
    vocab.update({c + "</w>": len(vocab) + i for i, c in enumerate(string.ascii_lowercase)})
    for special in ("<|startoftext|>", "<|endoftext|>"):
        vocab[special] = len(vocab)
    (folder / "vocab.json").write_text(json.dumps(vocab))
    (folder / "merges.txt").write_text("#version: 0.2\n")
    CLIPTokenizer(str(folder / "vocab.json"), str(folder / "merges.txt"), model_max_length=77).save_pretrained(folder)
    return len(vocab)


@pytest.fixture(scope="module")
def sd21_folder(tmp_path_factory):
    from diffusers import AutoencoderKL, UNet2DConditionModel
    from transformers import CLIPTextConfig, CLIPTextModel

    root = tmp_path_factory.mktemp("sd21-miniature")
    torch.manual_seed(0)
    vocab_size = _write_tokenizer(root / "tokenizer")
    CLIPTextModel(
        CLIPTextConfig(
            vocab_size=vocab_size,
            hidden_size=TEXT_DIM,
            intermediate_size=32,
            num_hidden_layers=1,
            num_attention_heads=2,
            max_position_embeddings=77,
            projection_dim=TEXT_DIM,
            bos_token_id=vocab_size - 2,
            eos_token_id=vocab_size - 1,
            pad_token_id=vocab_size - 1,
        )
    ).save_pretrained(root / "text_encoder")
    # SD 2.1's UNet traits: 4 latent channels, linear projections in the transformers,
    # cross-attention at every level but the lowest-resolution one, v-prediction.
    UNet2DConditionModel(
        sample_size=8,
        in_channels=4,
        out_channels=4,
        layers_per_block=1,
        block_out_channels=(8, 16),
        down_block_types=("CrossAttnDownBlock2D", "DownBlock2D"),
        up_block_types=("UpBlock2D", "CrossAttnUpBlock2D"),
        cross_attention_dim=TEXT_DIM,
        attention_head_dim=(2, 4),
        use_linear_projection=True,
        norm_num_groups=4,
    ).save_pretrained(root / "unet")
    # A VAE with SD's factor-8 downsampling (four encoder blocks, three of them stride 2).
    AutoencoderKL(
        in_channels=3,
        out_channels=3,
        latent_channels=4,
        layers_per_block=1,
        norm_num_groups=2,
        block_out_channels=(4, 4, 4, 4),
        down_block_types=("DownEncoderBlock2D",) * 4,
        up_block_types=("UpDecoderBlock2D",) * 4,
        sample_size=64,
    ).save_pretrained(root / "vae")
    return root


@pytest.fixture
def sd21_model(sd21_folder):
    torch.manual_seed(0)
    return RelightDiffusion(
        preset="sd21",
        sd21_path=str(sd21_folder),
        resolution=64,
        num_light_tokens=2,
        condition_widths=(4, 4, 4, 4, 8, 8),
    )


def _inputs(n=2, res=64, seed=0):
    gen = torch.Generator().manual_seed(seed)
    photo = torch.rand(n, 3, res, res, generator=gen)
    light = torch.tensor([[1.0, -1.0, 5.0]]).repeat(n, 1)
    camera = torch.tensor([[0.0, 0.0, 4.0]]).repeat(n, 1)
    x = torch.randn(n, 4, res // 8, res // 8, generator=gen)
    return photo, light, camera, x, torch.tensor([10, 700][:n])


def test_frozen_parts_and_shapes(sd21_model):
    m = sd21_model
    assert m.sample_shape == (4, 8, 8) and m.feature_size() == (8, 8)
    assert m.text_embeds.shape == (1, 77, TEXT_DIM) and not m.config.photo_concat and not m.config.residual
    frozen = [n for n, p in m.named_parameters() if not p.requires_grad]
    assert frozen and all(n.startswith(("unet.", "vae.")) and ".processor." not in n for n in frozen)
    assert all(p.requires_grad for p in m.controlnet.parameters())
    assert all(p.requires_grad for proc in decoupled_processors(m.unet) for p in proc.parameters())
    photo, light, camera, x, t = _inputs()
    cond = m.encode_condition(photo, photo, light, camera)
    assert cond.feats.shape == (2, 8, 8, 8) and cond.states.shape == (2, 77 + 2, TEXT_DIM)
    with torch.no_grad():
        v = m.denoise(x, t, *cond)
        plain = m.unet(x, t, encoder_hidden_states=cond.states).sample
    assert v.shape == x.shape and torch.equal(v, plain)  # zero-initialised injection
    x0 = m.to_model_space(photo, cond.base_x)
    assert x0.shape == (2, 4, 8, 8) and m.to_linear(x0, cond.base_x).shape == photo.shape


def test_training_step_moves_only_trainable_parts(sd21_model):
    m = sd21_model
    gen = torch.Generator().manual_seed(1)
    batch = {
        "images": torch.rand(1, 2, 3, 64, 64, generator=gen),
        "light_pos": torch.tensor([[[0.0, 0.0, 4.0], [1.0, 1.0, 5.0]]]),
        "camera_pos": torch.tensor([[[0.0, 0.0, 4.0], [0.0, 0.0, 4.0]]]),
    }
    m.train()
    loss = diffusion_loss(m, make_train_scheduler(), batch, torch.Generator().manual_seed(0))
    loss.backward()
    assert torch.isfinite(loss)
    assert all(p.grad is None for p in m.vae.parameters())
    assert all(p.grad is None for n, p in m.unet.named_parameters() if ".processor." not in n)
    assert any(p.grad is not None and p.grad.abs().sum() > 0 for p in m.controlnet.parameters())


def test_save_load_stores_only_trained_weights(sd21_model, tmp_path):
    m = sd21_model
    with torch.no_grad():
        for p in m.parameters():
            if p.requires_grad:
                p.add_(0.01 * torch.randn_like(p))
    m.save_pretrained(tmp_path / "ckpt")
    keys = load_file(str(tmp_path / "ckpt" / WEIGHTS_NAME)).keys()
    assert not any(k.startswith("vae.") for k in keys)
    assert not any(k.startswith("unet.") and ".processor." not in k for k in keys)
    assert any(k.startswith("unet.") and ".processor." in k for k in keys)
    loaded, info = RelightDiffusion.from_pretrained(tmp_path / "ckpt", output_loading_info=True)
    # the frozen weights are the ones missing from the file, and only they; none unexpected
    assert set(info["missing_keys"]) == {k for k in m.state_dict() if k not in keys}
    assert not info["unexpected_keys"] and not info["mismatched_keys"]
    for name, value in m.state_dict().items():  # frozen ones re-read from sd21_path
        assert torch.equal(loaded.state_dict()[name], value), name
    photo, light, camera, x, t = _inputs()
    with torch.no_grad():
        assert torch.equal(
            m.denoise(x, t, *m.encode_condition(photo, photo, light, camera)),
            loaded.denoise(x, t, *loaded.encode_condition(photo, photo, light, camera)),
        )


def test_pipeline_decodes_to_images(sd21_model):
    pipe = RelightPipeline(sd21_model)
    light_pos = torch.tensor([[1.0, 1.0, 4.0], [-2.0, 0.5, 6.0]])
    out = pipe(
        torch.rand(3, 64, 64),
        light_pos,
        torch.tensor([0.0, 0.0, 4.0]),
        num_inference_steps=2,
        generator=torch.Generator().manual_seed(0),
        progress=False,
    )
    assert out.shape == (2, 3, 64, 64) and torch.isfinite(out).all() and (out >= 0).all()


def test_bad_sd21_settings(tmp_path, sd21_folder):
    with pytest.raises(ValueError, match="needs sd21_path"):
        RelightDiffusion(preset="sd21")
    with pytest.raises(ValueError, match="photo_concat needs a UNet trained from scratch"):
        RelightDiffusion(preset="sd21", sd21_path=str(sd21_folder), photo_concat=True)
    with pytest.raises(FileNotFoundError, match="no such folder"):
        RelightDiffusion(preset="sd21", sd21_path=str(tmp_path / "nowhere"))
    (tmp_path / "partial" / "unet").mkdir(parents=True)
    with pytest.raises(FileNotFoundError, match=r"missing subfolder\(s\) \['vae', 'text_encoder', 'tokenizer'\]"):
        RelightDiffusion(preset="sd21", sd21_path=str(tmp_path / "partial"))


def test_a_missing_trained_weight_is_refused(sd21_model, tmp_path):
    # Only the frozen UNet/VAE weights may be absent from an sd21 checkpoint.
    from safetensors.torch import save_file

    sd21_model.save_pretrained(tmp_path)
    state = load_file(str(tmp_path / WEIGHTS_NAME))
    key = next(k for k in state if k.startswith("unet.") and ".processor." in k)
    del state[key]
    save_file(state, str(tmp_path / WEIGHTS_NAME), metadata={"format": "pt"})
    with pytest.raises(ValueError, match=f"1 missing keys, e.g. \\['{key}'\\]"):
        RelightDiffusion.from_pretrained(tmp_path)
