"""Exports: maps with stated colour spaces, the metallic-roughness conversion, and the
GLB re-read (header, alignment, accessors, textures, factors, KHR_materials_specular)."""

from __future__ import annotations

import io
import json
import struct

import numpy as np
import pytest
import torch
from PIL import Image

from kernels.tonemap import srgb_decode
from materials.io import FormatError, read_exr, read_glb
from materials.io.export import (
    DIELECTRIC_F0,
    EXPORT_JSON,
    SPECULAR_COLOR_FACTOR,
    export_material,
    material_from_metallic_roughness,
    metallic_roughness,
)
from materials.io.gltf import CHUNK_BIN, CHUNK_JSON, SPECULAR_EXTENSION, pack_glb
from materials.types import Material

#: One 8-bit code (1/255), plus float32 slack, bounds what a PNG round trip may move a
#: stored value; decoded sRGB colours may move more in the linear domain, so compare
#: encoded values.
CODE_TOL = 1.0 / 255.0 + 1e-6
#: The conversion's divisions are guarded by 1e-6 and done in float32: "exact" cases
#: agree to this.
EXACT_TOL = 1e-5
H, W = 12, 20  # non-square on purpose: the plane's aspect follows the maps


def make_material(seed: int = 0, h: int = H, w: int = W) -> Material:
    gen = torch.Generator().manual_seed(seed)
    n = torch.nn.functional.normalize(
        torch.rand(3, h, w, generator=gen) - torch.tensor([0.5, 0.5, -1.0]).view(3, 1, 1), dim=0
    )
    return Material(
        diffuse=torch.rand(3, h, w, generator=gen),
        normal=n,
        roughness=0.1 + 0.9 * torch.rand(1, h, w, generator=gen),
        specular=0.6 * torch.rand(3, h, w, generator=gen),
    )


def png_values(data: bytes) -> np.ndarray:
    """PNG bytes -> ``[H, W, C]`` float32 codes / 255."""
    with Image.open(io.BytesIO(data)) as img:
        a = np.asarray(img).astype(np.float32) / 255.0
    return a[..., None] if a.ndim == 2 else a


def chw(a: np.ndarray) -> torch.Tensor:
    return torch.from_numpy(np.ascontiguousarray(a)).permute(2, 0, 1)


# ----------------------------------------------------------------------------- conversion
def test_dielectric_with_f0_004_is_exact():
    m = make_material()
    m = Material(m.diffuse, m.normal, m.roughness, torch.full_like(m.specular, DIELECTRIC_F0))
    mr = metallic_roughness(m)
    assert float(mr.metallic.abs().max()) <= EXACT_TOL
    assert (mr.basecolor - m.diffuse).abs().max() <= EXACT_TOL
    back = material_from_metallic_roughness(mr, specular_extension=False)
    assert (back.diffuse - m.diffuse).abs().max() <= EXACT_TOL
    assert (back.specular - m.specular).abs().max() <= EXACT_TOL


def test_metal_without_diffuse_is_exact():
    m = make_material(seed=1)
    specular = 0.3 + 0.6 * torch.rand(3, H, W, generator=torch.Generator().manual_seed(5))
    metal = Material(torch.zeros_like(m.diffuse), m.normal, m.roughness, specular)
    mr = metallic_roughness(metal)
    assert (mr.metallic - 1).abs().max() <= EXACT_TOL
    assert (mr.basecolor - specular).abs().max() <= EXACT_TOL
    for ext in (False, True):
        back = material_from_metallic_roughness(mr, specular_extension=ext)
        assert (back.specular - specular).abs().max() <= EXACT_TOL
        # The residual 1 - m (float32 rounding) is divided by 1 - F0 >= 0.1 on the way back.
        assert float(back.diffuse.max()) <= EXACT_TOL / 0.1


def test_conversion_ranges_and_extension_restores_low_f0():
    m = make_material(seed=2)
    mr = metallic_roughness(m)
    for t in (mr.basecolor, mr.metallic, mr.specular_color):
        assert float(t.min()) >= 0 and float(t.max()) <= 1
    assert torch.equal(mr.roughness, m.roughness)
    # A dielectric below 0.04 (s <= a: m = 0): the core set shows F0 = 0.04, the
    # extension the true F0.
    low = Material(m.diffuse, m.normal, m.roughness, torch.full_like(m.specular, 0.02))
    mr = metallic_roughness(low)
    core = material_from_metallic_roughness(mr, specular_extension=False)
    ext = material_from_metallic_roughness(mr, specular_extension=True)
    assert (core.specular - DIELECTRIC_F0).abs().max() <= EXACT_TOL
    assert (ext.specular - 0.02).abs().max() <= EXACT_TOL


# ----------------------------------------------------------------------------- files
@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    folder = tmp_path_factory.mktemp("exp") / "wood"
    material = make_material(seed=3)
    export_material(folder, material, name="wood", provenance={"test": True})
    return folder, material


def test_export_writes_maps_in_their_stated_colour_spaces(exported):
    folder, material = exported
    info = json.loads((folder / EXPORT_JSON).read_text())
    files = info["files"]
    for name in ("diffuse", "specular", "basecolor"):
        assert "sRGB" in files[f"{name}.png"] and "linear" in files[f"{name}.exr"]
    for name in ("roughness", "metallic"):
        assert "linear" in files[f"{name}.png"]
    assert "OpenGL" in files["normal.png"] and info["normal_convention"] == "opengl"
    mr = metallic_roughness(material)
    # EXRs: linear and exact; PNGs: encoded as stated, to one code.
    assert torch.equal(chw(read_exr(folder / "basecolor.exr")), mr.basecolor)
    assert torch.equal(chw(read_exr(folder / "diffuse.exr")), material.diffuse)
    diffuse_png = chw(png_values((folder / "diffuse.png").read_bytes()))
    assert (srgb_decode(diffuse_png) - material.diffuse).abs().max() <= 0.01  # sRGB, not linear
    assert (diffuse_png - material.diffuse).abs().max() > 0.05
    rough_png = chw(png_values((folder / "roughness.png").read_bytes()))
    assert (rough_png - material.roughness).abs().max() <= CODE_TOL
    packed = chw(png_values((folder / "metallic_roughness.png").read_bytes()))
    assert (packed[1] - mr.roughness[0]).abs().max() <= CODE_TOL
    assert (packed[2] - mr.metallic[0]).abs().max() <= CODE_TOL
    normal_png = chw(png_values((folder / "normal.png").read_bytes()))
    assert (normal_png - (material.normal + 1) / 2).abs().max() <= CODE_TOL


def test_directx_normals_flip_green_only(tmp_path):
    material = make_material(seed=4)
    export_material(tmp_path / "dx", material, normal_convention="directx", glb=False)
    png = chw(png_values((tmp_path / "dx" / "normal.png").read_bytes()))
    flipped = material.normal * torch.tensor([1.0, -1.0, 1.0]).view(3, 1, 1)
    assert (png - (flipped + 1) / 2).abs().max() <= CODE_TOL
    assert torch.equal(chw(read_exr(tmp_path / "dx" / "normal.exr")), flipped)
    assert not (tmp_path / "dx" / "material.glb").exists()
    with pytest.raises(ValueError, match="normal_convention"):
        export_material(tmp_path / "x", material, normal_convention="vulkan")


def test_export_refuses_an_existing_folder(tmp_path):
    material = make_material(seed=6)
    export_material(tmp_path / "e", material, glb=False)
    with pytest.raises(FileExistsError):
        export_material(tmp_path / "e", material)
    export_material(tmp_path / "e", material, overwrite=True)  # a folder it wrote: replaced
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "keep.txt").write_text("mine")
    with pytest.raises(FileExistsError):
        export_material(tmp_path / "other", material, overwrite=True)
    assert (tmp_path / "other" / "keep.txt").read_text() == "mine"


# ----------------------------------------------------------------------------- GLB
def test_glb_container_layout(exported):
    folder, _ = exported
    data = (folder / "material.glb").read_bytes()
    magic, version, length = struct.unpack_from("<4sII", data, 0)
    assert (magic, version, length) == (b"glTF", 2, len(data))
    json_len, json_type = struct.unpack_from("<II", data, 12)
    assert json_type == CHUNK_JSON and json_len % 4 == 0
    assert data[20 + json_len - 1 : 20 + json_len] in (b"}", b" ")  # padded with spaces
    bin_len, bin_type = struct.unpack_from("<II", data, 20 + json_len)
    assert bin_type == CHUNK_BIN and bin_len % 4 == 0 and 28 + json_len + bin_len == len(data)
    glb = read_glb(folder / "material.glb")
    assert glb.gltf["asset"]["version"] == "2.0"
    assert glb.gltf["buffers"][0]["byteLength"] <= len(glb.binary)
    for view in glb.gltf["bufferViews"]:
        assert view.get("byteOffset", 0) % 4 == 0


def test_glb_geometry(exported):
    folder, _ = exported
    glb = read_glb(folder / "material.glb")
    prim = glb.gltf["meshes"][0]["primitives"][0]
    for name, index in prim["attributes"].items():
        acc = glb.gltf["accessors"][index]
        values = glb.accessor(index)
        assert values.shape[0] == acc["count"] == 4, name
        assert acc["min"] == pytest.approx(values.min(axis=0).tolist()), name
        assert acc["max"] == pytest.approx(values.max(axis=0).tolist()), name
    pos = glb.accessor(prim["attributes"]["POSITION"])
    uv = glb.accessor(prim["attributes"]["TEXCOORD_0"])
    # Long side 1 m, aspect of the maps (W / H), centred.
    assert np.ptp(pos[:, 0]) == pytest.approx(1.0) and np.ptp(pos[:, 1]) == pytest.approx(H / W)
    # UV (0, 0) is the image's top-left: the vertex with the smallest x and largest y.
    top_left = np.argmin(uv.sum(axis=1))
    assert pos[top_left, 0] == pos[:, 0].min() and pos[top_left, 1] == pos[:, 1].max()
    # v grows downwards (towards -y), u to the right (+x).
    assert np.corrcoef(uv[:, 0], pos[:, 0])[0, 1] > 0.99 and np.corrcoef(uv[:, 1], pos[:, 1])[0, 1] < -0.99
    # Triangles wind counter-clockwise seen from +Z, matching the +Z normals.
    idx = glb.accessor(prim["indices"]).reshape(-1, 3)
    for tri in idx:
        a, b, c = pos[tri]
        assert np.cross(b - a, c - a)[2] > 0
    normal = glb.accessor(prim["attributes"]["NORMAL"])
    tangent = glb.accessor(prim["attributes"]["TANGENT"])
    bitangent = np.cross(normal, tangent[:, :3]) * tangent[:, 3:]
    assert np.allclose(bitangent, [0, 1, 0])  # +y: the image's up, OpenGL green-up


def test_glb_material_textures_factors_and_extension(exported):
    folder, material = exported
    glb = read_glb(folder / "material.glb")
    assert SPECULAR_EXTENSION in glb.gltf["extensionsUsed"]
    assert SPECULAR_EXTENSION not in glb.gltf.get("extensionsRequired", [])  # viewers may ignore it
    mat = glb.gltf["materials"][0]
    assert mat["name"] == "wood"
    pbr = mat["pbrMetallicRoughness"]
    assert pbr["metallicFactor"] == 1.0 and pbr["roughnessFactor"] == 1.0
    assert pbr["baseColorFactor"] == [1.0, 1.0, 1.0, 1.0]
    spec = mat["extensions"][SPECULAR_EXTENSION]
    assert spec["specularColorFactor"] == [SPECULAR_COLOR_FACTOR] * 3 and spec["specularFactor"] == 1.0
    mr = metallic_roughness(material)
    base = chw(png_values(glb.texture_image(pbr["baseColorTexture"])))
    assert base.shape == (3, H, W)
    assert torch.equal(base, chw(png_values((folder / "basecolor.png").read_bytes())))  # the sRGB PNG
    packed = chw(png_values(glb.texture_image(pbr["metallicRoughnessTexture"])))
    assert (packed[1] - mr.roughness[0]).abs().max() <= CODE_TOL and (
        packed[2] - mr.metallic[0]
    ).abs().max() <= CODE_TOL
    normal = chw(png_values(glb.texture_image(mat["normalTexture"])))
    assert (normal - (material.normal + 1) / 2).abs().max() <= CODE_TOL  # OpenGL in the GLB
    f0 = srgb_decode(chw(png_values(glb.texture_image(spec["specularColorTexture"]))))
    assert (f0 - mr.specular_color).abs().max() <= 0.01  # sRGB-encoded, as the extension says
    for image in glb.gltf["images"]:
        assert image["mimeType"] == "image/png"


def test_read_glb_refuses_broken_files(tmp_path):
    good = pack_glb({"asset": {"version": "2.0"}}, b"\x01\x02")
    cases = {
        "magic": b"gLTF" + good[4:],
        "length": good[:8] + struct.pack("<I", len(good) + 4) + good[12:],
        "misaligned": good[:12] + struct.pack("<I", struct.unpack_from("<I", good, 12)[0] + 1) + good[16:],
    }
    for name, data in cases.items():
        path = tmp_path / f"{name}.glb"
        path.write_bytes(data)
        with pytest.raises(FormatError) as err:
            read_glb(path)
        assert str(path) in str(err.value), name
    (tmp_path / "ok.glb").write_bytes(good)
    assert read_glb(tmp_path / "ok.glb").binary[:2] == b"\x01\x02"
