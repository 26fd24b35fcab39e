"""``materials.relit_pool``: the pool file round trip and the mixing of relit items into
the ``RenderedGroups`` stream."""

from __future__ import annotations

import pytest
import torch

from materials.dataset import TRAIN_SEEDS, GroupConfig, RenderedGroups
from materials.relit_pool import RelitMixedGroups, read_relit_pool, write_relit_pool

CFG = GroupConfig(size=16, views=3, source_size=32, seed=4)
#: float16 storage: relative rounding 2^-11 of values in [0, 1].
HALF_TOL = 2.0**-11


def _pool(tmp_path, count=3, start=5):
    index = torch.arange(start, start + count)
    relit = torch.rand(count, CFG.views - 1, 3, CFG.size, CFG.size, generator=torch.Generator().manual_seed(0))
    path = write_relit_pool(tmp_path / "pool.safetensors", index, relit, CFG, {"relighter": "test"})
    return path, index, relit


def test_pool_round_trip(tmp_path):
    path, index, relit = _pool(tmp_path)
    got_index, got_relit, config, source = read_relit_pool(path)
    assert torch.equal(got_index, index) and config == CFG and source == {"relighter": "test"}
    assert got_relit.dtype == torch.float16
    torch.testing.assert_close(got_relit.float(), relit, atol=HALF_TOL, rtol=0)


def test_relit_items_swap_views_and_keep_the_ground_truth(tmp_path):
    path, index, relit = _pool(tmp_path)
    data = RelitMixedGroups(path, 0.5, TRAIN_SEEDS)
    plain = RenderedGroups(TRAIN_SEEDS, CFG)
    flags = []
    for i in range(20):
        item = data[i]
        flags.append(bool(item["relit"]))
        if not item["relit"]:
            assert torch.equal(item["images"], plain[i]["images"])
            continue
        j = i % len(index)
        truth = plain[int(index[j])]
        # View 0 (the photo), positions and maps are the pooled item's; views 1.. relit.
        for key in ("light_pos", "camera_pos", "maps"):
            assert torch.equal(item[key], truth[key]), key
        assert torch.equal(item["images"][0], truth["images"][0])
        torch.testing.assert_close(item["images"][1:], relit[j], atol=HALF_TOL, rtol=0)
    # 20 Bernoulli(0.5) draws: all alike has probability 2 * 2^-20.
    assert set(flags) == {True, False}
    assert not any(bool(RelitMixedGroups(path, 0.0, TRAIN_SEEDS)[i]["relit"]) for i in range(8))
    assert all(bool(RelitMixedGroups(path, 1.0, TRAIN_SEEDS)[i]["relit"]) for i in range(8))


def test_pool_validation(tmp_path):
    with pytest.raises(ValueError, match="relit"):
        write_relit_pool(tmp_path / "p.safetensors", torch.arange(2), torch.zeros(2, 1, 3, 16, 16), CFG, {})
    bad = torch.zeros(1, CFG.views - 1, 3, 16, 16)
    bad[0, 0, 0, 0, 0] = float("nan")
    with pytest.raises(ValueError, match="NaN"):
        write_relit_pool(tmp_path / "p.safetensors", torch.arange(1), bad, CFG, {})
    path, _, _ = _pool(tmp_path)
    with pytest.raises(ValueError, match="p_relit"):
        RelitMixedGroups(path, -0.1, TRAIN_SEEDS)
