"""Rendered training groups: procedural materials, random scale-and-crop, paper light
sampling, rendered on the fly by the Warp kernels (SPEC sections 3 and 6).

One item is one material under V lights (V = 8 by default, view 0 lit from the camera),
so a DataLoader batch is ``[B, V, ...]``, the multi-view layout every model uses. Both
the relighting and the estimator training read these.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch.utils.data import Dataset

import kernels
from materials.lights import sample_paper_lights
from materials.procedural import generate
from materials.types import Material

__all__ = [
    "GroupConfig",
    "RenderedGroups",
    "scale_and_crop",
    "TRAIN_SEEDS",
    "EVAL_SEEDS",
    "render_group",
]

#: Seeds of training materials: [0, 1_000_000). Evaluation seeds lie far above, so
#: no held-out material is ever trained on.
TRAIN_SEEDS = range(1_000_000)
#: Held-out evaluation materials (64 of them; evaluations may take a prefix).
EVAL_SEEDS = range(10_000_000, 10_000_064)


@dataclass(frozen=True)
class GroupConfig:
    """How training groups are made.

    Attributes:
        size: side of the rendered crops in pixels.
        views: images per group (view 0 lit from the camera).
        source_size: resolution the procedural material is generated at before the
            scale-and-crop (MatSynth-style: a random crop of a larger tileable map).
        min_scale: smallest crop side as a fraction of ``source_size`` (1 keeps all).
        preset: render preset name.
        seed: base seed of the random crops and lights (materials use their own seeds).
    """

    size: int = 128
    views: int = 8
    source_size: int = 256
    min_scale: float = 0.5
    preset: str = "dgrsise"
    seed: int = 0

    def __post_init__(self) -> None:
        if self.size < 8 or self.source_size < self.size:
            raise ValueError(f"need 8 <= size <= source_size, got size={self.size}, source_size={self.source_size}")
        if not 0 < self.min_scale <= 1:
            raise ValueError(f"min_scale must be in (0, 1], got {self.min_scale}")
        if self.views < 1:
            raise ValueError(f"views must be at least 1, got {self.views}")


def _item_seed(base: int, index: int, stream: int) -> int:
    """A deterministic per-item seed (not Python's hash(), which is salted per process)."""
    return ((int(base) * 1_000_003 + int(index)) * 4 + stream) % (2**63)


def scale_and_crop(material: Material, size: int, generator: torch.Generator, min_scale: float = 0.5) -> Material:
    """Random square crop of a tileable material (wrapping around), resized to ``size``.

    The crop side is uniform in [max(size, min_scale * S), S] for an S x S material.
    Normals are renormalised after resampling. Input and output maps unbatched [C, H, W].
    """
    s = material.shape[0]
    lo = max(size, int(round(min_scale * s)))
    side = int(torch.randint(lo, s + 1, (1,), generator=generator))
    top, left = (int(v) for v in torch.randint(0, s, (2,), generator=generator))
    out = {}
    for name, t in material.maps().items():
        t = torch.roll(t, shifts=(-top, -left), dims=(-2, -1))[..., :side, :side]
        if side != size:
            t = F.interpolate(t[None], size=(size, size), mode="bilinear", antialias=True, align_corners=False)[0]
        out[name] = t
    out["normal"] = F.normalize(out["normal"], dim=0)
    out["roughness"] = out["roughness"].clamp(0, 1)
    return Material(**out)


def render_group(
    material: Material, light_pos: torch.Tensor, camera_pos: torch.Tensor, preset: str = "dgrsise"
) -> torch.Tensor:
    """Render one unbatched material under V lights (``light_pos``, ``camera_pos``:
    ``[V, 3]``): ``[V, 3, H, W]`` linear radiance."""
    d, n, r, s = (t[None] for t in material.map_tensors())
    return kernels.render(d, n, r, s, light_pos, camera_pos, preset=preset)[0]


class RenderedGroups(Dataset):
    """Procedural materials rendered under paper-sampled lights, one group per item.

    Item ``i`` is deterministic: material seed ``seeds[i]``, crop and lights from
    ``(config.seed, i)``. Returns a dict:
        ``images`` ``[V, 3, H, W]`` linear radiance (view 0: flash at the camera),
        ``light_pos`` / ``camera_pos`` ``[V, 3]`` positions (scene units), ``maps`` ``[10, H, W]`` the ground
        truth (diffuse, normal, roughness, specular stacked; ``Material.from_stacked``),
        ``seed`` the material seed.
    """

    def __init__(self, seeds: range | list[int] = TRAIN_SEEDS, config: GroupConfig = GroupConfig()):
        if len(seeds) == 0:
            raise ValueError("seeds must not be empty")
        self.seeds = seeds
        self.config = config

    def __len__(self) -> int:
        return len(self.seeds)

    def material(self, index: int) -> Material:
        cfg = self.config
        gen = torch.Generator().manual_seed(_item_seed(cfg.seed, index, stream=0))
        source = generate(int(self.seeds[index]), size=cfg.source_size)
        return scale_and_crop(source, cfg.size, gen, cfg.min_scale)

    def __getitem__(self, index: int) -> dict:
        if not -len(self) <= index < len(self):
            raise IndexError(index)
        index = index % len(self)
        cfg = self.config
        material = self.material(index)
        gen = torch.Generator().manual_seed(_item_seed(cfg.seed, index, stream=1))
        light_pos, camera_pos = sample_paper_lights(cfg.views, gen)
        images = render_group(material, light_pos, camera_pos, cfg.preset)
        return {
            "images": images,
            "light_pos": light_pos,
            "camera_pos": camera_pos,
            "maps": material.stacked(),
            "seed": int(self.seeds[index]),
        }
