"""Shared tiny fixtures of the relighting tests: a small network config, a rendered
held-out-style batch, and a tiny saved checkpoint."""

import pytest
import torch

from materials.dataset import GroupConfig, RenderedGroups

#: A real but tiny BieronRelighter architecture (two levels, 8 channels): fast on the CPU.
TINY = dict(base_channels=8, channel_mults=(1, 2), blocks_per_level=1, norm_groups=4)


@pytest.fixture(autouse=True, scope="module")
def one_thread():
    """One intra-op thread: the tiny convs run far slower when two threads fight over a
    busy 2-core CPU (measured here: 0.4 s vs ~20 s for the same 30 overfit steps)."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


@pytest.fixture(scope="session")
def group_batch():
    """Two materials at 16x16: photo [2, 3, H, W], light_pos [2, 3, 3], camera_pos [2, 3], target [2, 3, 3, H, W]."""
    data = RenderedGroups(range(2), GroupConfig(size=16, source_size=32, views=4))
    items = [data[i] for i in range(2)]
    return {
        "photo": torch.stack([it["images"][0] for it in items]),
        "light_pos": torch.stack([it["light_pos"][1:] for it in items]),
        "camera_pos": torch.stack([it["camera_pos"][0] for it in items]),
        "target": torch.stack([it["images"][1:] for it in items]),
    }


@pytest.fixture(scope="session")
def tiny_checkpoint(tmp_path_factory):
    """A saved (untrained) tiny BieronRelighter folder."""
    from relight.bieron.model import BieronRelighter

    torch.manual_seed(0)
    folder = tmp_path_factory.mktemp("bieron") / "model"
    BieronRelighter(**TINY).save_pretrained(folder)
    return folder
