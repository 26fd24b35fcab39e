"""SVBRDFEstimator: shapes, view-order invariance, checkpoint round trip, input checks."""

from __future__ import annotations

import copy

import pytest
import torch

from estimator import EstimatorConfig, SVBRDFEstimator
from estimator.config import TINY_TEST_CONFIG, TRAINING_DEFAULTS
from materials.types import Material

SIZE = 32  # conftest's image side


#: Permuting views changes only the summation order of the mean over views (float32
#: rounding, ~1e-7 relative); 1e-5 is the tolerance the brief asks for.
PERMUTATION_ATOL = 1e-5


@pytest.mark.parametrize("views", [1, 3, 8])
def test_shapes_and_ranges(tiny_model, views, random_views):
    images, light, camera = random_views(2, views)
    with torch.no_grad():
        out = tiny_model(images, light, camera)
    assert isinstance(out, Material)
    assert out.diffuse.shape == (2, 3, SIZE, SIZE)
    assert out.normal.shape == (2, 3, SIZE, SIZE)
    assert out.roughness.shape == (2, 1, SIZE, SIZE)
    assert out.specular.shape == (2, 3, SIZE, SIZE)
    for t in (out.diffuse, out.roughness, out.specular):
        assert float(t.min()) >= 0 and float(t.max()) <= 1
    assert torch.allclose(out.normal.norm(dim=1), torch.ones(2, SIZE, SIZE), atol=1e-5)
    assert float(out.normal[:, 2].min()) > 0
    out.validate()


def test_view_order_does_not_matter(tiny_model, random_views):
    images, light, camera = random_views(2, 6, seed=3)
    perm = torch.tensor([4, 1, 5, 0, 3, 2])
    with torch.no_grad():
        a = tiny_model(images, light, camera).stacked()
        b = tiny_model(images[:, perm], light[:, perm], camera[:, perm]).stacked()
    torch.testing.assert_close(a, b, atol=PERMUTATION_ATOL, rtol=0)


def test_views_matter(tiny_model, random_views):
    """The model is not trivially ignoring extra views or the light positions."""
    images, light, camera = random_views(1, 3, seed=4)
    with torch.no_grad():
        one = tiny_model(images[:, :1], light[:, :1], camera[:, :1]).stacked()
        three = tiny_model(images, light, camera).stacked()
        moved = tiny_model(images, light + torch.tensor([1.0, 0.0, 0.0]), camera).stacked()
    assert (one - three).abs().max() > 1e-4
    assert (moved - three).abs().max() > 1e-4


def test_shared_positions_broadcast(tiny_model, random_views):
    images, light, camera = random_views(2, 3, seed=5)
    light[1], camera[1] = light[0], camera[0]
    with torch.no_grad():
        a = tiny_model(images, light, camera).stacked()
        b = tiny_model(images, light[0], camera[0]).stacked()
    torch.testing.assert_close(a, b)


#: Outputs of the float32 tiny model against the same model in float64, on random_views'
#: inputs (maps in [0, 1]): measured 2.4e-6 (AMD EPYC, AVX-512); the 10-20 float32
#: convolution layers' rounding depends on the kernels oneDNN picks (by CPU, and by the
#: weights' memory alignment, so even a reloaded copy on the same CPU differs from the
#: original by ~8e-7). 40x the measurement.
FLOAT32_OUTPUT_ATOL = 1e-4


def test_save_pretrained_round_trip(tiny_model, tmp_path, random_views):
    """The state dict survives bit for bit; the outputs are those of the same network, to
    float32 rounding (not bit-equal: the convolution code path may change with alignment)."""
    tiny_model.save_pretrained(tmp_path / "m")
    files = {p.name for p in (tmp_path / "m").iterdir()}
    assert "config.json" in files and any(f.endswith(".safetensors") for f in files)
    loaded = SVBRDFEstimator.from_pretrained(tmp_path / "m").eval()
    assert loaded.arch == tiny_model.arch
    saved, restored = tiny_model.state_dict(), loaded.state_dict()
    assert list(restored) == list(saved)
    for name, tensor in saved.items():
        assert restored[name].dtype == tensor.dtype and torch.equal(restored[name], tensor), name
    images, light, camera = random_views(1, 3, seed=6)
    with torch.no_grad():
        exact = copy.deepcopy(tiny_model).double()(images.double(), light.double(), camera.double()).stacked()
        for model in (tiny_model, loaded):
            out = model(images, light, camera).stacked()
            torch.testing.assert_close(out.double(), exact, rtol=0, atol=FLOAT32_OUTPUT_ATOL)


def test_default_size_budget():
    """The shipped architecture stays small (brief: < ~2.5 M params, safetensors < 10 MB)."""
    model = SVBRDFEstimator(**TRAINING_DEFAULTS)
    params = sum(p.numel() for p in model.parameters())
    assert params < 2_500_000
    assert params * 4 < 10_000_000
    # EstimatorConfig is generated from the signature: the model's defaults plus TRAINING_DEFAULTS
    assert model.arch == EstimatorConfig()
    # ... and a saved config without a field reads as the model's default (old checkpoints)
    assert SVBRDFEstimator().arch == EstimatorConfig.from_saved({}) != EstimatorConfig()
    assert EstimatorConfig.from_saved({}).shading_channels == 0


@pytest.mark.parametrize("change", ["drop", "add"])
def test_from_pretrained_refuses_a_partial_load(tiny_model, tmp_path, change):
    # diffusers alone would only warn (unexpected) or leave the weight on the meta device (missing).
    from safetensors.torch import load_file, save_file

    tiny_model.save_pretrained(tmp_path)
    (file,) = tmp_path.glob("*.safetensors")
    _, info = SVBRDFEstimator.from_pretrained(tmp_path, output_loading_info=True)
    assert not info["missing_keys"] and not info["unexpected_keys"] and not info["mismatched_keys"]
    state = load_file(str(file))
    if change == "drop":
        del state["heads.normal.out.bias"]
    else:
        state["heads.extra.bias"] = torch.zeros(3)
    save_file(state, str(file), metadata={"format": "pt"})
    with pytest.raises(ValueError, match="missing" if change == "drop" else "unexpected"):
        SVBRDFEstimator.from_pretrained(tmp_path)


def test_latent_offset_changes_output(tiny_model, random_views):
    images, light, camera = random_views(1, 2, seed=7)
    shape = tiny_model.latent_shape(1, (SIZE, SIZE))
    with torch.no_grad():
        pyramid = tiny_model.encode(images, light, camera)
        assert tuple(pyramid[-1].shape) == shape
        base = tiny_model.predict_maps(tiny_model.decode(pyramid)).stacked()
        zero = tiny_model(images, light, camera, latent_offset=torch.zeros(shape)).stacked()
        moved = tiny_model(images, light, camera, latent_offset=torch.ones(shape)).stacked()
    torch.testing.assert_close(base, zero, atol=0, rtol=0)
    assert (moved - base).abs().max() > 1e-3
    with pytest.raises(ValueError, match="latent_offset"):
        tiny_model(images, light, camera, latent_offset=torch.zeros(1, 1, 1, 1))


@pytest.mark.parametrize(
    "mutate, name",
    [
        (lambda i, l, c: (i[:, 0], l, c), "images"),  # [B, 3, H, W]
        (lambda i, l, c: (i[:, :, :2], l, c), "images"),  # 2 channels
        (lambda i, l, c: (i, l[:, :2], c), "light"),  # 2 positions for 3 views
        (lambda i, l, c: (i, l, c[:, :, :2]), "camera"),  # [B, V, 2]
        (lambda i, l, c: (i[..., :30, :30], l, c), "images"),  # not a multiple of 4
        (lambda i, l, c: (i.index_put((torch.tensor(0),), torch.tensor(float("nan"))), l, c), "images"),
        (lambda i, l, c: (i, l.index_put((torch.tensor(0),), torch.tensor(float("inf"))), c), "light"),
    ],
)
def test_bad_input_raises_value_error_naming_argument(tiny_model, mutate, name, random_views):
    images, light, camera = mutate(*random_views(1, 3, seed=8))
    with pytest.raises(ValueError, match=name):
        tiny_model(images, light, camera)


def test_tiny_config_is_small():
    assert sum(p.numel() for p in SVBRDFEstimator(**TINY_TEST_CONFIG.to_dict()).parameters()) < 50_000


def _with_live_shading_head(model: SVBRDFEstimator, seed: int) -> SVBRDFEstimator:
    """The shading head's output layer starts at zero (a grown model starts unchanged);
    give it weights so that tests see the branch."""
    g = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        out = model.shading_head.out
        out.weight.copy_(torch.randn(out.weight.shape, generator=g) * 0.5)
    return model


def test_shading_branch_is_read_and_symmetric(tiny_model, random_views):
    images, light, camera = random_views(2, 6, seed=11)
    with torch.no_grad():
        silent = tiny_model(images, light, camera)
        live = _with_live_shading_head(tiny_model, seed=0)
        a = live(images, light, camera)
        perm = torch.tensor([2, 0, 5, 1, 4, 3])
        b = live(images[:, perm], light[:, perm], camera[:, perm])
    torch.testing.assert_close(a.stacked(), b.stacked(), atol=PERMUTATION_ATOL, rtol=0)
    assert (a.normal - silent.normal).abs().max() > 1e-3  # the branch reaches the normals ...
    for name in ("diffuse", "roughness", "specular"):  # ... and only them
        torch.testing.assert_close(getattr(a, name), getattr(silent, name), atol=0, rtol=0)
    head = {id(p) for p in live.shading_head.parameters()}
    assert head <= {id(p) for p in live.adapter_parameters()}  # refinement tunes it too


def test_no_shading_branch_and_old_checkpoints(tmp_path, random_views):
    import json

    torch.manual_seed(0)
    plain = SVBRDFEstimator(**{**TINY_TEST_CONFIG.to_dict(), "shading_channels": 0}).eval()
    assert plain.shading is None and plain.shading_head is None
    plain.save_pretrained(tmp_path / "old")
    config = tmp_path / "old" / "config.json"
    raw = json.loads(config.read_text())
    del raw["shading_channels"]  # as saved before the branch existed
    config.write_text(json.dumps(raw))
    loaded = SVBRDFEstimator.from_pretrained(tmp_path / "old").eval()
    assert loaded.arch.shading_channels == 0
    images, light, camera = random_views(1, 3, seed=12)
    with torch.no_grad():
        torch.testing.assert_close(
            loaded(images, light, camera).stacked(), plain(images, light, camera).stacked(), atol=0, rtol=0
        )
    with pytest.raises(ValueError, match="two levels"):
        SVBRDFEstimator(channel_mults=(1,), shading_channels=4)
    with pytest.raises(ValueError, match="shading_channels"):
        SVBRDFEstimator(shading_channels=-1)


#: The channels-last mix against its textbook NCHW form, same float64 arithmetic up to
#: summation order (mean over 3 views, GroupNorm statistics): a few ulps of float64.
LAYOUT_ATOL = 1e-12


@pytest.mark.parametrize(
    "batch, c, groups",
    [
        (1, 8, 4),  # GroupNorm groups of 6 over [f, mean, max] of 8: one group straddles f and mean
        (2, 8, 4),
        (2, 6, 3),  # groups of 6 that align with the three parts: no straddling group
        (2, 4, 1),  # one group over all 12 channels: every channel's affine is per view
    ],
)
def test_view_mean_max_and_mix_match_the_reference_layout(batch, c, groups):
    """``_view_mean_max`` and ``CrossViewMix`` (channels-last buffers, running sums, and
    without autograd the GroupNorm from per-channel moments, split per view / per
    material) equal the plain formulas ``mean(1)`` / ``amax(1)`` and ``f_v +
    conv1x1(SiLU(GN([f_v, mean, max])))`` on NCHW tensors, for one and several
    materials, with and without autograd; the gradient too."""
    import torch.nn.functional as F

    from estimator.model import CrossViewMix, _view_mean_max

    views = 3
    gen = torch.Generator().manual_seed(0)
    x = torch.randn(batch * views, c, 5, 6, generator=gen, dtype=torch.float64)
    xv = x.unflatten(0, (batch, views))
    for layout in (torch.contiguous_format, torch.channels_last):
        mean, top = _view_mean_max(x.contiguous(memory_format=layout), views)
        torch.testing.assert_close(mean, xv.mean(1), atol=LAYOUT_ATOL, rtol=0)
        torch.testing.assert_close(top, xv.amax(1), atol=0, rtol=0)

    mix = CrossViewMix(c, groups=groups).double()
    assert mix.norm.num_groups == groups
    with torch.no_grad():
        mix.norm.weight.normal_(generator=gen)
        mix.norm.bias.normal_(generator=gen)
    joint = torch.cat([xv, xv.mean(1, keepdim=True).expand_as(xv), xv.amax(1, keepdim=True).expand_as(xv)], 2)
    expected = (x + mix.proj(F.silu(mix.norm(joint.flatten(0, 1))))).detach()
    with torch.no_grad():
        torch.testing.assert_close(mix(x, views), expected, atol=LAYOUT_ATOL, rtol=0)
        channels_last = x.contiguous(memory_format=torch.channels_last)
        torch.testing.assert_close(mix(channels_last, views), expected, atol=LAYOUT_ATOL, rtol=0)
    xg = x.clone().requires_grad_(True)
    (mix(xg, views) * expected).sum().backward()
    xr = x.clone().requires_grad_(True)
    xrv = xr.unflatten(0, (batch, views))
    jr = torch.cat([xrv, xrv.mean(1, keepdim=True).expand_as(xrv), xrv.amax(1, keepdim=True).expand_as(xrv)], 2)
    ((xr + mix.proj(F.silu(mix.norm(jr.flatten(0, 1))))) * expected).sum().backward()
    torch.testing.assert_close(xg.grad, xr.grad, atol=LAYOUT_ATOL, rtol=0)


#: The same float32 convs on the same inputs in another call: maps in [0, 1] agree to a
#: few ulps (oneDNN may pick another kernel order); 1e-6 is ~8 ulps at 1.
SAME_CONVS_TOL = 1e-6


#: Float32 against float64 at full resolution, 8 views: the per-channel moments path
#: (BLAS-accumulated sums of 1M pixels) lands within ~1e-6 of float64 on the shipped model
#: at 1024 px; 2e-5 leaves room for other BLAS summation orders (Intel and AMD), and is 30x
#: below what torch's float32 GroupNorm missed by there (6e-4).
MOMENTS_FP32_ATOL = 2e-5


def test_conv_block_without_graph_is_groupnorm_silu():
    """``ConvBlock`` without autograd (the GroupNorm as an affine from per-channel
    moments, in place) equals conv -> GroupNorm -> SiLU: in float64 to rounding, in
    float32 against float64 at a side large enough for float32 sums to drift (256 px);
    under bf16 autocast it keeps torch's GroupNorm (bf16 moments would lose the variance)."""
    import torch.nn.functional as F

    from estimator.model import ConvBlock, _moments_path

    gen = torch.Generator().manual_seed(1)
    block = ConvBlock(5, 12, groups=4).double()
    with torch.no_grad():
        block.norm.weight.normal_(generator=gen)
        block.norm.bias.normal_(generator=gen)
    # Features with a mean far from zero: the moments' difference is where precision goes.
    x = (torch.randn(3, 5, 256, 256, generator=gen, dtype=torch.float64) + 3.0).contiguous(
        memory_format=torch.channels_last
    )
    expected = F.silu(block.norm(block.conv(x))).detach()
    with torch.no_grad():
        torch.testing.assert_close(block(x), expected, atol=LAYOUT_ATOL, rtol=0)
        block32 = copy.deepcopy(block).float()
        torch.testing.assert_close(block32(x.float()).double(), expected, atol=MOMENTS_FP32_ATOL, rtol=0)
        assert _moments_path(x.float()) and not _moments_path(x.bfloat16())
    assert not _moments_path(x.float())  # autograd on: the graph path
    with torch.enable_grad():
        torch.testing.assert_close(block(x), expected, atol=0, rtol=0)


def test_generated_flag_marks_views_and_starts_as_a_no_op():
    # A flagged model starts equal to the same model without the flag (zero vectors); once
    # its vectors are non-zero the mark changes the maps, and only through marked views.
    import dataclasses

    torch.manual_seed(0)
    plain = SVBRDFEstimator(**TINY_TEST_CONFIG.to_dict()).eval()
    flagged = SVBRDFEstimator(**dataclasses.replace(TINY_TEST_CONFIG, generated_flag=True).to_dict()).eval()
    missing, unexpected = flagged.load_state_dict(plain.state_dict(), strict=False)
    assert not unexpected and all(k.startswith("generated_embed.") for k in missing) and missing
    gen = torch.Generator().manual_seed(3)
    images = torch.rand(2, 3, 3, 32, 32, generator=gen)
    lights = torch.tensor([[0.0, 0.0, 4.0], [2.0, 1.0, 5.0], [-1.0, 2.0, 4.0]])
    camera = torch.tensor([0.0, 0.0, 4.0]).expand(3, 3)
    marks = torch.tensor([False, True, True])

    def maps(model, generated):
        with torch.no_grad():
            out = model(images, lights, camera, generated=generated)
            return torch.cat([t.flatten(1) for t in out.map_tensors()], dim=1)  # [B, all map values]

    reference = maps(plain, None)
    assert torch.equal(maps(plain, marks), reference)  # a model without the flag ignores the mark
    assert torch.equal(maps(flagged, marks), reference)  # zero vectors: unchanged
    with torch.no_grad():
        for p in flagged.generated_embed:
            p.normal_(generator=gen)
    assert torch.equal(maps(flagged, torch.zeros(3, dtype=torch.bool)), reference)
    assert not torch.allclose(maps(flagged, marks), reference)
    per_batch = torch.tensor([[False, True, True], [False, False, False]])
    both = maps(flagged, per_batch)  # [B, V] marks: only the first material moves
    assert not torch.allclose(both[0], reference[0])
    assert torch.allclose(both[1], reference[1], atol=SAME_CONVS_TOL)
    with pytest.raises(ValueError, match="generated must be"):
        maps(flagged, torch.tensor([False, True]))
    with pytest.raises(TypeError, match="bool tensor"):
        maps(flagged, torch.tensor([0, 1, 1]))
