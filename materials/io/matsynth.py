"""MatSynth material folders (Vecchio and Deschaintre 2024): one image file per map.

File names are matched case-insensitively on the stem, bare or after a prefix and an
underscore: ``basecolor.png``, ``Wood_042_Basecolor.PNG`` and ``x_basecolor.exr`` all
name the base colour. Maps: ``basecolor``, ``diffuse``, ``specular``, ``metallic``,
``roughness``, ``normal``, ``height`` (height is found but not used: the normal map is
the geometry). Containers: ``.png``, ``.jpg`` / ``.jpeg``, ``.exr``; when one map has
several, EXR is preferred, then PNG, then JPEG.

Encodings:

- basecolor, diffuse, specular: sRGB-encoded in PNG/JPEG (decoded here); linear in EXR.
  A grey file is broadcast to RGB.
- metallic, roughness: linear grey (channel 0 of an RGB file); roughness is the
  perceptual roughness of SPEC section 2 (alpha = roughness^2), as in MatSynth.
- normal: ``(n + 1) / 2`` in every container, OpenGL / green-up tangent space (MatSynth's
  convention, the same as SPEC section 2); decoded and renormalised.

Workflow: a folder with diffuse + specular uses them directly. Otherwise base colour and
metallic are converted (the usual metallic-roughness to specular-glossiness mapping)::

    diffuse  = basecolor * (1 - metallic)
    specular = lerp(0.04, basecolor, metallic) = 0.04 * (1 - metallic) + basecolor * metallic

where 0.04 is the F0 of a dielectric with index of refraction 1.5 ((1.5-1)/(1.5+1))^2.
"""

from __future__ import annotations

import os
from pathlib import Path

import torch
import torch.nn.functional as F

from kernels.tonemap import srgb_decode
from materials.io.encoding import decode_normal, hwc_to_chw
from materials.io.errors import FormatError, require_same_size
from materials.io.exr import read_exr
from materials.io.png import read_ldr
from materials.types import Material

__all__ = ["read_matsynth", "find_matsynth_maps", "MATSYNTH_MAPS", "DIELECTRIC_F0"]

#: Map names recognised in a MatSynth folder.
MATSYNTH_MAPS = ("basecolor", "diffuse", "specular", "metallic", "roughness", "normal", "height")
#: F0 of a dielectric with IOR 1.5: ((n - 1) / (n + 1))^2 = 0.04 (Fresnel at normal incidence).
DIELECTRIC_F0 = 0.04

# Container preference when a map exists in several (lossless float first, lossy last).
_EXTENSION_RANK = {".exr": 0, ".png": 1, ".jpg": 2, ".jpeg": 2}
_COLOUR_MAPS = ("basecolor", "diffuse", "specular")
_WORKFLOWS = {
    "diffuse-specular": ("diffuse", "specular", "normal", "roughness"),
    "metallic-roughness": ("basecolor", "metallic", "normal", "roughness"),
}


def find_matsynth_maps(folder: str | os.PathLike) -> dict[str, Path]:
    """Find the MatSynth map files in ``folder``: ``{map name: file}`` (maybe empty).

    Raises:
        FormatError: two files with the same container name the same map (e.g.
            ``a_normal.png`` and ``b_normal.png``), so the choice would be a guess.
    """
    folder = Path(folder)
    candidates: dict[str, list[Path]] = {}
    for path in sorted(folder.iterdir()):
        ext = path.suffix.lower()
        if ext not in _EXTENSION_RANK or not path.is_file() or path.name.startswith("."):
            continue
        stem = path.stem.lower()
        for name in MATSYNTH_MAPS:
            if stem == name or stem.endswith("_" + name):
                candidates.setdefault(name, []).append(path)
    found = {}
    for name, paths in candidates.items():
        best = min(_EXTENSION_RANK[p.suffix.lower()] for p in paths)
        chosen = [p for p in paths if _EXTENSION_RANK[p.suffix.lower()] == best]
        if len(chosen) > 1:
            raise FormatError(folder, f"several files could be the {name} map: {', '.join(p.name for p in chosen)}")
        found[name] = chosen[0]
    return found


def _read_map(name: str, path: Path) -> torch.Tensor:
    """One map file -> linear ``[C, H, W]`` float32 (C = 3 for colour/normal, 1 for grey)."""
    is_exr = path.suffix.lower() == ".exr"
    image = read_exr(path) if is_exr else read_ldr(path)
    channels = image.shape[-1]
    t = hwc_to_chw(image)
    if name in _COLOUR_MAPS:
        t = t.expand(3, -1, -1).contiguous() if channels == 1 else t
        return t if is_exr else srgb_decode(t)
    if name == "normal":
        if channels != 3:
            raise FormatError(path, f"normal map has {channels} channel(s); expected 3 (RGB = (n + 1) / 2)")
        return decode_normal(t)
    return t[:1].contiguous()  # metallic / roughness: grey, channel 0


def _area_resize(t: torch.Tensor, size: int) -> torch.Tensor:
    """``[C, H, W]`` -> ``[C, size, size]`` by averaging over each output pixel's area."""
    return F.interpolate(t[None], size=(size, size), mode="area")[0]


def read_matsynth(folder: str | os.PathLike, *, size: int | None = None) -> tuple[Material, dict]:
    """Read a MatSynth material folder (file naming and encodings in the module docstring).

    Args:
        folder: the material's folder.
        size: if given, area-downsample the (square) maps to ``size x size`` after
            decoding to linear values (so 4K maps fit in memory downstream); normals
            are renormalised after averaging. Must not exceed the maps' size.

    Returns:
        ``(material, meta)``: an unbatched CPU float32 ``Material`` (``[C, H, W]``
        maps, linear, validated) and ``{"format": "matsynth", "source", "workflow",
        "files": {map: file name}, "original_size": [H, W]}``.

    Raises:
        FormatError: no folder, missing maps (all named), maps of different sizes,
            wrong channel counts, unreadable files, ``size`` on non-square maps.
        MapError: invalid values (the folder is named).
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise FormatError(folder, "MatSynth folder does not exist" if not folder.exists() else "not a folder")
    found = find_matsynth_maps(folder)

    missing_by_workflow = {workflow: [m for m in needed if m not in found] for workflow, needed in _WORKFLOWS.items()}
    # Prefer diffuse + specular when complete; otherwise metallic-roughness (MatSynth's own).
    if not missing_by_workflow["diffuse-specular"]:
        workflow = "diffuse-specular"
    else:
        workflow = "metallic-roughness"
        missing = missing_by_workflow[workflow]
        if missing:
            alt = missing_by_workflow["diffuse-specular"]
            if len(alt) < len(missing):
                missing = alt
            listing = ", ".join(sorted(p.name for p in found.values())) or "none"
            raise FormatError(
                folder,
                f"missing maps: {', '.join(missing)} (a MatSynth folder needs normal, roughness and "
                f"either diffuse + specular or basecolor + metallic; found files: {listing})",
            )

    needed = _WORKFLOWS[workflow]
    maps = {name: _read_map(name, found[name]) for name in needed}
    height, width = require_same_size(folder, {found[n].name: tuple(maps[n].shape[-2:]) for n in needed})

    if workflow == "diffuse-specular":
        diffuse, specular = maps["diffuse"], maps["specular"]
    else:
        base, metal = maps["basecolor"], maps["metallic"]
        diffuse = base * (1.0 - metal)
        specular = DIELECTRIC_F0 * (1.0 - metal) + base * metal
    normal, roughness = maps["normal"], maps["roughness"]

    if size is not None:
        if not isinstance(size, int) or isinstance(size, bool) or size < 1:
            raise ValueError(f"size must be a positive int, got {size!r}")
        if height != width:
            raise FormatError(folder, f"maps are {height}x{width}, not square; cannot resize to {size}x{size}")
        if size > height:
            raise ValueError(f"size {size} exceeds the maps' size {height}; only downsampling is supported")
        diffuse, specular, roughness = (_area_resize(t, size) for t in (diffuse, specular, roughness))
        normal = F.normalize(_area_resize(normal, size), dim=0, eps=1e-12)  # average, then renormalise

    material = Material(
        diffuse=diffuse.contiguous(),
        normal=normal.contiguous(),
        roughness=roughness.contiguous(),
        specular=specular.contiguous(),
    ).validate(source=str(folder))
    meta = {
        "format": "matsynth",
        "source": str(folder),
        "workflow": workflow,
        "files": {name: found[name].name for name in needed},
        "original_size": [height, width],
    }
    return material, meta
