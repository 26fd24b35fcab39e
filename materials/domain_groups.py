"""Training groups in the capture domain: ``RenderedGroups`` with randomised geometry,
light falloff and photometric degradation (``materials.capture_domain``), over the
procedural materials, optionally mixed pairs of them, and real-texture material folders.

One item is one material under V lights, like ``materials.dataset.RenderedGroups``, and
with the same keys, so a trainer can switch datasets without other changes:

- ``images`` ``[V, 3, H, W]`` float32: what the model sees, linear radiance as decoded
  from a photo (exposure, white balance, noise, clipping, 8-bit tone map, JPEG applied
  as drawn); view 0 is the flash photo (light next to the camera).
- ``clean`` ``[V, 3, H, W]`` float32: the same views before noise, clipping and
  quantisation (exposure and white balance applied), e.g. relighting targets.
- ``light_pos`` / ``camera_pos`` ``[V, 3]`` float32 positions in the model's frame
  (``dgrsise`` units, plane side 4).
- ``intensity`` ``[V, 3]`` float32 and ``inverse_square`` (bool tensor): rendering the
  maps with ``kernels.render(..., preset="dgrsise", intensity=intensity[v],
  inverse_square=inverse_square)`` reproduces ``clean[v]`` (e.g. for a rendering loss or
  refinement in the inputs' own lighting).
- ``maps`` ``[10, H, W]``: the ground truth (``Material.stacked``), unchanged by the
  photometric effects.
- ``seed``: the material seed; ``-(k + 1)`` for texture material ``k``.
- ``source``: ``"procedural"``, ``"mix"`` or the texture folder's name.

Real textures: ``load_texture_folder`` reads a folder of ``diffuse.png``, ``normal.png``,
``roughness.png``, ``specular.png`` (MatSynth-family convention: diffuse and specular
sRGB, roughness linear, normal (n + 1) / 2 OpenGL), e.g. the development materials in
``../shared/data/real-dev/materials`` (read by path at training time, never copied into
the repository). Split: ``REAL_DEV_TRAIN`` for training, ``REAL_DEV_VALIDATION`` held out.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from PIL import Image
from torch.utils.data import Dataset

from kernels.tonemap import srgb_decode, srgb_encode
from materials.capture_domain import (
    CaptureDomain,
    Degradation,
    apply_degradation,
    render_geometry,
    sample_degradation,
    sample_geometry,
)
from materials.dataset import TRAIN_SEEDS, GroupConfig, RenderedGroups, _item_seed, scale_and_crop
from materials.io.encoding import decode_normal, hwc_to_chw
from materials.io.errors import FormatError
from materials.procedural import generate
from materials.types import Material

__all__ = [
    "DomainGroups",
    "relighting_groups",
    "DATA_OPTIONS",
    "RELIGHTING_DATA_OPTIONS",
    "data_options",
    "training_texture_folders",
    "check_data_options",
    "DATA_DOMAINS",
    "load_texture_folder",
    "save_texture_folder",
    "crop_texture",
    "dihedral",
    "mix_materials",
    "REAL_DEV_TRAIN",
    "REAL_DEV_VALIDATION",
    "TEXTURE_FILES",
]

#: Real-dev materials trained on: three different structures (rough asphalt, bricks with
#: mortar, metal-sheet roof with a low-F0 specular map).
REAL_DEV_TRAIN = ("asphalt_floor", "castle_brick", "grey_roof")
#: Real-dev materials held out for validation: shapes none of the training three has
#: (rounded pebbles, wood planks), so validation measures transfer, not memorisation.
REAL_DEV_VALIDATION = ("clean_pebbles", "old_wood_floor")
#: File names of a texture material folder.
TEXTURE_FILES = ("diffuse.png", "normal.png", "roughness.png", "specular.png")


# ---------------------------------------------------------------------- texture folders
def _read_rgb(path: Path) -> np.ndarray:
    """8-bit PNG/JPEG -> ``[H, W, 3]`` float32 codes / 255. Grey is repeated to RGB; an
    alpha channel is dropped only when fully opaque (some source files store RGBA)."""
    if not path.is_file():
        raise FormatError(path, "texture map file does not exist")
    try:
        with Image.open(path) as img:
            img.load()
            if img.mode in ("RGBA", "LA"):
                alpha = np.asarray(img.getchannel("A"))
                if alpha.min() < 255:
                    raise FormatError(path, "alpha channel is not fully opaque; expected an opaque map")
            if img.mode == "I;16" or img.mode == "I":
                raise FormatError(path, f"{img.mode} (16/32-bit) maps are not supported; expected 8-bit")
            pixels = np.asarray(img.convert("RGB"))
    except (OSError, SyntaxError) as err:
        raise FormatError(path, f"cannot decode the image: {err}") from err
    return pixels.astype(np.float32) / 255.0


def load_texture_folder(
    folder: str | os.PathLike,
    *,
    diffuse_srgb: bool = True,
    specular_srgb: bool = True,
    roughness_srgb: bool = False,
    normal_green_up: bool = True,
) -> Material:
    """Read a real-texture material folder (``TEXTURE_FILES``) into a ``Material``.

    The defaults are the MatSynth-family convention, which the real-dev materials follow:
    diffuse and specular sRGB-encoded, roughness linear, normal ``(n + 1) / 2`` with
    green = +y (OpenGL). Checked on them: against the source's own render.png, sRGB
    diffuse beats linear by ~3 dB, sRGB specular (61/255 -> F0 0.047) beats linear by
    2 dB, linear roughness beats sRGB by 1 dB; the normals' slope field is nearly curl-free
    read as OpenGL (mean |curl| / |div| 0.15-0.26) and not as DirectX (0.53-1.08). The
    switches exist to test other hypotheses (a DirectX normal map has green = -y).

    Returns:
        Unbatched ``Material`` (``[C, H, W]`` float32, linear values), validated.

    Raises:
        FormatError: a missing or unreadable file, a non-opaque alpha channel, maps of
            different sizes. ``MapError``: values out of range.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise FormatError(folder, "texture material folder does not exist")
    raw = {name[: -len(".png")]: hwc_to_chw(_read_rgb(folder / name)) for name in TEXTURE_FILES}
    sizes = {tuple(t.shape[-2:]) for t in raw.values()}
    if len(sizes) != 1:
        raise FormatError(folder, f"maps have different sizes: { {k: tuple(v.shape[-2:]) for k, v in raw.items()} }")
    diffuse = srgb_decode(raw["diffuse"]) if diffuse_srgb else raw["diffuse"]
    specular = srgb_decode(raw["specular"]) if specular_srgb else raw["specular"]
    roughness = raw["roughness"].mean(0, keepdim=True)
    roughness = srgb_decode(roughness) if roughness_srgb else roughness
    normal = 2.0 * raw["normal"] - 1.0
    if not normal_green_up:
        normal = normal * normal.new_tensor([1.0, -1.0, 1.0])[:, None, None]
    # Normals pointing into the surface are artefacts of the source (castle_brick has 5
    # pixels down to z = -0.012); they are laid flat (z = 0) before normalising, which is
    # how the renderer's clamped dot products treat them anyway.
    normal[2].clamp_(min=0.0)
    normal = decode_normal((normal + 1.0) * 0.5)
    return Material(diffuse.contiguous(), normal.contiguous(), roughness.contiguous(), specular.contiguous()).validate(
        source=str(folder)
    )


def save_texture_folder(folder: str | os.PathLike, material: Material) -> Path:
    """Write ``material`` (unbatched) as a texture folder ``load_texture_folder`` reads with
    its defaults: 8-bit RGB PNGs, diffuse and specular sRGB-encoded, roughness linear (grey
    as RGB), normal ``(n + 1) / 2`` OpenGL. Returns the folder (created)."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    maps = {
        "diffuse": srgb_encode(material.diffuse),
        "normal": (material.normal + 1.0) * 0.5,
        "roughness": material.roughness.expand(3, -1, -1),
        "specular": srgb_encode(material.specular),
    }
    for name, chw in maps.items():
        codes = (chw.clamp(0, 1) * 255).round().to(torch.uint8).permute(1, 2, 0).numpy()
        Image.fromarray(np.ascontiguousarray(codes)).save(folder / f"{name}.png")
    return folder


#: The trainers' ``domain`` values: ``paper`` (``RenderedGroups``) or ``capture`` (``DomainGroups``).
DATA_DOMAINS = ("paper", "capture")


def check_data_options(domain: str, textures: str | None, **probabilities: float) -> None:
    """The trainers' shared data options (``domain``, ``textures``, ``p_*``), checked
    once for both: ``ValueError`` naming the option."""
    if domain not in DATA_DOMAINS:
        raise ValueError(f"domain must be one of {DATA_DOMAINS}, got {domain!r}")
    if domain == "paper" and textures is not None:
        raise ValueError("textures needs domain='capture' (the paper's data has procedural materials only)")
    for name, p in probabilities.items():
        if not 0 <= p <= 1:
            raise ValueError(f"{name} must be in [0, 1], got {p}")


#: The trainers' data options (their ``TrainConfig`` fields, checked by
#: ``check_data_options``): a checkpoint resumes only with the values it was trained on.
DATA_OPTIONS = ("domain", "textures", "p_texture", "p_mix", "p_paper")
#: The relighter trainers' data options: ``DATA_OPTIONS`` plus ``p_crop`` (the share of
#: items that show a window of the plane; ``relighting_groups``).
RELIGHTING_DATA_OPTIONS = (*DATA_OPTIONS, "p_crop")


def data_options(cfg: object, names: Sequence[str] = RELIGHTING_DATA_OPTIONS) -> dict[str, Any]:
    """A trainer config's data options by name, as keywords for ``check_data_options``
    and ``relighting_groups`` (one list of the options per trainer, not one per call)."""
    return {name: getattr(cfg, name) for name in names}


def training_texture_folders(root: str | os.PathLike) -> list[Path]:
    """The ``REAL_DEV_TRAIN`` material folders under ``root`` (e.g.
    ``../shared/data/real-dev/materials``), the textures every trainer may use;
    ``REAL_DEV_VALIDATION`` stays out. Raises ``FileNotFoundError`` naming the missing ones."""
    folders = [Path(root) / name for name in REAL_DEV_TRAIN]
    missing = [str(f) for f in folders if not f.is_dir()]
    if missing:
        raise FileNotFoundError(f"textures: {root} lacks the training materials {missing}")
    return folders


def relighting_groups(
    config: GroupConfig,
    domain: str = "paper",
    textures: str | os.PathLike | None = None,
    *,
    p_texture: float = 0.25,
    p_mix: float = 0.0,
    p_paper: float = 0.0,
    p_crop: float = CaptureDomain.p_crop,
) -> RenderedGroups | DomainGroups:
    """The relighters' training groups over ``TRAIN_SEEDS`` (the diffusion and Bieron-style
    trainers share it, so their comparison sees the same data): ``paper``, the clean
    renders (``RenderedGroups``); ``capture``, ``CaptureDomain.relighting()`` (the photo
    as the capture pipeline hands it to a relighter; items also carry the unclipped
    ``clean`` views, the targets), with the ``REAL_DEV_TRAIN`` textures under ``textures``
    when given; ``p_crop`` is ``CaptureDomain.p_crop`` (0: every item shows the whole
    plane, as the diffusion relighter's ``large="global"`` mode hands it the photo).
    Options are checked by ``check_data_options``."""
    check_data_options(
        domain,
        None if textures is None else str(textures),
        p_texture=p_texture,
        p_mix=p_mix,
        p_paper=p_paper,
        p_crop=p_crop,
    )
    if domain == "paper":
        return RenderedGroups(TRAIN_SEEDS, config)
    return DomainGroups(
        TRAIN_SEEDS,
        config,
        CaptureDomain.relighting(p_crop),
        textures=training_texture_folders(textures) if textures is not None else [],
        p_texture=p_texture,
        p_mix=p_mix,
        p_paper=p_paper,
    )


# ---------------------------------------------------------------------- augmentation
def dihedral(material: Material, transpose: bool, flip_x: bool, flip_y: bool) -> Material:
    """One of the 8 symmetries of the square, applied to unbatched maps ``[C, H, W]`` with
    the normals turned to match (they are vectors in the image's x / y frame).

    Pixel column j is +x and row i is -y (SPEC section 2): flipping the columns negates
    n_x, flipping the rows negates n_y, and transposing maps (x, y) to (-y, -x).
    Applied in the order transpose, flip_x, flip_y.
    """
    maps = material.maps()
    n = maps["normal"]
    if transpose:
        maps = {k: v.transpose(-1, -2) for k, v in maps.items()}
        n = maps["normal"]
        n = torch.stack([-n[1], -n[0], n[2]])
    if flip_x:
        maps = {k: v.flip(-1) for k, v in maps.items()}
        n = n.flip(-1) * n.new_tensor([-1.0, 1.0, 1.0])[:, None, None]
    if flip_y:
        maps = {k: v.flip(-2) for k, v in maps.items()}
        n = n.flip(-2) * n.new_tensor([1.0, -1.0, 1.0])[:, None, None]
    maps["normal"] = n
    return Material(**{k: v.contiguous() for k, v in maps.items()})


def crop_texture(material: Material, size: int, generator: torch.Generator, min_scale: float = 0.5) -> Material:
    """Random square crop inside a (not necessarily tileable) texture, resized to ``size``,
    in a random dihedral orientation.

    The crop side is uniform in [max(size, min_scale * S), S] of an S x S texture (as
    ``materials.dataset.scale_and_crop``, but never wrapping around: real textures need
    not tile). Normals are renormalised after resampling. Maps unbatched ``[C, H, W]``.
    """
    s = min(material.shape)
    lo = min(s, max(size, int(round(min_scale * s))))
    side = int(torch.randint(lo, s + 1, (1,), generator=generator))
    top = int(torch.randint(0, material.shape[0] - side + 1, (1,), generator=generator))
    left = int(torch.randint(0, material.shape[1] - side + 1, (1,), generator=generator))
    transpose, flip_x, flip_y = (bool(v) for v in torch.rand(3, generator=generator) < 0.5)
    out = {}
    for name, t in material.crop(top, left, side, side).maps().items():
        if side != size:
            t = F.interpolate(t[None], size=(size, size), mode="bilinear", antialias=True, align_corners=False)[0]
        out[name] = t
    out["normal"] = F.normalize(out["normal"], dim=0)
    out["roughness"] = out["roughness"].clamp(0, 1)
    return dihedral(Material(**out), transpose, flip_x, flip_y)


def mix_materials(a: Material, b: Material, alpha: float) -> Material:
    """Blend two materials' maps, ``(1 - alpha) a + alpha b``, normals renormalised
    (material mixing in the spirit of Deschaintre et al. 2018's training set)."""
    if not 0.0 <= alpha <= 1.0:
        raise ValueError(f"alpha must be in [0, 1], got {alpha}")
    out = {k: torch.lerp(v, getattr(b, k), alpha) for k, v in a.maps().items()}
    out["normal"] = F.normalize(out["normal"], dim=-3)
    return Material(**out)


# ---------------------------------------------------------------------- dataset
class DomainGroups(Dataset):
    """Materials rendered in the capture domain, one group of V views per item.

    Args:
        seeds: procedural material seeds (``TRAIN_SEEDS`` by default).
        config: sizes and seed as for ``RenderedGroups`` (``preset`` must be ``dgrsise``:
            the falloff is the domain's choice); None: ``GroupConfig()``.
        domain: the randomisation; None: ``CaptureDomain()``. With
            ``CaptureDomain.paper()`` (the paper's clean setup) and no textures or mixing,
            items equal ``RenderedGroups(seeds, config)``'s.
        textures: real-texture materials (unbatched ``Material``) or folders read with
            ``load_texture_folder``; loaded once, here.
        p_texture: probability that an item uses a texture (when any are given).
        p_mix: probability that a procedural item is a blend of two procedural materials
            (alpha ~ U[0.2, 0.8]).
        p_paper: probability that an item is rendered in ``CaptureDomain.paper()`` (the
            paper's clean geometry and linear renders) instead of ``domain``, whatever its
            material: a model fine-tuned on the capture domain alone forgets the clean,
            unclipped inputs (``results/estimator_domain``: -2.45 dB on the paper's set);
            this keeps them in the stream.

    Item ``i`` is deterministic given ``(config.seed, i)``: random streams 0 (material
    crop), 1 (geometry), 2 (photometric effects, noise), 3 (texture / mixing choice),
    4 (domain choice; a separate stream so ``p_paper`` = 0 leaves every other draw as it
    was).
    Keys: module docstring.
    """

    def __init__(
        self,
        seeds: range | list[int] = TRAIN_SEEDS,
        config: GroupConfig | None = None,
        domain: CaptureDomain | None = None,
        *,
        textures: Sequence[Material | str | os.PathLike] = (),
        p_texture: float = 0.25,
        p_mix: float = 0.0,
        p_paper: float = 0.0,
    ):
        if len(seeds) == 0:
            raise ValueError("seeds must not be empty")
        config = GroupConfig() if config is None else config
        domain = CaptureDomain() if domain is None else domain
        if config.preset != "dgrsise":
            raise ValueError(f"DomainGroups renders in the dgrsise frame; got preset {config.preset!r}")
        for name, p in (("p_texture", p_texture), ("p_mix", p_mix), ("p_paper", p_paper)):
            if not 0 <= p <= 1:
                raise ValueError(f"{name} must be in [0, 1], got {p}")
        self.seeds = seeds
        self.config = config
        self.domain = domain
        self.textures: list[Material] = []
        self.texture_names: list[str] = []
        for t in textures:
            if isinstance(t, Material):
                self.textures.append(t)
                self.texture_names.append(f"texture{len(self.texture_names)}")
            else:
                self.textures.append(load_texture_folder(t))
                self.texture_names.append(Path(t).name)
        self.p_texture = p_texture if self.textures else 0.0
        self.p_mix = p_mix
        self.p_paper = p_paper
        self._paper = CaptureDomain.paper()

    def __len__(self) -> int:
        return len(self.seeds)

    def material(self, index: int) -> tuple[Material, int, str]:
        """(unbatched material at ``config.size``, seed, source) of item ``index``."""
        cfg = self.config
        crop_gen = torch.Generator().manual_seed(_item_seed(cfg.seed, index, stream=0))
        choice = torch.Generator().manual_seed(_item_seed(cfg.seed, index, stream=3))
        use_texture, use_mix, k_tex, j_mix, alpha = torch.rand(5, generator=choice, dtype=torch.float64).tolist()
        if use_texture < self.p_texture:
            k = int(k_tex * len(self.textures))
            return crop_texture(self.textures[k], cfg.size, crop_gen, cfg.min_scale), -(k + 1), self.texture_names[k]
        seed = int(self.seeds[index])
        material = scale_and_crop(generate(seed, size=cfg.source_size), cfg.size, crop_gen, cfg.min_scale)
        if use_mix < self.p_mix:
            other = int(self.seeds[int(j_mix * len(self.seeds))])
            second = scale_and_crop(generate(other, size=cfg.source_size), cfg.size, crop_gen, cfg.min_scale)
            return mix_materials(material, second, 0.2 + 0.6 * alpha), seed, "mix"
        return material, seed, "procedural"

    def item_domain(self, index: int) -> CaptureDomain:
        """The randomisation of item ``index``: ``CaptureDomain.paper()`` with probability
        ``p_paper`` (stream 4), else ``domain``."""
        if self.p_paper == 0:
            return self.domain
        draw = torch.rand(1, generator=torch.Generator().manual_seed(_item_seed(self.config.seed, index, 4)))
        return self._paper if float(draw) < self.p_paper else self.domain

    def __getitem__(self, index: int) -> dict:
        if not -len(self) <= index < len(self):
            raise IndexError(index)
        index = index % len(self)
        cfg = self.config
        material, seed, source = self.material(index)
        domain = self.item_domain(index)
        geometry = sample_geometry(cfg.views, domain, torch.Generator().manual_seed(_item_seed(cfg.seed, index, 1)))
        photo_gen = torch.Generator().manual_seed(_item_seed(cfg.seed, index, stream=2))
        degradation = sample_degradation(cfg.views, domain, photo_gen)
        clean = render_geometry(material, geometry) * degradation.gain[:, :, None, None]
        images = apply_degradation(clean, _without_gain(degradation), photo_gen)
        intensity = geometry.intensity * degradation.gain
        return {
            "images": images,
            "clean": clean,
            "light_pos": geometry.light,
            "camera_pos": geometry.camera,
            "intensity": intensity,
            "inverse_square": torch.tensor(geometry.inverse_square),
            "maps": material.stacked(),
            "seed": seed,
            "source": source,
        }


def _without_gain(degradation: Degradation) -> Degradation:
    """The degradation with exposure and white balance already applied (set to 1)."""
    return replace(
        degradation,
        exposure=torch.ones_like(degradation.exposure),
        white_balance=torch.ones_like(degradation.white_balance),
    )
