"""Training groups whose views 1.. are a relighter's outputs instead of renders (issue 15,
item 5: an estimator trained on ground-truth renders only does not gain from relit views).

A pool file (safetensors, written by ``write_relit_pool``, e.g. by
``scripts/make_relit_pool.py``) holds, for N items of a ``RenderedGroups`` stream:

- ``index`` ``[N]`` int64: the item indices in that stream;
- ``relit`` ``[N, V - 1, 3, H, W]`` float16: views 1.. of each item as the relighter made
  them from view 0 (the flash photo), linear radiance, at the item's own lights and camera;

and in its metadata the stream's ``GroupConfig`` (JSON) and how the views were made. The
ground truth (maps, view 0, positions) is not stored: ``RenderedGroups`` items are
deterministic, so ``RelitMixedGroups`` re-renders item ``index[j]`` and swaps its views
1.. for the pool's. float16 keeps the file small (8 views of 64 px: 0.2 MB an item); its
relative error 2^-11 is far below the relighters' own (tens of percent).
"""

from __future__ import annotations

import json
import os
from dataclasses import asdict
from pathlib import Path

import torch
from safetensors import safe_open
from safetensors.torch import save_file
from torch.utils.data import Dataset

from materials.dataset import GroupConfig, RenderedGroups, _item_seed

__all__ = ["ITEM_KEYS", "RelitMixedGroups", "read_relit_pool", "write_relit_pool"]

#: The keys of a ``RelitMixedGroups`` item besides ``relit``: ``RenderedGroups``' keys,
#: which every group dataset has (a ``DomainGroups`` item has more: ``clean``, ...).
ITEM_KEYS = ("images", "light_pos", "camera_pos", "maps", "seed")


def write_relit_pool(
    path: str | os.PathLike, index: torch.Tensor, relit: torch.Tensor, config: GroupConfig, source: dict
) -> Path:
    """Write a pool file (module docstring).

    Args:
        path: the ``.safetensors`` file.
        index: ``[N]`` item indices of ``RenderedGroups(..., config)``.
        relit: ``[N, config.views - 1, 3, config.size, config.size]`` linear radiance.
        config: the stream's ``GroupConfig``.
        source: JSON-serialisable record of how ``relit`` was made (relighter, steps, seed).
    """
    expected = (index.shape[0], config.views - 1, 3, config.size, config.size)
    if index.dim() != 1 or tuple(relit.shape) != expected:
        raise ValueError(f"index [N] and relit {list(expected)} expected, got {list(index.shape)}, {list(relit.shape)}")
    if not bool(torch.isfinite(relit).all()):
        raise ValueError("relit holds NaN or infinite values")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    meta = {"group_config": json.dumps(asdict(config)), "source": json.dumps(source)}
    save_file({"index": index.long().contiguous(), "relit": relit.half().contiguous()}, str(path), metadata=meta)
    return path


def read_relit_pool(path: str | os.PathLike) -> tuple[torch.Tensor, torch.Tensor, GroupConfig, dict]:
    """``(index [N], relit [N, V - 1, 3, H, W] float16, GroupConfig, source)`` of a pool file."""
    with safe_open(str(path), framework="pt") as f:
        meta = f.metadata() or {}
        if "group_config" not in meta:
            raise ValueError(f"{path}: not a relit pool (no group_config in its metadata)")
        index, relit = f.get_tensor("index"), f.get_tensor("relit")
    return index, relit, GroupConfig(**json.loads(meta["group_config"])), json.loads(meta.get("source", "{}"))


class RelitMixedGroups(Dataset):
    """``RenderedGroups`` where a share ``p_relit`` of the items have relit views 1...

    Args:
        pool: a pool file (module docstring).
        p_relit: probability (drawn per item index, deterministic) that item ``i`` is the
            pool's entry ``i mod N`` (its ground truth re-rendered, views 1.. relit)
            instead of the stream's item ``i``.
        seeds: the stream's material seeds; must be the ones the pool was made from.
        base: where the other items come from (item ``i`` of it): None, the pool's own
            ``RenderedGroups`` stream; or another dataset of groups of the same views and
            size (e.g. ``materials.domain_groups.DomainGroups``), whose items are cut to
            ``ITEM_KEYS`` so that both kinds batch together.

    Items have ``ITEM_KEYS`` plus ``relit`` (bool tensor).
    """

    def __init__(self, pool: str | os.PathLike, p_relit: float, seeds: range | list[int], base: Dataset | None = None):
        if not 0 <= p_relit <= 1:
            raise ValueError(f"p_relit must be in [0, 1], got {p_relit}")
        self.index, self.relit, self.config, self.source = read_relit_pool(pool)
        self.groups = RenderedGroups(seeds, self.config)
        self.base = base if base is not None else self.groups
        self.p_relit = p_relit

    def __len__(self) -> int:
        return len(self.base)  # type: ignore[arg-type]

    def __getitem__(self, i: int) -> dict:
        g = torch.Generator().manual_seed(_item_seed(self.config.seed, i, stream=5))
        if float(torch.rand(1, generator=g)) >= self.p_relit:
            item = self.base[i]
            return {**{k: item[k] for k in ITEM_KEYS}, "relit": torch.tensor(False)}
        j = i % len(self.index)
        item = self.groups[int(self.index[j])]
        images = item["images"].clone()
        images[1:] = self.relit[j].float()
        return {**{k: item[k] for k in ITEM_KEYS}, "images": images, "relit": torch.tensor(True)}
