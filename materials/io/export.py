"""Exports people load without thinking: EXR + PNG maps, a metallic-roughness set, a GLB.

``export_material(folder, material)`` writes, atomically (layout and colour spaces also
recorded in ``export.json``)::

    diffuse.exr   / diffuse.png     albedo             EXR linear  | PNG sRGB
    normal.exr    / normal.png      tangent normal     EXR signed x, y, z | PNG (n + 1) / 2
    roughness.exr / roughness.png   roughness          linear (alpha = roughness^2, as glTF)
    specular.exr  / specular.png    F0 colour          EXR linear  | PNG sRGB
    basecolor.exr / basecolor.png   glTF base colour   EXR linear  | PNG sRGB
    metallic.exr  / metallic.png    glTF metallic      linear
    metallic_roughness.png          glTF packed: R = 1 (unused), G roughness, B metallic; linear
    material.glb                    glTF 2.0 binary: a textured plane (``materials.io.gltf``)

Colour maps (diffuse, specular, basecolor) are sRGB-encoded in 8 bits, as every viewer
and texture tool expects; data maps (normal, roughness, metallic) are linear. EXRs are
always linear float32. Normal maps are OpenGL (+y up, green up) by default;
``normal_convention="directx"`` flips the green channel (and y in the EXR) for DirectX /
Unreal-style tools. The GLB always uses OpenGL normals, as glTF requires.

Metallic-roughness from diffuse/specular (``metallic_roughness``)
-----------------------------------------------------------------
Our BRDF (SPEC section 2) has albedo D and F0 = S (RGB); its diffuse reflectance at
normal incidence is D (1 - S). glTF's metallic-roughness BRDF with base colour c and
metallic m has F0 = a (1 - m) + c m with the dielectric a = 0.04 (ior 1.5), and diffuse
reflectance c (1 - m) (1 - a). Matching both on luminance (Rec. 709 weights),
d = Y(D (1 - S)) and s = Y(S), and eliminating c gives one quadratic in m:

    a m^2 + (d / (1 - a) + s - 2 a) m + (a - s) = 0,

whose root in [0, 1] is the metallic (m = 0 when s <= a: no more specular than a
dielectric). The base colour per channel then comes from either equation,

    c_d = D (1 - S) / ((1 - a)(1 - m))      (reliable when m is small)
    c_s = (S - a (1 - m)) / m               (reliable when m is near 1)

blended as c = (1 - m^2) c_d + m^2 c_s (each is divided by a factor that vanishes at
the other end), clamped to [0, 1]. Roughness is copied: both use alpha = roughness^2.

Exact (to 8 bits) for dielectrics with a grey F0 of 0.04 (m = 0, c = D) and for metals
with no diffuse (m = 1, c = S). Between them it is an approximation: a dielectric with
F0 != 0.04 can only be expressed as partly metallic, which tints its highlight; the
luminance match leaves per-channel errors for coloured specular; and glTF couples
Fresnel and diffuse at grazing angles differently from our model (the match is at
normal incidence). ``KHR_materials_specular`` fixes most of the first two for viewers
that read it: the GLB adds a dielectric F0 colour f as ``specularColorTexture`` (sRGB)
with ``specularColorFactor`` = 1 / 0.04 = 25, because the extension's F0 is
min(0.04 * factor * texture, 1). The exact choice f* = (S - m c) / (1 - m) (so that
(1 - m) f* + m c = S) is divided by 1 - m and also darkens the diffuse (the extension
scales it by 1 - max_rgb f), so near-metallic pixels get large errors; f is therefore
faded to 0.04 as m grows: f = (1 - m) f* + m 0.04.

Measured (``material_from_metallic_roughness`` is the inverse, what a viewer shows at
normal incidence in our terms): 16 procedural materials, 64 px, re-rendered under the
8 evaluation lights, tone-mapped PSNR against the original maps: core metallic-roughness
only, median 38.8 dB (worst 24.4); with the extension, median 46.7 dB (worst 25.6; at
most 0.8 dB below core-only on any material); with the unfaded f*, median 45.6 dB but
worst 21.2 dB, up to 4.8 dB below core-only on the metallic ones.

A tileable option is not offered: making maps tile needs synthesis across the seam
(e.g. a blended or graph-cut overlap), which changes the material near the edges; its
honest measure would be the seam error (the mean |difference| across the wrapped edge
against the mean between interior neighbours) next to the map error it costs, and that
is work of its own.
"""

from __future__ import annotations

import io
import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from PIL import Image

from kernels.tonemap import srgb_encode
from materials.io.atomic import atomic_folder
from materials.io.encoding import chw_to_hwc, encode_normal
from materials.io.exr import write_exr
from materials.io.gltf import textured_plane, write_glb
from materials.io.png import write_png
from materials.types import MapError, Material

__all__ = [
    "MetallicRoughness",
    "metallic_roughness",
    "material_from_metallic_roughness",
    "export_material",
    "EXPORT_JSON",
    "NORMAL_CONVENTIONS",
    "DIELECTRIC_F0",
    "SPECULAR_COLOR_FACTOR",
]

EXPORT_JSON = "export.json"
NORMAL_CONVENTIONS = ("opengl", "directx")
#: glTF's dielectric F0: ((ior - 1) / (ior + 1))^2 with its default ior 1.5.
DIELECTRIC_F0 = 0.04
#: KHR_materials_specular: F0 = min(0.04 * factor * texture, 1), so 1 / 0.04 makes the
#: texture value the F0 itself.
SPECULAR_COLOR_FACTOR = 1.0 / DIELECTRIC_F0
# Rec. 709 / sRGB luminance weights of linear R, G, B (ITU-R BT.709).
_LUMA = (0.2126, 0.7152, 0.0722)
# Guard for the divisions by m and 1 - m: far below one 8-bit step, so it only matters
# where the other branch of the blend has all the weight.
_EPS = 1e-6


@dataclass(frozen=True)
class MetallicRoughness:
    """glTF-style maps, linear, ``[..., C, H, W]`` float32.

    Attributes:
        basecolor: ``[..., 3, H, W]`` base colour in [0, 1] (linear; files store sRGB).
        metallic: ``[..., 1, H, W]`` in [0, 1].
        roughness: ``[..., 1, H, W]`` in [0, 1] (alpha = roughness^2).
        normal: ``[..., 3, H, W]`` unit, OpenGL tangent space.
        specular_color: ``[..., 3, H, W]`` dielectric F0 colour for KHR_materials_specular.
    """

    basecolor: torch.Tensor
    metallic: torch.Tensor
    roughness: torch.Tensor
    normal: torch.Tensor
    specular_color: torch.Tensor


def _luminance(x: torch.Tensor) -> torch.Tensor:
    w = x.new_tensor(_LUMA).view(3, 1, 1)
    return (x * w).sum(dim=-3, keepdim=True)


def metallic_roughness(material: Material) -> MetallicRoughness:
    """Convert diffuse/specular maps to metallic-roughness (formula in the module docstring).

    Args:
        material: linear maps ``[..., C, H, W]`` (diffuse, specular, roughness in [0, 1]).

    Returns:
        ``MetallicRoughness`` of the same shape, values in [0, 1].
    """
    a = DIELECTRIC_F0
    diffuse, specular = material.diffuse.clamp(0, 1), material.specular.clamp(0, 1)
    d = _luminance(diffuse * (1 - specular))
    s = _luminance(specular)
    b = d / (1 - a) + s - 2 * a
    c = a - s
    root = (b * b - 4 * a * c).clamp_min(0).sqrt()
    # The root (-b + sqrt) / (2a), written without cancellation when b > 0.
    m = torch.where(b > 0, -2 * c / (b + root).clamp_min(_EPS), (root - b) / (2 * a))
    m = torch.where(s <= a, torch.zeros_like(m), m).clamp(0, 1)
    from_diffuse = diffuse * (1 - specular) / ((1 - a) * (1 - m).clamp_min(_EPS))
    from_specular = (specular - a * (1 - m)) / m.clamp_min(_EPS)
    w = m * m
    base = ((1 - w) * from_diffuse + w * from_specular).clamp(0, 1)
    # The dielectric F0 that makes (1 - m) f + m c = S, faded to 0.04 as m -> 1 (see the
    # module docstring for why and what it measured).
    exact = ((specular - m * base) / (1 - m).clamp_min(_EPS)).clamp(0, 1)
    dielectric = (1 - m) * exact + m * a
    return MetallicRoughness(
        basecolor=base,
        metallic=m,
        roughness=material.roughness.clamp(0, 1),
        normal=material.normal,
        specular_color=dielectric,
    )


def material_from_metallic_roughness(mr: MetallicRoughness, *, specular_extension: bool = True) -> Material:
    """What a glTF viewer shows, in our model's terms (matched at normal incidence).

    F0 = (1 - m) f + m c with f the extension's dielectric F0 (or 0.04 without it);
    diffuse reflectance c (1 - m) (1 - max_rgb f) (KHR_materials_specular scales the
    dielectric's diffuse by one minus its largest F0 component), turned back into our
    albedo D = reflectance / (1 - F0).
    """
    m, c = mr.metallic, mr.basecolor
    f = mr.specular_color if specular_extension else torch.full_like(c, DIELECTRIC_F0)
    f0 = (1 - m) * f + m * c
    reflectance = c * (1 - m) * (1 - f.amax(dim=-3, keepdim=True))
    diffuse = (reflectance / (1 - f0).clamp_min(_EPS)).clamp(0, 1)
    return Material(diffuse=diffuse, normal=mr.normal, roughness=mr.roughness, specular=f0.clamp(0, 1))


# ---------------------------------------------------------------------- files
def _png_bytes(values: torch.Tensor) -> bytes:
    """``[C, H, W]`` values in [0, 1] (C = 1 or 3) -> 8-bit PNG bytes."""
    codes = np.round(np.clip(chw_to_hwc(values), 0.0, 1.0) * 255.0).astype(np.uint8)
    image = Image.fromarray(codes[..., 0] if codes.shape[-1] == 1 else codes)
    buf = io.BytesIO()
    image.save(buf, format="PNG")
    return buf.getvalue()


def _flip_green(normal: torch.Tensor) -> torch.Tensor:
    return normal * normal.new_tensor([1.0, -1.0, 1.0]).view(3, 1, 1)


_DESCRIPTIONS = {
    "diffuse": "albedo",
    "specular": "F0 colour (specular albedo)",
    "basecolor": "glTF base colour",
    "roughness": "roughness, alpha = roughness^2",
    "metallic": "glTF metallic",
}


def export_material(
    folder: str | os.PathLike,
    material: Material,
    *,
    normal_convention: str = "opengl",
    glb: bool = True,
    name: str = "material",
    provenance: dict | None = None,
    overwrite: bool = False,
) -> Path:
    """Write a material as artists' maps, a metallic-roughness set and a GLB (module docstring).

    Args:
        folder: target folder, written atomically (marker ``export.json``).
        material: one material, ``[C, H, W]`` linear maps (validated first).
        normal_convention: ``"opengl"`` (default) or ``"directx"`` for the normal files.
        glb: also write ``material.glb``.
        name: the material's name inside the GLB.
        provenance: JSON-serialisable notes stored in ``export.json``.
        overwrite: replace a folder this function wrote before.

    Returns:
        The folder.
    """
    folder = Path(folder)
    if normal_convention not in NORMAL_CONVENTIONS:
        raise ValueError(f"normal_convention must be one of {NORMAL_CONVENTIONS}, got {normal_convention!r}")
    if material.batch_shape:
        raise MapError(f"{folder}: export_material takes one material [C, H, W], got batch {material.batch_shape}")
    material = material.to("cpu", torch.float32).validate(source=f"export_material({folder})")
    mr = metallic_roughness(material)
    height, width = material.shape
    colour = {"diffuse": material.diffuse, "specular": material.specular, "basecolor": mr.basecolor}
    data = {"roughness": material.roughness, "metallic": mr.metallic}
    normal = material.normal if normal_convention == "opengl" else _flip_green(material.normal)
    files: dict[str, str] = {}
    with atomic_folder(folder, overwrite=overwrite, marker=EXPORT_JSON) as tmp:
        for key, t in colour.items():
            what = _DESCRIPTIONS[key]
            write_exr(tmp / f"{key}.exr", chw_to_hwc(t))
            write_png(tmp / f"{key}.png", chw_to_hwc(srgb_encode(t)))
            files[f"{key}.exr"] = f"{what}; float32 linear"
            files[f"{key}.png"] = f"{what}; 8-bit sRGB-encoded (IEC 61966-2-1)"
        for key, t in data.items():
            what = _DESCRIPTIONS[key]
            write_exr(tmp / f"{key}.exr", chw_to_hwc(t))
            write_png(tmp / f"{key}.png", chw_to_hwc(t))
            files[f"{key}.exr"] = f"{what}; float32 linear"
            files[f"{key}.png"] = f"{what}; 8-bit linear"
        write_exr(tmp / "normal.exr", chw_to_hwc(normal))
        write_png(tmp / "normal.png", chw_to_hwc(encode_normal(normal)))
        convention = "OpenGL (+y up, green up)" if normal_convention == "opengl" else "DirectX (+y down, green flipped)"
        files["normal.exr"] = f"tangent-space unit normal x, y, z, {convention}; float32 signed"
        files["normal.png"] = f"tangent-space normal, {convention}; 8-bit linear (n + 1) / 2"
        packed = torch.cat([torch.ones_like(mr.roughness), mr.roughness, mr.metallic])
        write_png(tmp / "metallic_roughness.png", chw_to_hwc(packed))
        files["metallic_roughness.png"] = "glTF packed: R unused (1), G roughness, B metallic; 8-bit linear"
        if glb:
            textures = {
                "baseColor": _png_bytes(srgb_encode(mr.basecolor)),
                "metallicRoughness": _png_bytes(packed),
                "normal": _png_bytes(encode_normal(material.normal)),
                "specularColor": _png_bytes(srgb_encode(mr.specular_color)),
            }
            gltf, binary = textured_plane(
                textures, aspect=width / height, name=name, specular_color_factor=SPECULAR_COLOR_FACTOR
            )
            write_glb(tmp / "material.glb", gltf, binary)
            files["material.glb"] = (
                "glTF 2.0 binary: a 1 m plane (XY, facing +Z) with pbrMetallicRoughness, an OpenGL normal "
                "map and KHR_materials_specular (specularColorTexture sRGB, specularColorFactor 25)"
            )
        info = {
            "height": height,
            "width": width,
            "normal_convention": normal_convention,
            "files": files,
            "metallic_roughness": "converted from diffuse/specular: see materials/io/export.py",
            "provenance": dict(provenance or {}),
        }
        (tmp / EXPORT_JSON).write_text(json.dumps(info, indent=2) + "\n", encoding="utf-8")
    return folder
