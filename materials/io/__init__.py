"""File formats: the only place where maps and photos are decoded and encoded.

In memory everything is linear (SPEC section 2; ``materials.types``); files say their
own encoding and each reader undoes it at the boundary, then validates the result
(``Material.validate``), naming the file in every error.

Formats:

================  ===========================================  ==================================
name              on disk                                      functions
================  ===========================================  ==================================
``ours``          folder: EXR maps + PNG twins + material.json  ``write_material`` / ``read_material``
``ours``          folder: tone-mapped PNGs + capture.json       ``write_capture`` / ``read_capture``
``inria``         PNG of five panels (Deschaintre 2018)          ``write_inria`` / ``read_inria``
``matsynth``      folder of basecolor/normal/... files           ``read_matsynth``
``materialgan``   folder of photos + camera_pos.txt ...          ``read_materialgan``
photo             one PNG (8/16-bit), JPEG or EXR photo          ``read_photo`` (-> ``Photo``)
export            EXR + PNG maps, metallic-roughness, ``.glb``   ``export_material``
glTF              ``.glb`` container (json + struct)            ``write_glb`` / ``read_glb``
================  ===========================================  ==================================

``load_material`` / ``load_capture`` detect the format; ``save_material`` /
``save_capture`` write ours (or INRIA). Errors: ``FormatError`` for files,
``materials.types.MapError`` for values.

Dependency direction: ``errors`` <- ``atomic`` <- ``exr``, ``png``, ``gltf`` <- the format
modules (``ours``, ``inria``, ``matsynth``, ``materialgan``, ``photo``, ``export``) <- this
package's loaders.
Colour curves come from ``kernels.tonemap``; normal encoding from ``encoding``.

Example:
    >>> material, meta = load_material("scans/wood")  # doctest: +SKIP
    >>> save_material("out/wood", material, provenance={"from": meta["format"]})  # doctest: +SKIP
"""

from __future__ import annotations

import os
from pathlib import Path

import torch

from materials.io.encoding import decode_normal, encode_normal
from materials.io.errors import FormatError
from materials.io.export import export_material, metallic_roughness
from materials.io.exr import read_exr, write_exr
from materials.io.gltf import read_glb, write_glb
from materials.io.inria import read_inria, write_inria
from materials.io.materialgan import find_numbered_images, read_materialgan
from materials.io.matsynth import MATSYNTH_MAPS, find_matsynth_maps, read_matsynth
from materials.io.ours import (
    CAPTURE_JSON,
    MATERIAL_JSON,
    read_capture,
    read_material,
    write_capture,
    write_material,
)
from materials.io.photo import Photo, read_photo
from materials.io.png import read_ldr, read_png, write_png
from materials.types import Capture, Material

__all__ = [
    "FormatError",
    "load_material",
    "load_capture",
    "save_material",
    "save_capture",
    "detect_material_format",
    "detect_capture_format",
    "MATERIAL_FORMATS",
    "CAPTURE_FORMATS",
    "read_exr",
    "write_exr",
    "read_png",
    "read_ldr",
    "write_png",
    "encode_normal",
    "decode_normal",
    "read_material",
    "write_material",
    "read_capture",
    "write_capture",
    "read_inria",
    "write_inria",
    "read_matsynth",
    "read_materialgan",
    "Photo",
    "read_photo",
    "export_material",
    "metallic_roughness",
    "read_glb",
    "write_glb",
]

MATERIAL_FORMATS = ("ours", "matsynth", "inria")
CAPTURE_FORMATS = ("ours", "materialgan")

_MATERIAL_LOOKED_FOR = (
    f"a folder with {MATERIAL_JSON} (ours), a folder of MatSynth maps "
    f"({'/'.join(MATSYNTH_MAPS)} as .png/.jpg/.exr), or an INRIA .png of five panels"
)
_CAPTURE_LOOKED_FOR = (
    f"our capture folder: tone-mapped 8-bit PNGs 0.png ... N-1.png plus {CAPTURE_JSON} listing each image's "
    "light_pos and camera_pos (README, 'Capture folder format'); or a MaterialGAN folder "
    "(0.png ... N-1.png with camera_pos.txt)"
)


def detect_material_format(path: str | os.PathLike) -> str:
    """Name the material format at ``path`` (one of ``MATERIAL_FORMATS``).

    Raises:
        FormatError: nothing there, or nothing recognisable (says what was looked for).
    """
    path = Path(path)
    if not path.exists():
        raise FormatError(path, f"does not exist; looked for {_MATERIAL_LOOKED_FOR}")
    if path.is_dir():
        if (path / MATERIAL_JSON).is_file():
            return "ours"
        if find_matsynth_maps(path):
            return "matsynth"
    elif path.suffix.lower() == ".png":
        return "inria"
    raise FormatError(path, f"unknown material format; looked for {_MATERIAL_LOOKED_FOR}")


def detect_capture_format(path: str | os.PathLike) -> str:
    """Name the capture format at ``path`` (one of ``CAPTURE_FORMATS``).

    Raises:
        FormatError: nothing there, or nothing recognisable (says what was looked for).
    """
    path = Path(path)
    if not path.exists():
        raise FormatError(path, f"does not exist; looked for {_CAPTURE_LOOKED_FOR}")
    if not path.is_dir():
        raise FormatError(path, f"is a file; a capture is a folder: {_CAPTURE_LOOKED_FOR}")
    if (path / CAPTURE_JSON).is_file():
        return "ours"
    if (path / "camera_pos.txt").is_file():
        return "materialgan"
    found = "numbered photos but " if find_numbered_images(path) else ""
    raise FormatError(path, f"unknown capture format ({found}no {CAPTURE_JSON}); expected {_CAPTURE_LOOKED_FOR}")


def load_material(path: str | os.PathLike, fmt: str | None = None, **kwargs) -> tuple[Material, dict]:
    """Read a material in any supported format.

    Args:
        path: folder or file.
        fmt: ``"ours"``, ``"matsynth"`` or ``"inria"``; None detects it.
        **kwargs: passed to the reader (``size=`` for MatSynth).

    Returns:
        ``(material, meta)``: unbatched CPU float32 linear maps ``[C, H, W]``
        (validated) and a dict with at least ``"format"``. For INRIA, ``meta["render"]``
        holds the render panel, ``[3, H, W]`` linear radiance.
    """
    fmt = detect_material_format(path) if fmt is None else fmt
    if fmt == "ours":
        return read_material(path, **kwargs)
    if fmt == "matsynth":
        return read_matsynth(path, **kwargs)
    if fmt == "inria":
        material, render = read_inria(path, **kwargs)
        return material, {"format": "inria", "source": str(path), "render": render}
    raise FormatError(path, f"unknown material format {fmt!r}; known: {', '.join(MATERIAL_FORMATS)}")


def load_capture(path: str | os.PathLike, fmt: str | None = None) -> Capture:
    """Read a capture in any supported format (``"ours"`` or ``"materialgan"``; None detects).

    Returns:
        A CPU float32 ``Capture`` (linear radiance ``images [V, 3, H, W]``).
    """
    fmt = detect_capture_format(path) if fmt is None else fmt
    if fmt == "ours":
        return read_capture(path)
    if fmt == "materialgan":
        return read_materialgan(path)
    raise FormatError(path, f"unknown capture format {fmt!r}; known: {', '.join(CAPTURE_FORMATS)}")


def save_material(
    path: str | os.PathLike,
    material: Material,
    fmt: str = "ours",
    *,
    render: torch.Tensor | None = None,
    **kwargs,
) -> Path:
    """Write one material: ``"ours"`` (``write_material`` keywords) or ``"inria"`` (needs ``render``)."""
    if fmt == "ours":
        if render is not None:
            raise ValueError("render is only stored by the 'inria' format")
        return write_material(path, material, **kwargs)
    if fmt == "inria":
        if render is None:
            raise ValueError("the 'inria' format stores a render panel: pass render=[3, H, W] linear radiance")
        if kwargs:
            raise TypeError(f"unexpected keywords for the 'inria' format: {sorted(kwargs)}")
        return write_inria(path, material, render)
    raise FormatError(path, f"cannot write material format {fmt!r}; writable: ours, inria")


def save_capture(path: str | os.PathLike, capture: Capture, fmt: str = "ours", **kwargs) -> Path:
    """Write one capture in our format (``write_capture`` keywords, e.g. ``overwrite``)."""
    if fmt == "ours":
        return write_capture(path, capture, **kwargs)
    raise FormatError(path, f"cannot write capture format {fmt!r}; writable: ours")
