"""The project's own folders: a material folder and a capture folder.

Material folder (``write_material`` / ``read_material``)::

    material.json    {"format_version": 1, "preset", "plane_size", "height", "width",
                      "files": {file: encoding}, "provenance": {...}}
    diffuse.exr      float32 R,G,B  linear albedo in [0, 1]
    normal.exr       float32 R,G,B  signed unit x, y, z (tangent space, OpenGL)
    roughness.exr    float32 Y      linear roughness in [0, 1] (alpha = roughness^2)
    specular.exr     float32 R,G,B  linear F0 in [0, 1]
    diffuse.png, specular.png   8-bit sRGB-encoded   (twins for people and viewers)
    roughness.png               8-bit linear grey
    normal.png                  8-bit (n + 1) / 2

The EXRs are the data (exact round trip); the PNGs are views. A folder holding only
the PNG twins (e.g. edited by hand) still reads, to within 8-bit precision.

Capture folder (``write_capture`` / ``read_capture``)::

    capture.json  {"format_version": 1, "preset", "plane_size", "intensity",
                   "images": ["0.png", ...], "light_pos": [[x, y, z], ...],
                   "camera_pos": [[x, y, z], ...], "tone_map": ..., "meta": {...}}
    0.png ... N-1.png   8-bit RGB, tone-mapped: clamp(x, 0, 1) ** (1/2.2) (SPEC section 2)

Capture PNGs are 8-bit, so radiance above 1 is clipped on write and everything is
quantised; reading undoes the tone map (``inverse_tonemap``) back to linear radiance.

Both folders are written atomically: into a hidden temporary sibling, then renamed.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any

import torch

from kernels.presets import PRESETS
from kernels.tonemap import inverse_tonemap, srgb_decode, srgb_encode, tonemap
from materials.io.atomic import atomic_folder
from materials.io.encoding import chw_to_hwc, decode_normal, encode_normal, hwc_to_chw
from materials.io.errors import FormatError, require_same_size
from materials.io.exr import GREY, RGB, read_exr, write_exr
from materials.io.png import read_png, write_png
from materials.types import Capture, MapError, Material

__all__ = [
    "write_material",
    "read_material",
    "write_capture",
    "read_capture",
    "MATERIAL_JSON",
    "CAPTURE_JSON",
    "FORMAT_VERSION",
]

MATERIAL_JSON = "material.json"
CAPTURE_JSON = "capture.json"
FORMAT_VERSION = 1

# map -> (EXR channels, PNG encoding name). Encodings are described in material.json.
_MAPS: dict[str, tuple[tuple[str, ...], str]] = {
    "diffuse": (RGB, "srgb"),
    "normal": (RGB, "normal"),
    "roughness": (GREY, "linear"),
    "specular": (RGB, "srgb"),
}
# What each map's EXR holds (material.json "files"; the PNG twins use _ENCODING_NOTES).
_EXR_NOTES = {
    "diffuse": "float32 R,G,B linear albedo in [0, 1]",
    "normal": "float32 R,G,B signed unit x, y, z (tangent space, OpenGL: +y up)",
    "roughness": "float32 Y linear roughness in [0, 1] (alpha = roughness^2)",
    "specular": "float32 R,G,B linear F0 in [0, 1]",
}
_ENCODING_NOTES = {
    "srgb": "8-bit sRGB-encoded (IEC 61966-2-1)",
    "normal": "8-bit (n + 1) / 2, OpenGL tangent space",
    "linear": "8-bit linear grey",
}
_TONE_MAP_NOTE = "8-bit RGB, clamp(x, 0, 1) ** (1/2.2) of linear radiance"


# ---------------------------------------------------------------------- helpers
def _encode_png(name: str, t: torch.Tensor) -> torch.Tensor:
    encoding = _MAPS[name][1]
    if encoding == "srgb":
        return srgb_encode(t)
    if encoding == "normal":
        return encode_normal(t)
    return t.clamp(0.0, 1.0)


def _decode_png(name: str, t: torch.Tensor) -> torch.Tensor:
    encoding = _MAPS[name][1]
    if encoding == "srgb":
        return srgb_decode(t)
    if encoding == "normal":
        return decode_normal(t)
    return t


def _load_json(path: Path, what: str) -> dict:
    if not path.is_file():
        raise FormatError(path.parent, f"no {path.name}: not a {what} folder written by this project")
    try:
        meta = json.loads(path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise FormatError(path, f"not valid JSON: {err}") from err
    if not isinstance(meta, dict):
        raise FormatError(path, f"expected a JSON object, found {type(meta).__name__}")
    version = meta.get("format_version")
    if version != FORMAT_VERSION:
        raise FormatError(path, f"format_version is {version!r}; this reader understands {FORMAT_VERSION}")
    preset = meta.get("preset")
    if preset not in PRESETS:
        raise FormatError(path, f"unknown preset {preset!r}; known: {sorted(PRESETS)}")
    plane_size = meta.get("plane_size")
    if plane_size is not None and not (_is_number(plane_size) and plane_size > 0):
        raise FormatError(path, f"plane_size must be a positive number or null, got {plane_size!r}")
    return meta


def _is_number(x: Any) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)


def _json_dump(path: Path, obj: dict) -> None:
    path.write_text(json.dumps(obj, indent=2, sort_keys=False) + "\n", encoding="utf-8")


def _check_json_serialisable(obj: Any, what: str) -> None:
    try:
        json.dumps(obj)
    except (TypeError, ValueError) as err:
        raise TypeError(f"{what} must be JSON-serialisable: {err}") from err


# ---------------------------------------------------------------------- materials
def write_material(
    folder: str | os.PathLike,
    material: Material,
    *,
    preset: str = "dgrsise",
    plane_size: float | None = None,
    provenance: dict | None = None,
    overwrite: bool = False,
) -> Path:
    """Write one material as an EXR + PNG folder (layout in the module docstring).

    Args:
        folder: target folder; created atomically (its parent is created if needed).
        material: unbatched maps ``[C, H, W]`` (linear, unit normals; validated first).
        preset: render preset the maps are meant for (``kernels.PRESETS``).
        plane_size: side of the material plane in the preset's units (None: the preset's).
        provenance: JSON-serialisable notes (generator seed, source file, ...).
        overwrite: replace an existing material folder (never an unrelated folder).

    Returns:
        The folder path.

    Raises:
        MapError: batched material or invalid values. FileExistsError: see ``overwrite``.
    """
    folder = Path(folder)
    if material.batch_shape:
        raise MapError(f"{folder}: write_material takes one material [C, H, W], got batch {material.batch_shape}")
    material.validate(source=f"write_material({folder})")
    if preset not in PRESETS:
        raise ValueError(f"unknown preset {preset!r}; known: {sorted(PRESETS)}")
    if plane_size is not None and not (_is_number(plane_size) and plane_size > 0):
        raise ValueError(f"plane_size must be a positive number or None, got {plane_size!r}")
    provenance = dict(provenance or {})
    _check_json_serialisable(provenance, "provenance")

    maps = material.to("cpu", torch.float32).maps()
    height, width = material.shape
    files: dict[str, str] = {}
    with atomic_folder(folder, overwrite=overwrite, marker=MATERIAL_JSON) as tmp:
        for name, (channels, encoding) in _MAPS.items():
            write_exr(tmp / f"{name}.exr", chw_to_hwc(maps[name]), channels)
            write_png(tmp / f"{name}.png", chw_to_hwc(_encode_png(name, maps[name])))
            files[f"{name}.exr"] = _EXR_NOTES[name]
            files[f"{name}.png"] = _ENCODING_NOTES[encoding]
        _json_dump(
            tmp / MATERIAL_JSON,
            {
                "format_version": FORMAT_VERSION,
                "preset": preset,
                "plane_size": None if plane_size is None else float(plane_size),
                "height": height,
                "width": width,
                "files": files,
                "provenance": provenance,
            },
        )
    return folder


def read_material(folder: str | os.PathLike) -> tuple[Material, dict]:
    """Read a material folder written by :func:`write_material`.

    Each map is read from its EXR; a map whose EXR is absent is read from its PNG twin
    (decoded: sRGB for diffuse/specular, (n+1)/2 for normals), to 8-bit precision.

    Returns:
        ``(material, meta)``: an unbatched CPU float32 ``Material`` (``[C, H, W]``
        maps, linear, validated) and the ``material.json`` contents plus ``"sources"``
        (map -> file it was read from) and ``"format": "ours"``.

    Raises:
        FormatError: not a folder, no/invalid ``material.json``, missing maps, maps of
            different sizes or channel counts. MapError: invalid values (file named).
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise FormatError(folder, "material folder does not exist" if not folder.exists() else "not a folder")
    meta = _load_json(folder / MATERIAL_JSON, "material")

    maps: dict[str, torch.Tensor] = {}
    sources: dict[str, str] = {}
    missing = []
    for name, (channels, _) in _MAPS.items():
        exr_path, png_path = folder / f"{name}.exr", folder / f"{name}.png"
        if exr_path.exists():
            maps[name] = hwc_to_chw(read_exr(exr_path, channels))
            sources[name] = exr_path.name
        elif png_path.exists():
            image = read_png(png_path)
            if image.shape[-1] != len(channels) and not (name == "roughness" and image.shape[-1] == 3):
                raise FormatError(png_path, f"{name} map has {image.shape[-1]} channels; expected {len(channels)}")
            # A grey roughness map re-saved as RGB by an editor: its channels are equal.
            t = hwc_to_chw(image[..., :1] if name == "roughness" else image)
            maps[name] = _decode_png(name, t)
            sources[name] = png_path.name
        else:
            missing.append(name)
    if missing:
        raise FormatError(folder, f"missing maps: {', '.join(missing)} (looked for <map>.exr, then <map>.png)")
    require_same_size(folder, {sources[k]: tuple(v.shape[-2:]) for k, v in maps.items()})
    material = Material(**maps).validate(source=str(folder))
    return material, {**meta, "format": "ours", "sources": sources}


# ---------------------------------------------------------------------- captures
def write_capture(folder: str | os.PathLike, capture: Capture, *, overwrite: bool = False) -> Path:
    """Write a capture as tone-mapped 8-bit PNGs plus ``capture.json``, atomically.

    Args:
        folder: target folder (its parent is created if needed).
        capture: ``images [V, 3, H, W]`` linear radiance with per-image positions.
            Radiance above 1 is clipped by the 8-bit tone map.
        overwrite: replace an existing capture folder (never an unrelated folder).

    Returns:
        The folder path.
    """
    folder = Path(folder)
    meta = dict(capture.meta)
    _check_json_serialisable(meta, "Capture.meta")
    images = tonemap(capture.images.detach().to("cpu", torch.float32))
    names = [f"{i}.png" for i in range(capture.num_views)]
    with atomic_folder(folder, overwrite=overwrite, marker=CAPTURE_JSON) as tmp:
        for name, image in zip(names, images):
            write_png(tmp / name, chw_to_hwc(image))
        _json_dump(
            tmp / CAPTURE_JSON,
            {
                "format_version": FORMAT_VERSION,
                "preset": capture.preset,
                "plane_size": capture.plane_size,
                "intensity": None if capture.intensity is None else [float(v) for v in capture.intensity],
                "images": names,
                "light_pos": capture.light_pos.detach().cpu().double().tolist(),
                "camera_pos": capture.camera_pos.detach().cpu().double().tolist(),
                "tone_map": _TONE_MAP_NOTE,
                "meta": meta,
            },
        )
    return folder


def _positions(json_path: Path, meta: dict, key: str, count: int) -> torch.Tensor:
    rows = meta.get(key)
    if not isinstance(rows, list):
        raise FormatError(json_path, f"{key} must be a list of [x, y, z], found {type(rows).__name__}")
    if len(rows) != count:
        raise FormatError(json_path, f"mismatched counts: {count} images but {len(rows)} {key} entries")
    for i, row in enumerate(rows):
        if not (isinstance(row, list) and len(row) == 3 and all(_is_number(v) for v in row)):
            raise FormatError(json_path, f"{key}[{i}] must be three finite numbers, found {row!r}")
    return torch.tensor(rows, dtype=torch.float32).reshape(count, 3)


def read_capture(folder: str | os.PathLike) -> Capture:
    """Read a capture folder written by :func:`write_capture`.

    Returns:
        A CPU float32 ``Capture``: ``images [V, 3, H, W]`` linear radiance in [0, 1]
        (tone map undone), positions from ``capture.json``; ``meta`` is the stored
        meta plus ``"format"`` and ``"source"``.

    Raises:
        FormatError: no/invalid ``capture.json``, missing images, mismatched counts,
            images of different sizes or not RGB. MapError: invalid positions.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise FormatError(folder, "capture folder does not exist" if not folder.exists() else "not a folder")
    json_path = folder / CAPTURE_JSON
    meta = _load_json(json_path, "capture")
    names = meta.get("images")
    if not (isinstance(names, list) and names and all(isinstance(n, str) for n in names)):
        raise FormatError(json_path, "images must be a non-empty list of file names")
    light_pos = _positions(json_path, meta, "light_pos", len(names))
    camera_pos = _positions(json_path, meta, "camera_pos", len(names))
    intensity = meta.get("intensity")
    if intensity is not None:
        if not (isinstance(intensity, list) and len(intensity) == 3 and all(_is_number(v) for v in intensity)):
            raise FormatError(json_path, f"intensity must be three numbers or null, found {intensity!r}")
        intensity = tuple(float(v) for v in intensity)

    images, sizes = [], {}
    for name in names:
        path = folder / name
        image = read_png(path)
        if image.shape[-1] != 3:
            raise FormatError(path, f"capture image has {image.shape[-1]} channel(s); expected 3 (RGB)")
        sizes[name] = image.shape[:2]
        images.append(hwc_to_chw(image))
    require_same_size(folder, sizes)
    stored_meta = meta.get("meta") or {}
    try:
        return Capture(
            images=inverse_tonemap(torch.stack(images)),
            light_pos=light_pos,
            camera_pos=camera_pos,
            preset=meta["preset"],
            plane_size=None if meta.get("plane_size") is None else float(meta["plane_size"]),
            intensity=intensity,
            meta={**stored_meta, "format": "ours", "source": str(folder)},
        )
    except MapError as err:
        raise MapError(f"{json_path}: {err}") from err
