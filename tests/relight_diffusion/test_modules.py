"""Shapes and behaviour of the relighting building blocks."""

import pytest
import torch

from relight.modules import (
    AttentionFeatureSelection,
    Branch,
    ConditionEncoder,
    HAConv,
    LightTokenEncoder,
    MDConv,
    shuffle_within_groups,
)


@pytest.mark.parametrize("conv", [MDConv, HAConv])
def test_gated_conv_shapes(conv):
    x = torch.randn(2, 5, 12, 12)
    assert conv(5, 7)(x).shape == (2, 7, 12, 12)
    assert conv(5, 7, stride=2)(x).shape == (2, 7, 6, 6)


@pytest.mark.parametrize("kind", ["ha", "md", "plain"])
def test_branch_resolution(kind):
    x = torch.randn(1, 3, 32, 32)
    assert Branch(kind, 3, 10, downsample=True)(x).shape == (1, 10, 4, 4)
    assert Branch(kind, 3, 10, downsample=False, widths=(4, 4, 4, 4, 8, 8))(x).shape == (1, 10, 32, 32)


def test_afs_weights_select_between_sources():
    afs = AttentionFeatureSelection([6, 4], 4)
    a, b = torch.randn(3, 6, 5, 5), torch.randn(3, 4, 5, 5)
    out = afs(a, b)
    assert out.shape == (3, 4, 5, 5)
    w = afs.weights([p(f) for p, f in zip(afs.proj, (a, b))])
    assert torch.allclose(w.sum(1), torch.ones(3, 4))
    # a real attention: the weights depend on the input (unlike a softmax over one element)
    w2 = afs.weights([p(f) for p, f in zip(afs.proj, (a * 3, b))])
    assert not torch.allclose(w, w2)


def test_shuffle_within_groups_stays_in_group():
    perm = shuffle_within_groups(16, 8, torch.Generator().manual_seed(1))
    assert sorted(perm.tolist()) == list(range(16))
    assert (perm[:8] < 8).all() and (perm[8:] >= 8).all()
    with pytest.raises(ValueError, match="groups"):
        shuffle_within_groups(10, 8)


def _live_encoder(**kw):
    torch.manual_seed(0)
    enc = ConditionEncoder(out_channels=8, widths=(4, 4, 4, 4, 8, 8), **kw)
    torch.nn.init.normal_(enc.zero_out.weight)  # zero-initialised output would hide everything
    return enc


def test_encoder_is_zero_at_init():
    enc = ConditionEncoder(out_channels=8, widths=(4, 4, 4, 4, 8, 8))
    x = torch.rand(2, 3, 16, 16)
    assert enc(x, x, torch.zeros(2, 2)).abs().max() == 0


def test_shuffle_only_in_training_mode():
    enc = _live_encoder()
    photos = torch.rand(4, 3, 16, 16)
    prior = photos[:1].expand(4, -1, -1, -1)
    offsets = torch.zeros(4, 2)
    perm = torch.tensor([1, 0, 3, 2])
    enc.eval()
    assert torch.equal(enc(photos, prior, offsets, perm), enc(photos, prior, offsets))
    enc.train()
    shuffled = enc(photos, prior, offsets, perm)
    expected = enc(photos[perm], prior, offsets)  # same prior per target, background permuted
    assert torch.allclose(shuffled, expected, atol=1e-5)
    assert not torch.allclose(shuffled, enc(photos, prior, offsets), atol=1e-5)


def test_prior_follows_offsets_and_ablation_ignores_them():
    photos = torch.rand(2, 3, 16, 16)
    enc = _live_encoder().eval()
    assert not torch.allclose(enc(photos, photos, torch.zeros(2, 2)), enc(photos, photos, torch.full((2, 2), 3.0)))
    no_prior = _live_encoder(prior=False).eval()
    assert torch.equal(no_prior(photos, photos, torch.zeros(2, 2)), no_prior(photos, photos, torch.full((2, 2), 3.0)))


def test_light_tokens_shape_and_bad_input():
    enc = LightTokenEncoder(token_dim=16, num_tokens=3)
    assert enc(torch.randn(5, 9, 32, 32)).shape == (5, 3, 16)
    with pytest.raises(ValueError, match="9"):
        enc(torch.randn(5, 8, 32, 32))
